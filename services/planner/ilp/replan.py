"""Planning a running mission on with the multi-commodity flow ILP (issue 16; paper 000 §V-E), from
the same state as SIPP's replanning (`services/planner/replanning.py`): on the ILP's own network.

The plan being replanned must be on the ILP's time steps (a plan the ILP made, or replanned): every
entry at a multiple of `dt`, one per step. The network's time 0 is the first step at or after the
switch time `at` (`origin`); every remaining vehicle is at a node there (the entry of that step), so
the ILP plans each from that node, as from a start that need not be a parking spot (a vehicle in the
air continues from its air node, a driving one from the road node it reaches). A vehicle at rest
that gets a new goal must first wait at its node until it may leave (`TURN_ALLOWANCE_S`): its
columns before then are the wait there. Every other vehicle's columns that would touch:
- a vehicle resting at its goal (for ever): the arcs that collide with its wait there (`ArcTable`);
- a body that left (`Sweep`): the arcs over its nodes and edges that could touch it
  (`touched_by_segment`), in the steps that overlap its time window (for ever when it rests),
are removed before the model is built, so the ILP's own flow, capacity and clique rows keep the
remaining vehicles apart and the battery rows hold each to what its prefix left (eq. 6). The
horizons tried reach as far as a detour around a closure for ever may need (any route: the graph's
node count more; the fewest steps ignore the closures). The answer is the prefixes with the ILP's
paths spliced on, validated whole by the caller.
"""

from __future__ import annotations

import math
import time

import numpy as np

from common.bus.messages import Replan
from common.domain.planfile import PathEntry
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.ilp.arcs import ArcTable, arc_table
from services.planner.ilp.network import WAIT, Columns, Fleet, time_step
from services.planner.ilp.planner import plan_fleet
from services.planner.replanning import Leg, failed, split, touched_by_segment
from services.planner.result import PlanResult

ALIGN = 1e-6
"""s: how far from a multiple of dt a plan entry may be and still count as on a step."""


class Closures:
    """Arc types closed to the replanned vehicles, per window of steps (inclusive; `None`: for ever)."""

    def __init__(self, n_types: int) -> None:
        self.n_types = n_types
        self.windows: list[tuple[np.ndarray, int, int | None]] = []

    def close(self, types: np.ndarray, first: int, last: int | None) -> None:
        if len(types) and (last is None or last >= max(first, 0)):
            mask = np.zeros(self.n_types, dtype=bool)
            mask[types] = True
            self.windows.append((mask, max(first, 0), last))

    def open_columns(self, cols: Columns) -> np.ndarray:
        keep = np.ones(len(cols), dtype=bool)
        for mask, first, last in self.windows:
            hit = mask[cols.ptype] & (cols.step >= first)
            if last is not None:
                hit &= cols.step <= last
            keep &= ~hit
        return keep

    @property
    def last_step(self) -> int:
        """The last step a window with an end closes (0 with none)."""
        return max((last for _, _, last in self.windows if last is not None), default=0)


def colliding(table: ArcTable, arc_type: int) -> np.ndarray:
    """The arc types whose bodies touch a body on `arc_type` in the same step (itself included)."""
    return table.touch_ids[table.touch_ptr[arc_type]:table.touch_ptr[arc_type + 1]]


def replan_ilp(graph: FleetGraph, replan: Replan, mu: float, time_limit: float, seed: int = 0) -> PlanResult:
    """The spliced paths of every remaining vehicle (module doc); on failure PlanResult says why."""
    t0 = time.perf_counter()
    dt = time_step(graph)
    if dt is None:
        return PlanResult(ok=False, error=f"the ILP replans on a graph whose edges take one time step; {graph.name!r}"
                                          " is not one: replan with sipp", planning_time_s=time.perf_counter() - t0)
    origin = math.ceil(replan.at / dt - ALIGN)
    at = origin * dt
    fixed, legs = split(graph, Replan(base=replan.base, at=at - ALIGN, left=replan.left, sweeps=replan.sweeps,
                                      goals=replan.goals))
    for leg in legs:
        moving = leg.prefix[-1].t > at - ALIGN
        if moving and abs(leg.prefix[-1].t - at) > ALIGN:
            return failed(leg.vid, f"its path is not on the ILP's {dt:g} s steps at {at:.2f} s (a plan SIPP "
                                   "made or replanned): replan with sipp", t0)
    if not legs:
        return PlanResult(ok=True, paths={v: p for v, p in replan.base.paths.items() if v in fixed},
                          planning_time_s=time.perf_counter() - t0)
    table = arc_table(graph)
    closures = Closures(len(table.tail))
    for path in fixed.values():
        closures.close(colliding(table, graph.n_edges + graph.index[path[-1].node]), 0, None)
    for sweep in replan.sweeps:
        nodes, edges = touched_by_segment(graph, sweep.p0, sweep.p1, sweep.reach)
        first = math.ceil((sweep.t0 - at) / dt - 1.0 - ALIGN)  # steps [k, k+1] dt overlapping the window
        last = None if sweep.rest else math.floor((sweep.t1 - at) / dt + ALIGN)
        closures.close(np.concatenate([edges, graph.n_edges + nodes]), first, last)
    delays = np.array([max(0, math.ceil((leg.depart - at) / dt - ALIGN)) for leg in legs], dtype=np.int64)
    fleet = Fleet.of(graph, [graph.ids[leg.start] for leg in legs], [graph.ids[leg.goal] for leg in legs], mu,
                     [leg.task.capabilities for leg in legs], [leg.usable for leg in legs])

    def allowed(cols: Columns) -> np.ndarray:
        keep = closures.open_columns(cols)
        for i in np.flatnonzero(delays):  # a vehicle at rest waits at its node until it may leave
            early = (cols.veh == i) & (cols.step < delays[i])
            keep &= ~early | ((cols.kind == WAIT) & (cols.tail == fleet.starts[i]))
        return keep

    result = plan_fleet(graph, fleet, {leg.vid: leg.task for leg in legs}, t0 + time_limit, seed, t0,
                        allowed=allowed, delays=delays, slack_steps=closures.last_step + graph.n_nodes)
    if not result.ok:
        return result
    paths = {**fixed, **{leg.vid: _spliced(leg, result.paths[leg.vid], origin, dt) for leg in legs}}
    return PlanResult(ok=True, paths={v: paths[v] for v in replan.base.paths if v in paths}, cost=result.cost,
                      planning_time_s=time.perf_counter() - t0, mip_gap=result.mip_gap, stats=result.stats)


def _spliced(leg: Leg, suffix: list[PathEntry], origin: int, dt: float) -> list[PathEntry]:
    """The leg's prefix and the ILP's path from step `origin` on (its times counted from there), each
    entry on its step (step x dt, so that the next replan finds it there exactly)."""
    kept = leg.prefix[:-1] if leg.prefix[-1].t > (origin * dt) - ALIGN else leg.prefix
    return kept + [PathEntry(e.node, (origin + round(e.t / dt)) * dt) for e in suffix]
