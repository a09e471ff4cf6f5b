"""Team plan requests on the planner service (paper 002 over zenoh): `PlanRequest(planner="collab",
team=TeamTask(...))` -> a TeamPlan (§IV-E), and its per-robot copies for the executors
(`vehicle/<vid>/team_plan`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import zenoh

from common.bus.keys import check_chunk
from common.bus.messages import PlanReply, PlanRequest, TeamTask, VehicleTeamPlan
from common.bus.pubsub import Publisher
from common.bus.service import Service
from common.domain.team_plan import TeamPlan
from common.errors import InputError

if TYPE_CHECKING:  # the planning modules load on the first team request, not with every `fleet` command
    from services.planner.collab.planner import TeamPlanner

PLANNER = "collab"
"""The `PlanRequest.planner` name of team planning."""

_planners: dict[str, TeamPlanner] = {}


def team_planner(map_name: str) -> TeamPlanner:
    """The planner of a map, kept across requests (it reuses the SLC graphs it has built)."""
    from common.team.maps import load_env
    from services.planner.collab.planner import TeamPlanner

    if map_name not in _planners:
        _planners[map_name] = TeamPlanner(load_env(map_name))
    return _planners[map_name]


def solve_team(req: PlanRequest) -> PlanReply:
    """Plan for the request's team (blocking: run it in a worker thread); errors name the field."""
    team = req.team
    if team is None:
        return PlanReply(ok=False, error="planner collab needs `team`: the drone and UGV ids, their starts and the goal")
    if req.tasks:
        return PlanReply(ok=False, error="planner collab plans one team (`team`), not `tasks`")
    try:
        check_chunk(team.drone, "team.drone")
        check_chunk(team.ugv, "team.ugv")
    except ValueError as exc:
        return PlanReply(ok=False, error=str(exc))
    if team.drone == team.ugv:
        return PlanReply(ok=False, error="team.drone and team.ugv must be different vehicles")
    try:
        planner = team_planner(req.map)
        problem = planner.problem_at(team.drone_start, team.ugv_start, team.goal, "plan request team")
    except InputError as exc:
        return PlanReply(ok=False, error=str(exc))
    out = planner.plan(problem, team.method, req.time_limit, max(0.0, team.improve_s))
    if out.plan is None:
        why = f"time limit of {req.time_limit:g} s reached" if out.timed_out else "no team plan exists"
        return PlanReply(ok=False, error=f"no team plan: {why} ({out.expansions} expansions)")
    return PlanReply(ok=True, team_plan=out.plan)


def robot_plans(plan: TeamPlan, team: TeamTask, mission: str, t0: float = 0.0) -> dict[str, VehicleTeamPlan]:
    """The drone's and the UGV's copy of a team plan, each naming its partner."""
    return {
        team.drone: VehicleTeamPlan(vid=team.drone, mission=mission, robot="drone", partner=team.ugv, plan=plan, t0=t0),
        team.ugv: VehicleTeamPlan(vid=team.ugv, mission=mission, robot="ugv", partner=team.drone, plan=plan, t0=t0),
    }


class TeamPlanPublisher:
    """Publishes VehicleTeamPlans on `vehicle/<vid>/team_plan` for a service, one publisher per robot."""

    def __init__(self, service: Service) -> None:
        self._service = service
        self._pubs: dict[str, Publisher[VehicleTeamPlan]] = {}

    def put(self, plans: dict[str, VehicleTeamPlan]) -> None:
        for vid, msg in plans.items():
            pub = self._pubs.get(vid)
            if pub is None:
                pub = self._pubs[vid] = self._service.publisher(
                    self._service.keys.vehicle(vid, "team_plan"), VehicleTeamPlan,
                    congestion_control=zenoh.CongestionControl.BLOCK)
            pub.put(msg)
