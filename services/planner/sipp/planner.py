"""Prioritized planning with multimodal SIPP (paper 000 §V-D): `plan_sipp`, registered as "sipp".

Vehicles are planned one at a time in a priority order; each one's path (Alg. 1-2,
services/planner/sipp/search.py) avoids the space-time claimed by the ones before it
(services/planner/sipp/safe_intervals.py). On well-formed infrastructure (§V-D: starts and goals on
parking spots or helipads, paths that do not pass through other spots) the vehicles not planned yet
close the space their parked bodies touch, for all time (revised prioritized planning, Čáp et al.
2015): each later vehicle finds its spot and its way out untouched, and can wait there until the way
is clear (as far as the battery allows). On
maps with open endpoints (MovingAI grids, §VII-style benchmarks) a lower-priority vehicle's start is
not reserved; it must leave before a higher-priority path passes.

A goal may be another vehicle's start. Orders plan the vehicle leaving a spot before the one that
will park there where they can (a stable topological sort); otherwise (a cycle of such goals, or a
restart that promotes a vehicle) the vehicle planned first ignores the body still parked on its goal,
which must then get away before it arrives.

The first order is the task order (so sorted). When a vehicle cannot be placed, the next order
promotes it to the front and keeps the others' order (on random-32-32-10 with 300 agents this needs
3 orders where reshuffling the others needs 60); an order tried before is replaced by a seeded
shuffle of the others. Restarts go on until a plan is found, the vehicle fails even at the top
priority, or the time limit passes. Every plan returned is conflict-free by construction.
"""

from __future__ import annotations

import itertools
import random
import time
from dataclasses import dataclass

from common.domain.planfile import PathEntry, Task
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.result import PlanResult, battery_shortfall
from services.planner.sipp.heuristic import CostToGo
from services.planner.sipp.safe_intervals import Footprints, Reservations
from services.planner.sipp.search import SearchGraph, SearchTimeout, TimedPath, sipp

FEW_VEHICLES = 6  # up to this many vehicles, restarts never repeat a priority order


@dataclass(frozen=True)
class _Failure:
    vid: str
    reason: str


@dataclass(frozen=True)
class _Setup:
    """What every priority order of one planning call shares."""

    graph: FleetGraph
    sg: dict[str, SearchGraph]
    """Per vehicle: the adjacency of the edges its capabilities allow."""
    ctg: dict[str, CostToGo]
    ends: dict[str, tuple[int, int]]  # vehicle -> (start, goal) node indices
    blockers: dict[str, list[str]]
    park_starts: bool
    deadline: float
    usable: dict[str, float]
    """Per vehicle: eq. 6's budget (what its battery still holds)."""


def plan_sipp(graph: FleetGraph, tasks: dict[str, Task], mu: float, time_limit: float, seed: int) -> PlanResult:
    """Plan every task on `graph` with eq. 3 weight `mu`; PlanResult names the vehicle it could not place."""
    t0 = time.perf_counter()
    ends = {vid: (graph.index[t.start], graph.index[t.goal]) for vid, t in tasks.items()}
    sg = {vid: SearchGraph.of(graph, mu, t.capabilities) for vid, t in tasks.items()}
    ctg = {vid: CostToGo.of(graph, mu, t.capabilities) for vid, t in tasks.items()}
    for caps in {t.capabilities for t in tasks.values()}:  # one batched Dijkstra per kind of vehicle
        CostToGo.of(graph, mu, caps).prepare(ends[v][1] for v, t in tasks.items() if t.capabilities == caps)
    hopeless = _check_reachable(graph, tasks, ends, ctg)
    if hopeless:
        return _failed(hopeless, t0, orders=0)
    setup = _Setup(
        graph=graph, sg=sg, ctg=ctg, ends=ends, blockers=_blockers(graph, ends),
        park_starts=not graph.open_endpoints, deadline=t0 + time_limit,
        usable={vid: t.usable_ah(graph.model) for vid, t in tasks.items()},
    )
    order: list[str] | None = _leavers_first(list(tasks), setup.blockers)
    rng = random.Random(seed)
    tried: set[tuple[str, ...]] = set()
    orders = 0
    while order is not None:
        tried.add(tuple(order))
        orders += 1
        outcome = _plan_order(setup, order)
        if isinstance(outcome, dict):
            return _solved(graph, list(tasks), outcome, t0, orders, order)
        if outcome.vid == order[0] or time.perf_counter() > setup.deadline:
            return _failed(outcome, t0, orders)
        order = _next_order(order, outcome.vid, setup.blockers, rng, tried)
    return _failed(_Failure(outcome.vid, outcome.reason + "; every priority order failed"), t0, orders)


def _next_order(
    order: list[str], failed: str, blockers: dict[str, list[str]], rng: random.Random, tried: set[tuple[str, ...]]
) -> list[str] | None:
    """A restart: `failed` promoted to the front, the others in their order; if that order was tried,
    the others shuffled (seeded) then sorted. With few vehicles, where the sort maps many shuffles to
    one order, an order not tried yet instead of a repeat; None when every order was tried."""
    rest = [v for v in order if v != failed]
    promoted = [failed, *rest]
    if tuple(promoted) not in tried:
        return promoted
    rng.shuffle(rest)
    nxt = [failed, *_leavers_first(rest, blockers)]
    if len(order) > FEW_VEHICLES or tuple(nxt) not in tried:
        return nxt
    untried = [list(p) for p in itertools.permutations(order) if p not in tried]
    return rng.choice(untried) if untried else None


def _check_reachable(
    graph: FleetGraph, tasks: dict[str, Task], ends: dict[str, tuple[int, int]], ctgs: dict[str, CostToGo]
) -> _Failure | None:
    """Tasks no order can serve: goal unreachable, or more charge than usable even alone (§V-C)."""
    for vid, (s, g) in ends.items():
        task, ctg = tasks[vid], ctgs[vid]
        if ctg.h[g][s] == float("inf"):
            only = "" if task.capabilities == "fly+drive" else f", using only {task.capabilities} edges"
            return _Failure(vid, f"no route from {task.start!r} to {task.goal!r} (entering spots only as the goal{only})")
        usable = task.usable_ah(graph.model)
        if ctg.q[g][s] > usable:
            return _Failure(vid, battery_shortfall(task, ctg.q[g][s], usable))
    return None



def _blockers(graph: FleetGraph, ends: dict[str, tuple[int, int]]) -> dict[str, list[str]]:
    """For each vehicle, the others whose bodies parked at their starts touch its goal."""
    rest_nodes = Footprints.of(graph).rest_nodes
    parked: dict[int, list[str]] = {}
    for vid, (start, _) in ends.items():
        for node in rest_nodes[start]:
            parked.setdefault(node, []).append(vid)
    return {vid: [b for b in parked.get(goal, []) if b != vid] for vid, (_, goal) in ends.items()}


def _leavers_first(order: list[str], blockers: dict[str, list[str]]) -> list[str]:
    """`order`, changed only so that a vehicle comes after those parked on its goal (a depth-first
    topological sort; a cycle is cut where it is entered)."""
    members = set(order)
    seen: set[str] = set()
    out: list[str] = []
    for root in order:
        if root in seen:
            continue
        seen.add(root)
        stack = [(root, iter(blockers[root]))]
        while stack:
            vid, todo = stack[-1]
            nxt = next((b for b in todo if b in members and b not in seen), None)
            if nxt is None:
                stack.pop()
                out.append(vid)
            else:
                seen.add(nxt)
                stack.append((nxt, iter(blockers[nxt])))
    return out


def _plan_order(setup: _Setup, order: list[str]) -> dict[str, TimedPath] | _Failure:
    """One pass of prioritized planning in `order`: every path, or the first vehicle that fails."""
    graph, ends, park = setup.graph, setup.ends, setup.park_starts
    res = Reservations(graph)
    if park:
        for vid in order:
            res.park(ends[vid][0], +1)
    paths: dict[str, TimedPath] = {}
    for vid in order:
        start, goal = ends[vid]
        # its own parked body, and the bodies still parked on its goal (they must leave before it comes)
        lifted = [start] + [ends[b][0] for b in setup.blockers[vid] if b not in paths] if park else []
        for node in lifted:
            res.park(node, -1)
        where = f"{graph.ids[start]!r} -> {graph.ids[goal]!r}"
        try:
            ctg = setup.ctg[vid]
            path = sipp(setup.sg[vid], res, start, goal, ctg.h[goal], ctg.q[goal], setup.usable[vid], setup.deadline)
        except SearchTimeout:
            return _Failure(vid, f"time limit reached while planning {where} ({len(paths)} vehicles placed)")
        for node in lifted[1:]:
            res.park(node, +1)
        if path is None:
            return _Failure(vid, f"no collision-free path {where} within the battery ({len(paths)} vehicles placed)")
        _reserve(res, path)
        paths[vid] = path
    return paths


def _reserve(res: Reservations, path: TimedPath) -> None:
    """Claim a planned path's space-time: rests at nodes (start from 0, goal forever) and traversals."""
    for i, node in enumerate(path.nodes):
        if path.depart[i] > path.arrive[i]:
            res.rest(node, path.arrive[i], path.depart[i])
        if i < len(path.edges):
            res.move(path.edges[i], path.depart[i])


def path_entries(graph: FleetGraph, path: TimedPath) -> list[PathEntry]:
    """Plan-file entries: each arrival, and the end of each wait (DESIGN.md "Plan file")."""
    out = []
    for node, arrive, depart in zip(path.nodes, path.arrive, path.depart, strict=True):
        out.append(PathEntry(graph.ids[node], arrive))
        if arrive < depart < float("inf"):
            out.append(PathEntry(graph.ids[node], depart))
    return out


def _solved(graph: FleetGraph, vids: list[str], paths: dict[str, TimedPath], t0: float, orders: int,
            order: list[str]) -> PlanResult:
    return PlanResult(
        ok=True,
        paths={vid: path_entries(graph, paths[vid]) for vid in vids},
        cost=sum(p.cost for p in paths.values()),
        planning_time_s=time.perf_counter() - t0,
        stats={"orders": orders},
        priority=list(order),
    )


def _failed(failure: _Failure, t0: float, orders: int) -> PlanResult:
    tried = f" after {orders} priority order{'s' if orders != 1 else ''}" if orders else ""
    return PlanResult(
        ok=False,
        error=f"{failure.vid}: {failure.reason}{tried}",
        failed_vehicle=failure.vid,
        planning_time_s=time.perf_counter() - t0,
        stats={"orders": orders},
    )
