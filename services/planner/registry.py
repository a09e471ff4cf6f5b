"""The planner registry: name -> planning function, and the step from result to plan file."""

from __future__ import annotations

import time
from collections.abc import Callable
from importlib import import_module

from common.domain.planfile import Plan, Task
from common.errors import InputError
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.maps.loading import Problem
from services.planner.result import PlanResult, to_plan

PlannerFn = Callable[[FleetGraph, dict[str, Task], float, float, int], PlanResult]

PLANNERS: dict[str, str] = {
    "sipp": "services.planner.sipp.planner:plan_sipp",
    "ilp": "services.planner.ilp.planner:plan_ilp",
}


def get_planner(name: str) -> PlannerFn:
    if name not in PLANNERS:
        raise InputError("planner", "", f"unknown planner {name!r} (choose from {', '.join(PLANNERS)}; collab for ground-air teams)")
    module, fn = PLANNERS[name].split(":")
    return getattr(import_module(module), fn)


def run_planner(problem: Problem, planner: str, mu: float, time_limit: float, seed: int) -> tuple[Plan | None, PlanResult]:
    """Run a planner; the plan file on success, else None (the result says why)."""
    fn = get_planner(planner)
    t0 = time.perf_counter()
    result = fn(problem.graph, problem.tasks, mu, time_limit, seed)
    if not result.planning_time_s:
        result.planning_time_s = time.perf_counter() - t0
    if not result.ok:
        return None, result
    return to_plan(problem.graph, problem.map_name, planner, mu, problem.tasks, result), result
