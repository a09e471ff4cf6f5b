"""The arcs of one time step of the time-expanded network and which pairs of them collide
(paper 000 §V-E, Alg. 3 lines 2 and 6-7; Yu & LaValle 2015, "Optimal multi-robot path planning on
graphs", §III: the time-expanded network, meet and head-on collisions).

On the uniform-time-step graph every edge takes exactly one step dt, so one step of the network has
E move arcs (arc type e: along edge e) and N wait arcs (arc type E + n: stay at node n). Two vehicles
using arcs a and b in the same step move linearly and synchronously over [k dt, (k+1) dt]; their
relative position is then linear too, so `common.domain.geometry.contact_intervals` decides exactly whether
the cylinders touch (endpoints included). Candidate pairs come from `graph.conflicts`, a conservative
superset. The outcome is the same for every step, so it is computed once per graph and cached.

Pairs whose arcs share a tail or a head node are implied by the per-node capacity ("meet")
constraints; the rest (head-on swaps, crossing edges, near misses, neighbouring nodes) are covered
greedily by cliques of the conflict graph, so one row "at most one vehicle on these arcs" per clique
and step replaces many pair rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.domain.geometry import contact_intervals
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.graph.memo import per_graph
from services.planner.ilp.network import time_step


@dataclass(frozen=True)
class ArcTable:
    """Arc types of one step: tail and head node per type (E moves, then N waits); every colliding
    pair as CSR adjacency (`touch`, for prioritized planning); and a clique cover of the collisions
    not implied by node capacity, as CSR from arc type to clique ids (for the model's rows)."""

    n_edges: int  # E: arc type E + n is the wait at node n
    tail: np.ndarray  # (E + N,)
    head: np.ndarray  # (E + N,)
    touch_ptr: np.ndarray  # (E + N + 1,)
    touch_ids: np.ndarray  # arc types colliding with each arc type (itself included)
    clique_ptr: np.ndarray  # (E + N + 1,) CSR row pointers over arc types
    clique_ids: np.ndarray  # clique ids of each arc type
    n_cliques: int
    n_pairs: int  # colliding pairs that needed covering


def arc_endpoints(graph: FleetGraph) -> tuple[np.ndarray, np.ndarray]:
    """Tail and head node of every arc type: the edges, then a self loop per node (waits)."""
    nodes = np.arange(graph.n_nodes)
    return np.concatenate([graph.edges[:, 0], nodes]), np.concatenate([graph.edges[:, 1], nodes])


def candidate_pairs(graph: FleetGraph) -> np.ndarray:
    """(P, 2) arc-type pairs a < b that may collide: edge-edge, edge-wait and wait-wait pairs from
    the conservative `graph.conflicts`."""
    conf = graph.conflicts
    n_e = graph.n_edges
    rows: list[np.ndarray] = []
    for e, w in enumerate(conf.edge_edges):
        rows.append(np.stack([np.full(len(w.other), e), w.other], axis=1))
    for e, w in enumerate(conf.edge_nodes):
        rows.append(np.stack([np.full(len(w.other), e), n_e + w.other], axis=1))
    for n, others in enumerate(conf.node_nodes):
        rows.append(np.stack([np.full(len(others), n_e + n), n_e + others], axis=1))
    pairs = np.concatenate(rows).astype(np.int64) if rows else np.zeros((0, 2), dtype=np.int64)
    pairs = np.sort(pairs, axis=1)
    return np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)


def colliding_pairs(graph: FleetGraph, tail: np.ndarray, head: np.ndarray) -> np.ndarray:
    """The candidate pairs whose bodies touch when both arcs are used in the same step (exact)."""
    pairs = candidate_pairs(graph)
    pos = graph.pos
    a, b = pairs[:, 0], pairs[:, 1]
    lo, hi = contact_intervals(
        pos[tail[a]] - pos[tail[b]], pos[head[a]] - pos[head[b]], 2 * graph.model.radius, graph.model.height
    )
    return pairs[lo < hi]


def clique_cover(n: int, pairs: np.ndarray, must: np.ndarray) -> list[list[int]]:
    """Greedy cliques of the graph with `pairs` as edges that together cover every pair flagged in
    `must` (the others may join a clique but need no row)."""
    adj: list[set[int]] = [set() for _ in range(n)]
    for a, b in pairs:
        adj[a].add(int(b))
        adj[b].add(int(a))
    uncovered = {(int(a), int(b)) for a, b in pairs[must]}
    cliques: list[list[int]] = []
    for a, b in sorted(uncovered):
        if (a, b) not in uncovered:
            continue
        clique = [a, b]
        cand = adj[a] & adj[b]
        while cand:
            # most pairs still to cover with the clique, then most room to grow, then the lowest id
            best = max(cand, key=lambda c: (sum((min(c, m), max(c, m)) in uncovered for m in clique),
                                            len(adj[c] & cand), -c))
            clique.append(best)
            cand &= adj[best]
        for i, x in enumerate(clique):
            for y in clique[i + 1:]:
                uncovered.discard((min(x, y), max(x, y)))
        cliques.append(sorted(clique))
    return cliques


def _csr(n: int, src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row pointers and column ids of the (src -> dst) incidence, rows sorted."""
    order = np.argsort(src, kind="stable")
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=ptr[1:])
    return ptr, dst[order]


def build_arc_table(graph: FleetGraph) -> ArcTable:
    tail, head = arc_endpoints(graph)
    n = len(tail)
    pairs = colliding_pairs(graph, tail, head)
    a, b = pairs[:, 0], pairs[:, 1]
    must = (tail[a] != tail[b]) & (head[a] != head[b])
    cliques = clique_cover(n, pairs, must)
    members = np.array([x for c in cliques for x in c], dtype=np.int64)
    ids = np.repeat(np.arange(len(cliques)), [len(c) for c in cliques])
    clique_ptr, clique_ids = _csr(n, members, ids)
    own = np.arange(n)
    touch_ptr, touch_ids = _csr(n, np.concatenate([a, b, own]), np.concatenate([b, a, own]))
    return ArcTable(graph.n_edges, tail, head, touch_ptr, touch_ids, clique_ptr, clique_ids, len(cliques), int(must.sum()))


def arc_table(graph: FleetGraph) -> ArcTable:
    """The arc table of a graph whose edges all take one time step, computed once per graph."""
    if time_step(graph) is None:
        raise ValueError(f"graph {graph.name!r} has edges of different durations: build it with a time step dt")
    return per_graph(graph, "ilp_arcs", lambda: build_arc_table(graph))
