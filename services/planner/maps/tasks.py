"""Scenarios (paper 000 §IV) on a graph: a scenario file (`common.domain.scenario`) checked, or a
seeded random draw.

Well-formed (§V-D): every start and goal is a parking spot or helipad (any node on maps with open
endpoints, such as MovingAI grids), starts are unique and goals are unique. A plan request may also
end a flying vehicle's task at an air node (`air_goals`: it hovers there until given another goal,
issue 19's single-vehicle take-off; SIPP's goal rests there for ever, as on the ground).
"""

from __future__ import annotations

import random
from pathlib import Path

from common.bus.keys import check_chunk
from common.domain.planfile import Task
from common.domain.scenario import read_scenario
from common.errors import InputError
from services.planner.graph.fleet_graph import FleetGraph


def load_scenario(path: str | Path, graph: FleetGraph) -> dict[str, Task]:
    spec = read_scenario(path)
    check_tasks(spec.tasks, graph, str(path))
    return dict(spec.tasks)


def check_tasks(tasks: dict[str, Task], graph: FleetGraph, source: str, air_goals: bool = False) -> None:
    """Raise InputError naming the task field when a scenario is not well-formed on `graph`;
    `air_goals`: a vehicle that flies may also end at an air node (see the module doc)."""
    if not tasks:
        raise InputError(source, "tasks", "no vehicles")
    allowed = {caps: set(graph.endpoints(caps)) for caps in ("fly+drive", "fly", "drive")}
    air = {n for n, k in zip(graph.ids, graph.kinds, strict=True) if k == "air"} if air_goals else set()
    goal_allowed = {caps: nodes | air if caps != "drive" else nodes for caps, nodes in allowed.items()}
    spots = {"fly+drive": "a parking spot or helipad", "fly": "a helipad or road node (it only flies)",
             "drive": "a parking spot (it only drives)"}
    starts: dict[str, str] = {}
    goals: dict[str, str] = {}
    for vid, task in tasks.items():
        try:
            check_chunk(vid, "vehicle id")
        except ValueError as exc:
            raise InputError(source, f"tasks.{vid}", str(exc)) from None
        for field, node, seen, ok in (("start", task.start, starts, allowed), ("goal", task.goal, goals, goal_allowed)):
            where = f"tasks.{vid}.{field}"
            if node not in graph.index:
                raise InputError(source, where, f"unknown node {node!r} on map {graph.name!r}")
            if node not in ok[task.capabilities]:
                raise InputError(source, where, f"{node!r} is a {graph.kinds[graph.index[node]]} node, "
                                                f"not {spots[task.capabilities]}")
            if node in seen:
                raise InputError(source, where, f"{node!r} is also the {field} of {seen[node]!r}")
            seen[node] = vid
        if not graph.joined(task.start, task.goal):
            raise InputError(source, f"tasks.{vid}", f"{task.start!r} and {task.goal!r} are in different connected "
                             f"components of {graph.name!r}: no path joins them")


def random_tasks(graph: FleetGraph, n: int, seed: int) -> dict[str, Task]:
    """n vehicles on 2n distinct spots drawn with `seed` (so no goal is another vehicle's start)."""
    spots = sorted(graph.endpoints())
    if n < 1 or 2 * n > len(spots):
        raise InputError(graph.name, "--random", f"needs 1 <= N <= {len(spots) // 2} on this map, got {n}")
    picked = random.Random(seed).sample(spots, 2 * n)
    width = len(str(n))
    return {f"cf{i + 1:0{width}d}": Task(start=picked[2 * i], goal=picked[2 * i + 1]) for i in range(n)}
