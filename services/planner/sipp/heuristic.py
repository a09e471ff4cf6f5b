"""Exact cost-to-go and charge-to-go lower bounds for SIPP (paper 000 §V-D, h(s) of Alg. 1; §V-C).

Dijkstra backwards from the goal on the eq. 3 edge costs (or the eq. 4-5 edge charges), ignoring the
other vehicles and waits, over the graph a path may use (the edge kinds of the vehicle's capabilities; well-formed infrastructure lets a path
enter a parking spot or helipad only as its goal (Alg. 2 line 10). Waits cost >= 0, so the bound is
admissible and consistent. Tables are cached per (graph, mu, goal).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from common.domain.vehicle_model import Capabilities
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.graph.memo import per_graph

SPOT_KINDS = ("parking", "helipad")
MAX_GOALS = 2048  # tables kept per (graph, mu); the oldest are dropped beyond this


def spot_mask(graph: FleetGraph) -> np.ndarray:
    """Nodes a path may enter only as its goal (§V-D well-formed infrastructure)."""
    return np.isin(np.array(graph.kinds), SPOT_KINDS)


class CostToGo:
    """h[goal][n]: least eq. 3 cost from n to the goal; q[goal][n]: least charge (Ah); inf if cut off.
    Lists, not arrays: the search reads single elements."""

    def __init__(self, graph: FleetGraph, mu: float, capabilities: Capabilities = "fly+drive") -> None:
        # arrays only, no reference to the graph: the per-graph memo must not keep it alive
        self._n = graph.n_nodes
        allowed = graph.allowed_edges(capabilities)
        self._edges = graph.edges[allowed]
        self._charge = graph.charge[allowed]
        u, v = self._edges[:, 0], self._edges[:, 1]
        self.spot = spot_mask(graph)
        into_spot = self.spot[v]
        # reversed graph (v -> u) without edges entering spots; a spot goal is reached by its in-edges
        keep = ~into_spot
        n = graph.n_nodes
        self._cost = graph.edge_cost(mu)[allowed]
        self._rev_cost = csr_matrix((self._cost[keep], (v[keep], u[keep])), shape=(n, n))
        self._rev_charge = csr_matrix((self._charge[keep], (v[keep], u[keep])), shape=(n, n))
        self.h: dict[int, list[float]] = {}
        self.q: dict[int, list[float]] = {}

    @staticmethod
    def of(graph: FleetGraph, mu: float, capabilities: Capabilities = "fly+drive") -> CostToGo:
        return per_graph(graph, ("cost_to_go", float(mu), capabilities), lambda: CostToGo(graph, mu, capabilities))

    def prepare(self, goals: Iterable[int]) -> None:
        """Compute the tables of the goals not cached yet, in one batched Dijkstra per weight."""
        goals = set(goals)
        todo = sorted(g for g in goals if g not in self.h)
        if not todo:
            return
        for old in [g for g in self.h if g not in goals][: max(0, len(self.h) + len(todo) - MAX_GOALS)]:
            del self.h[old], self.q[old]
        # sources: the goal itself, or for a spot goal the tails of its in-edges (offset by that edge)
        rows: list[tuple[int, int, int]] = []  # (goal, source node, edge into the goal or -1)
        for g in todo:
            if self.spot[g]:
                rows += [(g, int(self._edges[e, 0]), int(e)) for e in np.flatnonzero(self._edges[:, 1] == g)]
            else:
                rows.append((g, g, -1))
        sources = sorted({s for _, s, _ in rows})
        col = {s: i for i, s in enumerate(sources)}
        dist_c = np.atleast_2d(dijkstra(self._rev_cost, indices=sources))
        dist_q = np.atleast_2d(dijkstra(self._rev_charge, indices=sources))
        for g in todo:
            h = np.full(self._n, np.inf)
            q = np.full(self._n, np.inf)
            for goal, s, e in rows:
                if goal != g:
                    continue
                h = np.minimum(h, dist_c[col[s]] + (self._cost[e] if e >= 0 else 0.0))
                q = np.minimum(q, dist_q[col[s]] + (self._charge[e] if e >= 0 else 0.0))
            h[g] = q[g] = 0.0
            self.h[g] = h.tolist()
            self.q[g] = q.tolist()
