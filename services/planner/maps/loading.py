"""From command-line arguments or a plan request to a graph and tasks (maps, scenarios, MovingAI)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from functools import lru_cache

from common.domain.mapfile import load_map, resolve_map_path
from common.domain.planfile import Task
from common.errors import InputError
from services.planner.graph.fleet_graph import FleetGraph, build_graph
from services.planner.maps.tasks import check_tasks, load_scenario, random_tasks


@dataclass
class GraphProblem:
    graph: FleetGraph
    map_name: str
    tasks: dict[str, Task]


@lru_cache(maxsize=16)
def _cached_graph(path: str, mtime: float, dt: float | None, uniform: bool) -> FleetGraph:
    spec = load_map(path)
    step = spec.time_step if uniform else dt
    return build_graph(spec, step, source=path)


def load_graph(name_or_path: str, dt: float | None = None, uniform: bool = False) -> FleetGraph:
    """The graph of a map file; `uniform` uses the map's own time_step (§V-E). Cached per file version."""
    path = resolve_map_path(name_or_path)
    try:
        mtime = path.stat().st_mtime
    except OSError as exc:
        raise InputError(str(path), "", f"cannot read ({exc.strerror})") from None
    return _cached_graph(str(path), mtime, dt, uniform)


def load_problem(args: argparse.Namespace) -> GraphProblem:
    """`fleet plan` arguments -> graph + tasks. ILP plans always use the uniform-time-step graph."""
    uniform = args.planner == "ilp" or args.uniform
    if args.movingai:
        from services.planner.maps.movingai_graph import load_movingai, load_scen

        graph = load_movingai(args.movingai)
        if not args.scen:
            raise InputError("--scen", "", "a MovingAI map needs its .scen file")
        tasks = load_scen(args.scen, graph, args.agents)
        return GraphProblem(graph, args.movingai, tasks)
    graph = load_graph(args.map, uniform=uniform)
    if args.scenario:
        tasks = load_scenario(args.scenario, graph)
    elif args.random:
        tasks = random_tasks(graph, args.random, args.seed)
    else:
        raise InputError("fleet plan", "--scenario/--random", "give a scenario file or --random N")
    return GraphProblem(graph, args.map, tasks)


def problem_from_request(map_name: str, tasks: dict[str, Task], planner: str) -> GraphProblem:
    """The planner service's path: a map name and tasks from a zenoh request. A flying vehicle's
    goal may be an air node (it hovers there: a single-vehicle take-off, issue 19; the mission
    runner flies such tasks only in a `hover` mission)."""
    graph = load_graph(map_name, uniform=planner == "ilp")
    check_tasks(tasks, graph, "plan request", air_goals=True)
    return GraphProblem(graph, map_name, tasks)
