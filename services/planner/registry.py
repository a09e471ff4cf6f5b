"""The planners, by name, all with one signature: a `PlanRequest` in, a `PlanReply` out (the planner
service calls `solve`). Paper 000's graph planners ("sipp", "ilp") share one path: map + tasks ->
graph problem -> paths -> plan file -> validation; paper 002's team planner ("collab") plans for a
ground-air team (`services/planner/collab/request.py`)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from importlib import import_module

import msgspec

from common.bus.messages import PlanReply, PlanRequest
from common.domain.planfile import Plan, Task
from common.errors import InputError
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.maps.loading import GraphProblem, load_graph, problem_from_request
from services.planner.replanning import rejoins_blocked
from services.planner.result import PlanResult, to_plan

log = logging.getLogger(__name__)

Solver = Callable[[PlanRequest], PlanReply]
GraphPlanner = Callable[[FleetGraph, dict[str, Task], float, float, int], PlanResult]

PLANNERS: dict[str, str] = {
    "sipp": "services.planner.registry:solve_on_graph",
    "ilp": "services.planner.registry:solve_on_graph",
    "collab": "services.planner.collab.request:solve_team",
}
"""Every planner a request may name -> its solver (``module:function``, imported on first use)."""

GRAPH_PLANNERS: dict[str, str] = {
    "sipp": "services.planner.sipp.planner:plan_sipp",
    "ilp": "services.planner.ilp.planner:plan_ilp",
}
"""The graph planners of paper 000 behind `solve_on_graph` and `fleet plan`."""


def _load(target: str) -> Callable:
    module, fn = target.split(":")
    return getattr(import_module(module), fn)


def solve(req: PlanRequest) -> PlanReply:
    """Plan for a request with the planner it names (blocking: run it in a worker thread)."""
    if req.planner not in PLANNERS:
        return PlanReply(ok=False, error=f"unknown planner {req.planner!r} (choose from {', '.join(PLANNERS)})")
    if not 0.0 <= req.mu <= 1.0:
        return PlanReply(ok=False, error=f"mu must be in [0, 1], got {req.mu}")
    if req.time_limit <= 0:
        return PlanReply(ok=False, error="time_limit must be positive")
    if req.reply_within < 0:
        return PlanReply(ok=False, error=f"reply_within must be 0 (no limit) or positive, got {req.reply_within}")
    if req.replan is not None:
        return solve_replan(req)
    solver: Solver = _load(PLANNERS[req.planner])
    return solver(req)


REPLANNERS: dict[str, str] = {
    "sipp": "services.planner.sipp.replan:replan_sipp",
    "ilp": "services.planner.ilp.replan:replan_ilp",
}
"""The planners that plan a running mission on (`Replan`), by the name a replan request gives."""
ILP_SHARE = 0.5
"""Of a replan's time limit, what the ILP may take; SIPP plans on in the rest if it found no plan."""


def solve_replan(req: PlanRequest) -> PlanReply:
    """Plan a running mission on (`Replan`, issue 16) on its base plan's graph with the planner the
    request names: SIPP (fast; the default), or the ILP where its time limit allows (on a plan on
    its time steps; SIPP takes over within the limit if it finds none). The spliced plan is
    validated as a whole (prefixes + new suffixes + the vehicles at rest); SIPP tries again with
    the later of two vehicles it found in contact placed first, while the time limit allows."""
    rp = req.replan
    assert rp is not None
    base = rp.base
    if req.planner not in REPLANNERS:
        return PlanReply(ok=False, error=f"replan: planner {req.planner!r} does not replan (choose from "
                                         f"{', '.join(REPLANNERS)})")
    if req.planner == "ilp" and base.planner != "ilp":
        return PlanReply(ok=False, error=f"replan: the ILP replans plans on its time steps (planner ilp), "
                                         f"not a {base.planner} plan: replan with sipp")
    try:  # the base's tasks are not checked again: a stranded vehicle's goal may be a road node
        graph = load_graph(base.map, uniform=base.planner == "ilp")
    except InputError as exc:
        return PlanReply(ok=False, error=str(exc))
    unknown = sorted((set(rp.left) | set(rp.goals) | set(rp.rejoin)) - set(base.paths))
    if unknown:
        return PlanReply(ok=False, error=f"replan: {', '.join(unknown)} not in the plan")
    if rp.rejoin and req.planner != "sipp":
        return PlanReply(ok=False, error="replan: vehicles rejoin with sipp (their paths are shifted off the ILP's time steps)")
    if blocked := rejoins_blocked(graph, rp):
        return PlanReply(ok=False, error="; ".join(f"replan: {vid} cannot rejoin yet: {why}" for vid, why in blocked.items()),
                         failed_vehicle=next(iter(blocked)), refused=blocked)
    missing = sorted(g for g in rp.goals.values() if g not in graph.index)
    if missing:
        return PlanReply(ok=False, error=f"replan: no node {', '.join(map(repr, missing))} on map {base.map!r}")
    deadline = time.perf_counter() + req.time_limit
    if req.planner == "ilp":
        reply, _ = _replan_with(graph, req, "ilp", ILP_SHARE * req.time_limit)
        if reply.ok:
            return reply
        log.info("replan: the ILP found no plan (%s): SIPP plans on", reply.error)
    first: list[str] = []
    while True:
        reply, later = _replan_with(graph, req, "sipp", max(deadline - time.perf_counter(), min(0.05, req.time_limit)),
                                    first)
        if reply.ok or later is None or later in first:
            return reply
        if time.perf_counter() > deadline:  # another order was left to try
            return msgspec.structs.replace(reply, timed_out=True)
        first.insert(0, later)


def _replan_with(graph: FleetGraph, req: PlanRequest, planner: str, time_limit: float,
                 first: Sequence[str] = ()) -> tuple[PlanReply, str | None]:
    """One replan by `planner` (SIPP with the vehicles `first` placed first), validated whole; and,
    when the validator found two bodies in contact, the one SIPP placed later: a vehicle placed
    earlier may cross the last step of a later one's prefix (`sipp/replan.py`), which placing it
    first avoids."""
    from services.planner.validate import validate_plan

    rp = req.replan
    assert rp is not None
    base = rp.base
    extra = {"first": first} if planner == "sipp" else {}
    result = _load(REPLANNERS[planner])(graph, rp, base.mu, time_limit, req.seed, **extra)
    if not result.ok:
        return PlanReply(ok=False, error=f"no plan (could not place {result.failed_vehicle}): {result.error}",
                         failed_vehicle=result.failed_vehicle, timed_out=result.timed_out,
                         unplaceable=result.unplaceable), None
    tasks = {vid: msgspec.structs.replace(base.tasks[vid], goal=result.paths[vid][-1].node
                                          if vid in result.stranded else rp.goals.get(vid, base.tasks[vid].goal))
             for vid in result.paths}
    if stuck := sorted(set(result.stranded) & set(rp.rejoin)):
        return PlanReply(ok=False, error=f"replan: {stuck[0]} cannot rejoin yet: its goal is out of reach "
                                         f"({result.stranded[stuck[0]]})", failed_vehicle=stuck[0]), None
    plan = to_plan(graph, base.map, base.planner, base.mu, tasks, result)
    report = validate_plan(plan, check_cost=False, since=rp.at)
    if report.ok:  # priced by the validator: whole paths, the executed prefix and the new suffix
        return PlanReply(ok=True, plan=msgspec.structs.replace(plan, cost=report.cost), planner=planner), None
    rank = {vid: i for i, vid in enumerate(result.priority)}
    later = next((max(c.a, c.b, key=lambda v: rank[v]) for c in report.contacts if c.a in rank and c.b in rank), None)
    # a rejoining vehicle in contact is named: its mission leaves it out and brings the others back
    # (named by no one, none came back: two held vehicles stood within reach of each other)
    rejoining = next((v for c in report.contacts for v in (c.a, c.b) if v in rp.rejoin), "")
    return PlanReply(ok=False, error="replan failed validation: " + "; ".join(report.errors[:5]),
                     failed_vehicle=rejoining), later


def solve_on_graph(req: PlanRequest) -> PlanReply:
    """A graph planner's request: plan the tasks on the map's graph and validate the plan."""
    from services.planner.validate import validate_plan

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
    return PlanReply(ok=True, plan=plan, planner=req.planner)


def get_planner(name: str) -> GraphPlanner:
    if name not in GRAPH_PLANNERS:
        raise InputError("planner", "", f"unknown graph planner {name!r} (choose from {', '.join(GRAPH_PLANNERS)})")
    return _load(GRAPH_PLANNERS[name])


def run_planner(problem: GraphProblem, planner: str, mu: float, time_limit: float, seed: int) -> tuple[Plan | None, PlanResult]:
    """Run a graph planner; the plan file on success, else None (the result says why)."""
    fn = get_planner(planner)
    t0 = time.perf_counter()
    result = fn(problem.graph, problem.tasks, mu, time_limit, seed)
    if not result.planning_time_s:
        result.planning_time_s = time.perf_counter() - t0
    if not result.ok:
        return None, result
    return to_plan(problem.graph, problem.map_name, planner, mu, problem.tasks, result), result
