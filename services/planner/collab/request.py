"""Team plan requests (paper 002 over zenoh), the solver of planner "collab" in `registry.py`:
`PlanRequest(planner="collab", team=TeamTask(...))` -> a TeamPlan (§IV-E)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from common.bus.keys import check_chunk
from common.bus.messages import PlanReply, PlanRequest
from common.errors import InputError

if TYPE_CHECKING:  # the planning modules load on the first team request, not with every `fleet` command
    from services.planner.collab.planner import TeamPlanner

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
    return PlanReply(ok=True, team_plan=out.plan, planner="collab")
