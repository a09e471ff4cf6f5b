"""What every replanner shares (issue 16; `Replan`, `services/planner/sipp/replan.py` and
`services/planner/ilp/replan.py`): which vehicles stay as they are and which are planned on from
where (their *prefix*: the path up to the first node at or after the switch time, flown unchanged),
what their batteries still allow after it, and which nodes and edges a body that left could touch.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from common.bus.messages import Replan
from common.domain.planfile import PathEntry, Task
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.result import PlanResult

TURN_ALLOWANCE_S = 2.0
"""s: a vehicle at rest on its goal leaves for a new goal this long after the switch time, time to
turn in place towards its first edge (it parked facing the way it came: 180 deg at the pursuit's
6 rad/s turn rate, `services/executor/pure_pursuit.py`: 0.5 s, with margin for a loaded loop)."""


@dataclass(frozen=True)
class Leg:
    """A remaining vehicle to plan: its prefix, the node and time it is planned from, its goal and
    the charge its battery still allows after the prefix (planner units, eq. 6); `hold`: it stays
    at `start` from `depart` on, unplanned (a stranded vehicle with nowhere to go)."""

    vid: str
    prefix: list[PathEntry]
    start: int
    depart: float
    goal: int
    usable: float
    task: Task
    hold: bool = False


def split(graph: FleetGraph, replan: Replan) -> tuple[dict[str, list[PathEntry]], list[Leg]]:
    """The vehicles that stay as they are (resting at their goals by `at`) and those planned on."""
    base, at, left = replan.base, replan.at, set(replan.left)
    fixed: dict[str, list[PathEntry]] = {}
    legs: list[Leg] = []
    for vid, path in base.paths.items():
        if vid in left:
            continue
        task = base.tasks[vid]
        goal = replan.goals.get(vid, task.goal)
        if path[-1].t <= at:
            if goal == path[-1].node:
                fixed[vid] = path
                continue
            prefix, depart = path, at + TURN_ALLOWANCE_S
        else:
            k = next(i for i, e in enumerate(path) if e.t >= at)
            prefix, depart = path[:k + 1], path[k].t
        usable = task.usable_ah(graph.model) - prefix_charge(graph, prefix)
        legs.append(Leg(vid, list(prefix), graph.index[prefix[-1].node], depart, graph.index[goal], usable,
                        Task(start=prefix[-1].node, goal=goal, capabilities=task.capabilities,
                             charge_used_ah=task.charge_used_ah, voltage=task.voltage)))
    return fixed, legs


def prefix_charge(graph: FleetGraph, entries: list[PathEntry]) -> float:
    """Eq. 4-5 over a path's entries: each traversal's charge and each wait at its node's rate."""
    rate = graph.wait_charge_rate()
    total = 0.0
    for a, b in pairwise(entries):
        u, v = graph.index[a.node], graph.index[b.node]
        total += float(rate[u]) * (b.t - a.t) if u == v else float(graph.charge[graph.edge_index[(u, v)]])
    return total


Touched = tuple[np.ndarray, np.ndarray]
"""The indices of the nodes and of the edges a body on a segment could touch (`touched_by_segment`)."""


def touched_by_segment(graph: FleetGraph, p0: tuple[float, float, float], p1: tuple[float, float, float],
                       extra: float = 0.0) -> Touched:
    """Indices of the nodes and edges whose bodies (cylinders of the graph's envelope) could touch a
    body anywhere on the segment p0 -> p1, or within `extra` m of it."""
    r, h = graph.model.radius, graph.model.height
    step = r / 4
    a, b = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    k = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
    seg = a + np.linspace(0.0, 1.0, k)[:, None] * (b - a)  # (K, 3)
    reach, reach_z = 2 * r + step + extra, h + step + extra
    if a[0] == b[0] and a[1] == b[1]:  # a column (a held vehicle, a descent: most sweeps): every sample
        # at one horizontal distance, so the test below in closed form (15 -> 1.3 ms a sweep on city934)
        low, high = min(a[2], b[2]) - reach_z, max(a[2], b[2]) + reach_z

        def touch(points: np.ndarray) -> np.ndarray:  # (..., 3) -> (...,) whether it touches the column
            z = points[..., 2]
            return (np.hypot(points[..., 0] - a[0], points[..., 1] - a[1]) < reach) & (z > low) & (z < high)
    else:
        def touch(points: np.ndarray) -> np.ndarray:  # (..., 3) -> (...,) whether any sample touches
            d = points[..., None, :] - seg
            return ((np.hypot(d[..., 0], d[..., 1]) < reach) & (np.abs(d[..., 2]) < reach_z)).any(axis=-1)

    pos = np.asarray(graph.pos, dtype=float)
    # only the nodes and edges near the segment's bounding box are looked at closely (every edge
    # sampled, then most thrown away, made a 32-vehicle replan's 76 sweeps 0.47 of its 0.6 s)
    lo, hi = seg.min(axis=0) - reach - h, seg.max(axis=0) + reach + h
    close = np.flatnonzero(((pos >= lo) & (pos <= hi)).all(axis=1))
    nodes = close[touch(pos[close])]
    tail, head = pos[graph.edges[:, 0]], pos[graph.edges[:, 1]]
    near = np.flatnonzero(((np.minimum(tail, head) <= hi) & (np.maximum(tail, head) >= lo)).all(axis=1))
    if not len(near):
        return nodes, near
    length = np.linalg.norm(head - tail, axis=1)
    m = max(2, int(np.ceil(length.max() / step)) + 1)
    f = np.linspace(0.0, 1.0, m)
    tail, head = tail[near], head[near]
    samples = tail[:, None, :] + f[None, :, None] * (head - tail)[:, None, :]  # (near edges, M, 3)
    return nodes, near[touch(samples).any(axis=1)]


def rejoins_blocked(graph: FleetGraph, replan: Replan) -> dict[str, str]:
    """The vehicles that rejoin (`Replan.rejoin`) whose way from where each stands to its switch
    node (the last step of its prefix, over [at, its arrival there]) a body that left could touch
    then (`touched_by_segment`: the whole edge, conservatively), each with whose body; empty when
    every rejoining vehicle's way is clear. (The prefix is flown unchanged: the planner cannot
    route it around a body, and the validator knows only paths, not the bodies that left.) All of
    them at once: a mission brings the others back in one more request, not one per vehicle
    refused (13 of one 32-vehicle soak's 23 requests to its planner were such refusals)."""
    at = replan.at
    blocked: dict[str, str] = {}
    touched: dict[int, Touched] = {}  # per sweep, found once for every vehicle
    for vid in replan.rejoin:
        path = replan.base.paths[vid]
        k = next((i for i, e in enumerate(path) if e.t >= at), None)
        if k is None:
            continue  # at rest at the end of its path: planned from there
        a, b = path[max(k - 1, 0)], path[k]
        u, v = graph.index[a.node], graph.index[b.node]
        for w, sweep in enumerate(replan.sweeps):
            if sweep.vid == vid or sweep.t0 > b.t or (not sweep.rest and sweep.t1 < at):
                continue
            if w not in touched:
                touched[w] = touched_by_segment(graph, sweep.p0, sweep.p1, sweep.reach)
            nodes, edges = touched[w]
            if (u == v and v in nodes) or (u != v and graph.edge_index[(u, v)] in edges):
                blocked[vid] = f"its way to {b.node!r} crosses where {sweep.vid} may be"
                break
    return blocked


def failed(vid: str, reason: str, t0: float, timed_out: bool = False, unplaceable: Sequence[str] = ()) -> PlanResult:
    return PlanResult(ok=False, error=f"{vid}: {reason}", failed_vehicle=vid, planning_time_s=time.perf_counter() - t0,
                      timed_out=timed_out, unplaceable=list(unplaceable))
