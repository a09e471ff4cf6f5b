"""The planner service: a zenoh queryable `planner/plan` (paper 000 Fig. 4: map + scenario ->
planner -> paths). A request names a map, tasks, a planner, mu and a time limit; the reply is a
validated plan or a clear error. With a mission id it also publishes each vehicle's plan on
`vehicle/<vid>/plan`; a team plan (planner "collab", paper 002) goes to both robots on
`vehicle/<vid>/team_plan`. The planners are those of `registry.py`. A second queryable,
`planner/graph`, serves the graph of a map to whoever draws it (the telemetry recorder)."""

from __future__ import annotations

import argparse
import asyncio
import logging
import time
from collections import deque
from pathlib import Path

import msgspec
import zenoh

from common.bus.args import keys_from_args, run_service, zconfig_from_args
from common.bus.messages import GraphReply, GraphRequest, PlanReply, PlanRequest, VehiclePlan, VehicleTeamPlan
from common.bus.service import KeyedPublishers, Service
from common.bus.stats import percentile_figures, publish_stats
from common.bus.vehicle_plans import robot_plans, vehicle_plans
from common.errors import InputError
from services.planner.failed_requests import FailedRequests
from services.planner.registry import solve

log = logging.getLogger(__name__)

RECENT = 100
"""Requests the planner's figures are taken over (the latest)."""


class PlannerService(Service):
    def __init__(self, *args, keep_failed: Path | None = None, **kwargs) -> None:
        """`keep_failed`: the folder each request it could not plan is written to (`FailedRequests`)."""
        super().__init__(*args, **kwargs)
        self._failed_requests = FailedRequests(keep_failed) if keep_failed is not None else None
        self._lock = asyncio.Lock()
        self._waited: deque[float] = deque(maxlen=RECENT)
        self._planned: deque[float] = deque(maxlen=RECENT)
        self._plans: KeyedPublishers[VehiclePlan] | None = None
        self._team_plans: KeyedPublishers[VehicleTeamPlan] | None = None

    async def main(self) -> None:
        block = zenoh.CongestionControl.BLOCK
        self._plans = self.publishers(lambda vid: self.keys.vehicle(vid, "plan"), VehiclePlan, congestion_control=block)
        self._team_plans = self.publishers(lambda vid: self.keys.vehicle(vid, "team_plan"), VehicleTeamPlan,
                                           congestion_control=block)
        self.serve(self.keys.planner_plan, PlanRequest, PlanReply, self.handle)
        self.serve(self.keys.planner_graph, GraphRequest, GraphReply, self.graph)
        self.spawn(publish_stats(self, self._figures), name="stats")
        await self.stopped()

    def _figures(self) -> dict[str, float]:
        """How long the recent requests waited for the planner and how long it planned them
        (`stats/planner/<instance>`: the soak's table)."""
        return {**percentile_figures("waited", self._waited), **percentile_figures("planned", self._planned),
                "waited_max_ms": 1e3 * max(self._waited, default=0.0),
                "planned_max_ms": 1e3 * max(self._planned, default=0.0)}

    async def graph(self, req: GraphRequest) -> GraphReply:
        """The graph of a map, as the plan file carries it (the recorder draws it)."""
        return await asyncio.to_thread(graph_of, req)

    async def handle(self, req: PlanRequest) -> PlanReply:
        """One plan at a time (planning is CPU-bound), and only while its requester waits
        (`PlanRequest.reply_within`): a request that waited that long behind others is answered
        "expired" without planning, one that waited part of it is planned within what is left.
        (On a loaded machine a mission's replans, each waited for a second or two, queued behind
        ones their mission had given up on: in a 32-vehicle soak they waited up to 8 s, and the
        planner spent its CPU on answers nobody read.)"""
        arrived = time.monotonic()
        async with self._lock:
            waited = time.monotonic() - arrived
            self._waited.append(waited)
            if req.reply_within > 0.0:
                left = req.reply_within - waited
                if left <= 0.0:
                    self.counters.inc("plans_expired")
                    log.info("plan request expired: waited %.2f s behind other plans, its requester %.2f s",
                             waited, req.reply_within)
                    return PlanReply(ok=False, error=f"expired: waited {waited:.2f} s behind other plans "
                                                     f"(the requester waits {req.reply_within:.2f} s)")
                if left < req.time_limit:
                    req = msgspec.structs.replace(req, time_limit=left)
            log.info("plan request: map %s, %d vehicles, %s, mu %.2f, time limit %.2f s (waited %.2f s)",
                     req.map, len(req.tasks), req.planner, req.mu, req.time_limit, waited)
            started = time.monotonic()
            reply = await asyncio.to_thread(solve, req)
            self._planned.append(time.monotonic() - started)
        self.counters.inc("plans_ok" if reply.ok else "plans_failed")
        if self._failed_requests is not None and (kept := self._failed_requests.keep(req, reply)) is not None:
            log.warning("plan request not planned (%s); kept: fleet replay-plan %s", reply.error[:300], kept)
        if reply.ok and req.mission and reply.plan is not None and self._plans is not None:
            self._plans.put_all(vehicle_plans(reply.plan, req.mission))
        if reply.ok and req.mission and reply.team_plan is not None and req.team and self._team_plans is not None:
            self._team_plans.put_all(robot_plans(reply.team_plan, req.team, req.mission))
        return reply


def graph_of(req: GraphRequest) -> GraphReply:
    from services.planner.maps.loading import load_graph

    try:
        return GraphReply(ok=True, graph=load_graph(req.map, uniform=req.uniform).to_plan_graph())
    except InputError as exc:
        return GraphReply(ok=False, error=str(exc))


def cmd_planner(args: argparse.Namespace) -> int:
    svc = PlannerService("planner", args.instance, zconfig_from_args(args), keys_from_args(args),
                         keep_failed=Path(args.keep_failed) if args.keep_failed else None)
    return run_service(svc)
