"""Planning a running mission on from its current state (issue 16): after a vehicle left the plan
(a fault: it lands or stops where its executor decides) or when a vehicle gets a new goal while the
others move.

From the switch time `at` (mission time) on, every remaining vehicle keeps its path up to the first
node it reaches at or after `at` (its *prefix*: the executors fly it unchanged, so the switch needs
no stop) and is planned from that node and time to its goal with prioritized SIPP (paper 000 §V-D),
against:
- the paths of the vehicles that already rest at their goals (for ever) and every prefix;
- the bodies that left the plan (`Sweep`s: somewhere on a segment over a time window, or from its
  start for ever), as closures of every node whose body could touch the segment and every edge
  whose traversal could, over the window (conservative: the segment is sampled at a quarter of a
  body's radius and the sampling step and the sweep's `reach` are added to the contact distance);
- each vehicle's battery: what its task's budget (`Task.usable_ah`) leaves after its prefix.

A prefix's last step (the traversal or wait into its switch node) is reserved only once its own
vehicle is placed: against itself it would close the node's exits for as long as two bodies would
touch (the same body cannot). A vehicle placed earlier searches against the later ones' last
steps that come near its own switch node, for its search alone (`_coming_near`,
`Reservations.moving_meanwhile`): it must leave that node before they come, or wait for them to
pass; it may still cross a later one's last step elsewhere, which the validation of the whole
spliced plan catches (the replan then tries the later one first, `registry.solve_replan`).

Priority: the vehicles that must move first (earliest switch node) first, those whose prefixes end
at one node together, the last to arrive first (`priority`); a vehicle that cannot be placed is
promoted to the front and the others follow in their order, until the time limit. Starts
are not closed for the vehicles planned later (as on open-endpoint maps): a vehicle whose switch node
an earlier path crosses must leave it before, or is promoted (an order is never tried twice). The answer is whole paths (prefix +
new suffix) that the validator checks like any plan.

A vehicle whose switch node is claimed when it gets there by a body that left (resting or coming
down beside it) or by one at rest cannot be placed in any order, nor after the mission stopped
others (a stop only adds a body that left): the replan fails at once, naming every such vehicle
(`PlanResult.unplaceable`; the mission stops them all where they are, `MissionRunner._replan`).
(Named one a replan, an 80-vehicle soak's mission replanned 21 times in 15 s, stopping one vehicle
each time, while up to 13 were so at once.) One at rest there is stranded instead (below). (A
switch node claimed by another's prefix alone is not so: stopped, that one claims only where it
stops.)

Stranding (`Replan.strand`): a vehicle whose goal is out of reach even first in the order (a road
closed for ever by a vehicle that came down on it, its goal under a resting body) is given the
nearest goal it can still reach instead, its switch node itself when that is on the ground (it
stops there), and the orders start again; when it cannot be placed there either (a body comes
down on that node later), the next nearest, up to `STRAND_CANDIDATES`; the answer names it
(`PlanResult.stranded`). One that cannot reach any of those (its own node is closed: a vehicle
came down next to it) and stops on the ground is held where it stops, unplanned (`Leg.hold`), and
the others are planned around it. Without `strand` the replan fails, naming it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from itertools import pairwise

import msgspec
import numpy as np

from common.bus.messages import Replan, Sweep
from common.domain.planfile import PathEntry
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.replanning import Leg, failed, split, touched_by_segment
from services.planner.result import PlanResult, battery_shortfall
from services.planner.sipp.heuristic import CostToGo
from services.planner.sipp.planner import path_entries
from services.planner.sipp.safe_intervals import Footprints, Reservations, carve
from services.planner.sipp.search import SearchGraph, SearchTimeout, TimedPath, sipp

INF = math.inf
STRAND_CANDIDATES = 8
"""How many ground nodes near a stranded vehicle are tried as its new goal."""


def replan_sipp(graph: FleetGraph, replan: Replan, mu: float, time_limit: float, seed: int = 0,
                first: Sequence[str] = ()) -> PlanResult:
    """The spliced paths of every remaining vehicle (see the module doc), the vehicles in `first`
    placed first (in that order); PlanResult names the vehicle it could not place."""
    t0 = time.perf_counter()
    deadline = t0 + time_limit
    fixed, legs = split(graph, replan)
    for caps in {leg.task.capabilities for leg in legs}:  # one batched Dijkstra per kind of vehicle
        CostToGo.of(graph, mu, caps).prepare(leg.goal for leg in legs if leg.task.capabilities == caps)
    for leg in legs:
        ctg = CostToGo.of(graph, mu, leg.task.capabilities)
        if ctg.h[leg.goal][leg.start] == INF:
            return failed(leg.vid, f"no route from {leg.task.start!r} to {leg.task.goal!r}", t0)
        if ctg.q[leg.goal][leg.start] > leg.usable:
            return failed(leg.vid, battery_shortfall(leg.task, ctg.q[leg.goal][leg.start], leg.usable), t0)
    order = priority(legs, first)
    seen = {tuple(leg.vid for leg in order)}
    tried = 0
    stranded: dict[str, str] = {}
    short_goals: dict[str, list[int]] = {}
    """The goals short of its own still to try for each stranded vehicle, nearest first."""
    held: set[str] = set()
    claimed = _claimed(graph, replan.sweeps, fixed)
    if shut := [leg for leg in order if claimed.interval_at(leg.start, leg.depart) is None
                and not (replan.strand and _at_rest(graph, leg))]:
        first_shut = shut[0]
        others = f"; nor can {', '.join(leg.vid for leg in shut[1:])}, whose switch nodes are claimed too" \
            if len(shut) > 1 else ""
        return failed(first_shut.vid, f"its switch node {graph.ids[first_shut.start]!r} is claimed when it gets there "
                                      f"at {first_shut.depart:.1f} s: no priority order can place it{others}", t0,
                      unplaceable=[leg.vid for leg in shut])
    for leg in legs:  # each prefix but its last step (a body does not block itself, `_plan_order`)
        if len(leg.prefix) > 1:
            _reserve_entries(claimed, graph, leg.prefix[:-1], forever=False)
    while True:
        tried += 1
        outcome = _plan_order(graph, claimed.copy(), order, mu, deadline)
        if isinstance(outcome, dict):
            paths = {**fixed}
            for leg in order:
                suffix = outcome[leg.vid]
                # the suffix starts where the prefix ends: at its last entry, or later (a vehicle at rest)
                kept = leg.prefix[:-1] if leg.prefix[-1].t >= leg.depart else leg.prefix
                paths[leg.vid] = kept + path_entries(graph, suffix)
            cost = sum(p.cost for p in outcome.values())
            return PlanResult(ok=True, paths={v: paths[v] for v in replan.base.paths if v in paths}, cost=cost,
                              planning_time_s=time.perf_counter() - t0, stats={"orders": tried},
                              priority=[leg.vid for leg in order], stranded=stranded)
        vid, reason, out_of_time = outcome
        leg = next(leg for leg in order if leg.vid == vid)
        key = tuple([vid] + [x.vid for x in order if x.vid != vid])
        if key in seen and replan.strand and vid not in held and time.perf_counter() <= deadline:
            # its goal is out of its reach even first in the order: it stops short (module doc)
            taken = {x.goal for x in order} | {graph.index[p[-1].node] for p in fixed.values()}
            if vid not in short_goals:
                short_goals[vid] = _stranding_goals(graph, leg, mu, taken)
            short = _short_of_goal(graph, leg, short_goals[vid], taken)
            if short is not None:
                if short.hold:
                    held.add(vid)
                stranded.setdefault(vid, reason)
                order = [short] + [x for x in order if x.vid != vid]
                seen = {tuple(x.vid for x in order)}
                continue
        order = [leg] + [x for x in order if x.vid != vid]
        if key in seen or time.perf_counter() > deadline:  # every order tried, or the time is up
            return failed(vid, f"{reason} after {tried} priority order{'s' if tried > 1 else ''}", t0,
                          timed_out=out_of_time or key not in seen)
        seen.add(key)


def priority(legs: list[Leg], first: Sequence[str] = ()) -> list[Leg]:
    """The first order tried: the vehicles in `first`, then the earliest switch first; the vehicles
    whose prefixes end at one node are placed there together, the one arriving last first. The one
    arriving first must leave that node before the other's last step comes in, and a last step is
    reserved only once its vehicle is placed (module doc): placed first, it left along the edge the
    other was coming up. (In an 80-vehicle soak's replan two such pairs met head-on, 0 m apart on a
    road; the validation caught it, and no time was left on the loaded machine to try another
    order.)"""
    ahead = {vid: i for i, vid in enumerate(first)}
    together: dict[int, float] = {}
    for leg in legs:
        together[leg.start] = min(together.get(leg.start, INF), leg.depart)
    return sorted(legs, key=lambda leg: (ahead.get(leg.vid, len(ahead)), together[leg.start], -leg.depart, leg.vid))


def _short_of_goal(graph: FleetGraph, leg: Leg, goals: list[int], taken: set[int]) -> Leg | None:
    """`leg` stopping short of its goal: at the next of `goals` (taken from the list) that is not
    another vehicle's goal by now, or, when none is left, held where it is if it is at rest there;
    None when neither. (A goal short of its own may fail too: its switch node, a road node, may be
    where a body is coming down; the vehicle then drives on to the next nearest instead of being
    stopped there by the mission, under that body.)"""
    while goals:
        n = goals.pop(0)
        if n == leg.start or n not in taken:
            return dataclasses.replace(leg, goal=n, task=msgspec.structs.replace(leg.task, goal=graph.ids[n]))
    if _at_rest(graph, leg):  # it stays
        return dataclasses.replace(leg, goal=leg.start, hold=True,
                                   task=msgspec.structs.replace(leg.task, goal=leg.task.start))
    return None


def _at_rest(graph: FleetGraph, leg: Leg) -> bool:
    """Whether `leg`'s vehicle stands at its switch node at the switch: its path ended there
    before, or its prefix ends in a wait there on the ground (a car parked until its next drive).
    (Only the first counted: in an 80-vehicle soak's replan a car waiting 22 cm beside a held
    flyer, its node closed by the flyer's sweep, had no goal it could leave for and was not held
    either; the replan failed, naming it, 13 orders in.)"""
    prefix = leg.prefix
    return prefix[-1].t < leg.depart or (len(prefix) > 1 and prefix[-2].node == prefix[-1].node
                                         and graph.kinds[leg.start] != "air")


def _stranding_goals(graph: FleetGraph, leg: Leg, mu: float, taken: set[int]) -> list[int]:
    """The goals short of `leg`'s own it can still reach, nearest first: its switch node when that
    is on the ground, and the ground nodes nearest to it in the horizontal (`STRAND_CANDIDATES` in
    all), not another vehicle's goal, within its battery."""
    here = leg.start
    d = np.hypot(*(graph.pos[:, :2] - graph.pos[here, :2]).T)
    ground = [n for n in np.argsort(d).tolist() if graph.kinds[n] != "air" and n != leg.goal
              and (n == here or n not in taken)][:STRAND_CANDIDATES]
    ctg = CostToGo.of(graph, mu, leg.task.capabilities)
    ctg.prepare(ground)
    return [n for n in ground if ctg.h[n][here] < INF and ctg.q[n][here] <= leg.usable]


def _claimed(graph: FleetGraph, sweeps: list[Sweep], fixed: dict[str, list[PathEntry]]) -> Reservations:
    """What no vehicle of a replan can change: the vehicles that stay as they are, for ever; the
    bodies that left. (Every priority order starts from these and the prefixes: a replan that fails
    tries up to 10 orders.)"""
    res = Reservations(graph)
    for path in fixed.values():
        _reserve_entries(res, graph, path, forever=True)
    for sweep in sweeps:
        block_sweep(res, graph, sweep)
    return res


def _plan_order(graph: FleetGraph, res: Reservations, order: list[Leg], mu: float,
                deadline: float) -> dict[str, TimedPath] | tuple[str, str, bool]:
    """One pass of prioritized planning in `order` on `res` (`_claimed`, a copy: it is changed);
    on failure the vehicle it could not place, why, and whether its search ran out of time."""
    out: dict[str, TimedPath] = {}
    coming = _coming_near(graph, order)
    for leg in order:
        ctg = CostToGo.of(graph, mu, leg.task.capabilities)
        where = f"{graph.ids[leg.start]!r} at {leg.depart:.1f} s -> {graph.ids[leg.goal]!r}"
        path: TimedPath | None
        if leg.hold:  # it stays where it stops, whatever closed that node
            path = TimedPath([leg.start], [leg.depart], [INF], [], 0.0, 0.0)
        else:
            meanwhile = [(edge, x.prefix[-2].t) for x, edge in coming.get(leg.start, ())
                         if x.vid != leg.vid and x.vid not in out and x.prefix[-1].t > leg.depart]
            try:
                with res.moving_meanwhile(meanwhile):  # (their last steps, for its search alone: `_coming_near`)
                    path = sipp(SearchGraph.of(graph, mu, leg.task.capabilities), res, leg.start, leg.goal,
                                ctg.h[leg.goal], ctg.q[leg.goal], leg.usable, deadline, t_start=leg.depart)
            except SearchTimeout:
                return leg.vid, f"time limit reached while planning {where}", True
        if path is None:
            return leg.vid, f"no collision-free path {where} within the battery ({len(out)} vehicles placed)", False
        if len(leg.prefix) > 1:  # its last step into its switch node, now that it is placed
            _reserve_entries(res, graph, leg.prefix[-2:], forever=False)
        for i, node in enumerate(path.nodes):
            if path.depart[i] > path.arrive[i]:
                res.rest(node, path.arrive[i], path.depart[i])
            if i < len(path.edges):
                res.move(path.edges[i], path.depart[i])
        out[leg.vid] = path
    return out


def _coming_near(graph: FleetGraph, order: list[Leg]) -> dict[int, list[tuple[Leg, int]]]:
    """The legs whose prefix's last step is a traversal that comes near a node (the node's body
    could touch its body on the way: `Footprints.move_nodes`, its switch node among them), each
    with that step's edge, by node.
    A vehicle placed before one of these whose switch node that is leaves it on a suffix planned
    against those last steps (for its search alone: reserved for good, a last step would close
    its own vehicle's exits, module doc). Without them an 80-vehicle soak's replan had cf29,
    waiting at g2_0, take off there while cf49 came up the road into g2_0, 12.8 cm apart; the
    validation refused the plan, and in the other order cf29 could not be placed (2026-12-08)."""
    move_nodes = Footprints.of(graph).move_nodes
    near: dict[int, list[tuple[Leg, int]]] = {}
    for leg in order:
        if len(leg.prefix) > 1 and (a := leg.prefix[-2].node) != (b := leg.prefix[-1].node):
            edge = graph.edge_index[(graph.index[a], graph.index[b])]
            for m, _, _ in move_nodes[edge]:
                near.setdefault(m, []).append((leg, edge))
    return near


def _reserve_entries(res: Reservations, graph: FleetGraph, entries: list[PathEntry], forever: bool) -> None:
    """Claim the space-time of plan-file entries (rests and traversals), and the last node for ever."""
    first = graph.index[entries[0].node]
    if entries[0].t > 0:
        res.rest(first, 0.0, entries[0].t)
    for a, b in pairwise(entries):
        u, v = graph.index[a.node], graph.index[b.node]
        if u == v:
            res.rest(u, a.t, b.t)
        else:
            res.move(graph.edge_index[(u, v)], a.t)
    if forever:
        res.rest(graph.index[entries[-1].node], entries[-1].t, INF)


def block_sweep(res: Reservations, graph: FleetGraph, sweep: Sweep) -> None:
    """Close, over the sweep's window (and for ever after it when it rests), every node a body at
    which could touch the swept body, and the departures on every edge whose traversal could."""
    nodes, edges = touched_by_segment(graph, sweep.p0, sweep.p1, sweep.reach)
    end = INF if sweep.rest else sweep.t1
    d = graph.duration
    for n in nodes.tolist():
        carve(res.node_start[n], res.node_end[n], sweep.t0, end)
    for e in edges.tolist():
        carve(res.edge_start[e], res.edge_end[e], sweep.t0 - float(d[e]), end)


