"""Safe intervals (paper 000 §V-D) of nodes and free departure times of edges, as planned bodies
claim space-time in prioritized planning.

Times are free or blocked. Each node keeps its *safe intervals* [start, end], sorted and disjoint:
the times a body may be at the node without touching any planned body. Each edge keeps the departure
times [start, end] at which a body may enter it and traverse it (linearly, in its duration) without
touching one. Both start fully free and are carved by open windows (a, b) of blocked time; the
window boundaries are instants of exact contact (|d| = 2r), where bodies touch but do not intersect,
so they stay free and a closed free interval never degenerates to a point.

What a planned body blocks comes from the Conflicts windows (services/planner/graph/conflicts.py), turned
into time offsets once per graph (`Footprints`). A body resting at node n over [t1, t2] blocks n and
the nodes touching it over (t1, t2), and departures on each edge f touching it for
tau in (t1 - hi_f d_f, t2 - lo_f d_f). A body traversing edge e over [t1, t1 + d_e] blocks each node
m near e over (t1 + lo d_e, t1 + hi d_e), departures on each edge f whose sweep can touch it for
tau - t1 in the exact window of services/planner/sipp/windows.py (within the Conflicts bound
(self_lo d_e - hi d_f, self_hi d_e - lo d_f), which ignores that the two windows must be reached at the
same instant), and departures on e itself while the two would follow too closely,
|tau - t1| < follow_fraction d_e.

Vehicles not planned yet rest at their starts for all we know: their bodies close the nodes and edges
they touch for all time (revised prioritized planning, Čáp et al. 2015), kept as counters so that the
closure lifts when the vehicle's own plan replaces it.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from services.planner.graph.fleet_graph import FleetGraph
from services.planner.graph.memo import per_graph
from services.planner.sipp.windows import edge_pair_windows

INF = math.inf

Offsets = list[tuple[int, float, float]]


def carve(starts: list[float], ends: list[float], a: float, b: float) -> None:
    """Remove the open window (a, b) from the sorted disjoint closed intervals [starts[i], ends[i]]."""
    if not a < b:
        return
    i = bisect_right(ends, a)  # first interval ending after a
    j = bisect_left(starts, b, i)  # first interval starting at or after b
    if i >= j:
        return
    keep_s: list[float] = []
    keep_e: list[float] = []
    if starts[i] < a:
        keep_s.append(starts[i])
        keep_e.append(a)
    if ends[j - 1] > b:
        keep_s.append(b)
        keep_e.append(ends[j - 1])
    starts[i:j] = keep_s
    ends[i:j] = keep_e


@dataclass(frozen=True)
class Footprints:
    """Per node and edge of a graph, what a body there blocks, as offsets from its own times.

    rest_nodes[n]: n and the nodes whose bodies touch n's. rest_edges[n]: (f, a, b) such that a body
    resting at n over [t1, t2] blocks departures on f in (t1 + a, t2 + b). move_nodes[e]: (m, a, b):
    a traversal of e entered at t1 blocks m over (t1 + a, t1 + b). move_edges[e]: (f, a, b): it blocks
    departures on f in (t1 + a, t1 + b), including e itself (following).
    """

    rest_nodes: list[list[int]]
    rest_edges: list[Offsets]
    move_nodes: list[Offsets]
    move_edges: list[Offsets]

    @staticmethod
    def of(graph: FleetGraph) -> Footprints:
        return per_graph(graph, "footprints", lambda: _build_footprints(graph))


def _offsets(other: np.ndarray, a: np.ndarray, b: np.ndarray) -> Offsets:
    return list(zip(other.tolist(), a.tolist(), b.tolist(), strict=True))


def _build_footprints(graph: FleetGraph) -> Footprints:
    conf = graph.conflicts
    d = graph.duration
    rest_nodes = [[n, *conf.node_nodes[n].tolist()] for n in range(graph.n_nodes)]
    rest_edges = [_offsets(w.other, -w.hi * d[w.other], -w.lo * d[w.other]) for w in conf.node_edges]
    move_nodes = [_offsets(w.other, w.lo * d[e], w.hi * d[e]) for e, w in enumerate(conf.edge_nodes)]
    # edge pairs: the Conflicts candidates, with their exact windows (sipp_windows) instead of the
    # bounding box; following on the same edge is exact already (follow_fraction)
    count = np.array([len(w.other) for w in conf.edge_edges], dtype=np.int64)
    e = np.repeat(np.arange(graph.n_edges), count)
    f = np.concatenate([w.other for w in conf.edge_edges]) if len(e) else np.zeros(0, dtype=np.int64)
    lo, hi = edge_pair_windows(graph.pos, graph.edges, d, e, f, graph.model.radius, graph.model.height)
    move_edges: list[Offsets] = [[] for _ in range(graph.n_edges)]
    for k in np.flatnonzero(lo < hi).tolist():
        move_edges[e[k]].append((int(f[k]), float(lo[k]), float(hi[k])))
    for edge, offsets in enumerate(move_edges):
        follow = float(conf.follow_fraction[edge] * d[edge])
        offsets.append((edge, -follow, follow))
    return Footprints(rest_nodes, rest_edges, move_nodes, move_edges)


class Reservations:
    """The space-time already claimed, as seen by the next vehicle to plan (§V-D: "the safe
    intervals are updated" after each vehicle).

    node_start[n], node_end[n]: safe intervals of node n (from 0). edge_start[e], edge_end[e]: free
    departure times of edge e. node_closed[n], edge_closed[e]: how many parked bodies of vehicles not
    yet planned touch the node or edge (closed for all time while > 0).
    """

    def __init__(self, graph: FleetGraph) -> None:
        self.footprints = Footprints.of(graph)
        self.node_start: list[list[float]] = [[0.0] for _ in range(graph.n_nodes)]
        self.node_end: list[list[float]] = [[INF] for _ in range(graph.n_nodes)]
        self.edge_start: list[list[float]] = [[-INF] for _ in range(graph.n_edges)]
        self.edge_end: list[list[float]] = [[INF] for _ in range(graph.n_edges)]
        self.node_closed = [0] * graph.n_nodes
        self.edge_closed = [0] * graph.n_edges

    def copy(self) -> Reservations:
        """An independent copy (each priority order a replan tries starts from the same claims)."""
        other = Reservations.__new__(Reservations)
        other.footprints = self.footprints
        other.node_start, other.node_end = [s[:] for s in self.node_start], [e[:] for e in self.node_end]
        other.edge_start, other.edge_end = [s[:] for s in self.edge_start], [e[:] for e in self.edge_end]
        other.node_closed, other.edge_closed = self.node_closed[:], self.edge_closed[:]
        return other

    def interval_at(self, node: int, t: float) -> int | None:
        """The index of `node`'s safe interval that holds time `t`, or None: the node is claimed at
        `t` (a search cannot start there then, `search.sipp`)."""
        k = bisect_right(self.node_start[node], t) - 1
        return k if k >= 0 and self.node_end[node][k] >= t else None

    def park(self, node: int, delta: int) -> None:
        """Add (+1) or lift (-1) the all-time closure by a body parked at `node`."""
        fp = self.footprints
        for m in fp.rest_nodes[node]:
            self.node_closed[m] += delta
        for f, _, _ in fp.rest_edges[node]:
            self.edge_closed[f] += delta

    def rest(self, node: int, t1: float, t2: float) -> None:
        """A planned body stays at `node` over [t1, t2] (t2 may be inf: parked at its goal)."""
        fp = self.footprints
        for m in fp.rest_nodes[node]:
            carve(self.node_start[m], self.node_end[m], t1, t2)
        for f, a, b in fp.rest_edges[node]:
            carve(self.edge_start[f], self.edge_end[f], t1 + a, t2 + b)

    @contextmanager
    def moving_meanwhile(self, moves: list[tuple[int, float]]) -> Iterator[None]:
        """The claims of bodies traversing `moves` (edge, entry time) while the block runs, lifted
        after it (what they had carved restored: a vehicle placed before another searches against
        the other's last step into its switch node, which reserved for good would close that
        vehicle's own exits, `services/planner/sipp/replan.py`)."""
        if not moves:
            yield
            return
        fp = self.footprints
        nodes = {m for e, _ in moves for m, _, _ in fp.move_nodes[e]}
        edges = {f for e, _ in moves for f, _, _ in fp.move_edges[e]}
        kept = ([(n, self.node_start[n][:], self.node_end[n][:]) for n in nodes],
                [(f, self.edge_start[f][:], self.edge_end[f][:]) for f in edges])
        for e, t1 in moves:
            self.move(e, t1)
        try:
            yield
        finally:
            for n, starts, ends in kept[0]:
                self.node_start[n], self.node_end[n] = starts, ends
            for f, starts, ends in kept[1]:
                self.edge_start[f], self.edge_end[f] = starts, ends

    def move(self, edge: int, t1: float) -> None:
        """A planned body enters `edge` at t1 and traverses it in its duration."""
        fp = self.footprints
        for m, a, b in fp.move_nodes[edge]:
            carve(self.node_start[m], self.node_end[m], t1 + a, t1 + b)
        for f, a, b in fp.move_edges[edge]:
            carve(self.edge_start[f], self.edge_end[f], t1 + a, t1 + b)
