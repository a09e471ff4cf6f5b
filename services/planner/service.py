"""The planner service: a zenoh queryable `planner/plan` (paper 000 Fig. 4: map + scenario ->
planner -> paths). A request names a map, tasks, a planner, mu and a time limit; the reply is a
validated plan or a clear error. With a mission id it also publishes each vehicle's plan on
`vehicle/<vid>/plan`. Planner "collab" plans for a ground-air team (paper 002, `services/planner/collab/
request.py`): the reply carries a team plan, published to both robots on `vehicle/<vid>/team_plan`."""

from __future__ import annotations

import argparse
import asyncio
import logging

from common.bus.args import keys_from_args, run_service, zconfig_from_args
from common.bus.messages import PlanReply, PlanRequest
from common.bus.service import Service
from common.bus.vehicle_plans import PlanPublisher, vehicle_plans
from common.errors import InputError
from services.planner.collab.request import TeamPlanPublisher, robot_plans

log = logging.getLogger(__name__)


def solve(req: PlanRequest) -> PlanReply:
    """Plan and validate (blocking: run it in a worker thread)."""
    from services.planner.maps.loading import problem_from_request
    from services.planner.registry import run_planner
    from services.planner.validate import validate_plan

    if not 0.0 <= req.mu <= 1.0:
        return PlanReply(ok=False, error=f"mu must be in [0, 1], got {req.mu}")
    if req.time_limit <= 0:
        return PlanReply(ok=False, error="time_limit must be positive")
    if req.planner == "collab":
        from services.planner.collab.request import solve_team

        return solve_team(req)
    try:
        problem = problem_from_request(req.map, req.tasks, req.planner)
        plan, result = run_planner(problem, req.planner, req.mu, req.time_limit, req.seed)
    except InputError as exc:
        return PlanReply(ok=False, error=str(exc))
    if plan is None:
        who = f" (could not place {result.failed_vehicle})" if result.failed_vehicle else ""
        return PlanReply(ok=False, error=f"no plan{who}: {result.error}")
    report = validate_plan(plan)
    if not report.ok:
        return PlanReply(ok=False, error="plan failed validation: " + "; ".join(report.errors[:5]))
    return PlanReply(ok=True, plan=plan)


class PlannerService(Service):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._lock = asyncio.Lock()
        self._plans: PlanPublisher | None = None
        self._team_plans: TeamPlanPublisher | None = None

    async def main(self) -> None:
        self._plans = PlanPublisher(self)
        self._team_plans = TeamPlanPublisher(self)
        self.serve(self.keys.planner_plan, PlanRequest, PlanReply, self.handle)
        await self.stopped()

    async def handle(self, req: PlanRequest) -> PlanReply:
        async with self._lock:  # one plan at a time: planning is CPU-bound
            log.info("plan request: map %s, %d vehicles, %s, mu %.2f", req.map, len(req.tasks), req.planner, req.mu)
            reply = await asyncio.to_thread(solve, req)
        self.counters.inc("plans_ok" if reply.ok else "plans_failed")
        if reply.ok and req.mission and reply.plan is not None and self._plans is not None:
            self._plans.put(vehicle_plans(reply.plan, req.mission))
        if reply.ok and req.mission and reply.team_plan is not None and req.team and self._team_plans is not None:
            self._team_plans.put(robot_plans(reply.team_plan, req.team, req.mission))
        return reply


def cmd_planner(args: argparse.Namespace) -> int:
    svc = PlannerService("planner", args.instance, zconfig_from_args(args), keys_from_args(args))
    return run_service(svc)
