"""Which nodes and edges would bring two bodies into contact (paper 000 §V-D: "the nodes within a
radius r of each path"), including edges that cross without sharing a node.

For each pair the precomputation keeps *where* along an edge the contact can happen (a window of the
edge parameter s in [0, 1]), so planners can turn a vehicle's timed path into exact or conservative
blocked time windows for the others.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from common.domain.geometry import bodies_touch, segment_hits_body, segment_pair_windows


@dataclass
class Windows:
    """Partners of one node or edge, with parameter windows (lo, hi) on the partner edge (for node
    partners of an edge: on this edge), and for edge-edge pairs also the window on this edge."""

    other: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    self_lo: np.ndarray | None = None
    self_hi: np.ndarray | None = None


@dataclass
class Conflicts:
    """node_nodes[n]: nodes whose bodies touch n's. node_edges[n]: edges whose traversal touches a body
    resting at n, with the window of the edge's parameter. edge_nodes[e]: the same from the edge's
    side. edge_edges[e]: edges f (f != e) whose traversal can touch a body on e, with the windows on f
    (lo, hi) and on e (self_lo, self_hi). follow_fraction[e]: two bodies traversing the same edge e one
    behind the other touch while their entry times differ by less than this fraction of its duration."""

    node_nodes: list[np.ndarray]
    node_edges: list[Windows]
    edge_nodes: list[Windows]
    edge_edges: list[Windows]
    follow_fraction: np.ndarray

    def edge_pair_count(self) -> int:
        return sum(len(w.other) for w in self.edge_edges) // 2


def _reach(radius: float, height: float) -> float:
    return float(np.hypot(2 * radius, height))


def compute_conflicts(pos: np.ndarray, edges: np.ndarray, radius: float, height: float) -> Conflicts:
    n, m = len(pos), len(edges)
    reach = _reach(radius, height)
    tree = cKDTree(pos)

    node_nodes: list[list[int]] = [[] for _ in range(n)]
    for i, j in tree.query_pairs(reach, output_type="ndarray"):
        if bodies_touch(pos[i] - pos[j], radius, height):
            node_nodes[i].append(int(j))
            node_nodes[j].append(int(i))

    a, b = pos[edges[:, 0]], pos[edges[:, 1]]
    mid = (a + b) / 2
    half = np.linalg.norm(b - a, axis=1) / 2

    # node-edge windows
    ne_rows: list[tuple[int, int]] = []
    for e, near in enumerate(tree.query_ball_point(mid, half + reach)):
        ne_rows.extend((e, int(k)) for k in near)
    node_e = [[[], [], []] for _ in range(n)]
    edge_n = [[[], [], []] for _ in range(m)]
    if ne_rows:
        rows = np.array(ne_rows)
        lo, hi = segment_hits_body(a[rows[:, 0]], b[rows[:, 0]], pos[rows[:, 1]], radius, height)
        for (e, k), l_, h_ in zip(rows, lo, hi, strict=True):
            if l_ < h_:
                node_e[k][0].append(e), node_e[k][1].append(l_), node_e[k][2].append(h_)
                edge_n[e][0].append(k), edge_n[e][1].append(l_), edge_n[e][2].append(h_)

    # edge-edge windows (each unordered pair once, then mirrored)
    edge_e = [[[], [], [], [], []] for _ in range(m)]
    follow = np.zeros(m)
    if m:
        etree = cKDTree(mid)
        pairs = etree.query_pairs(2 * float(half.max()) + reach, output_type="ndarray")
        if len(pairs):
            e, f = pairs[:, 0], pairs[:, 1]
            keep = np.linalg.norm(mid[e] - mid[f], axis=1) < half[e] + half[f] + reach
            e, f = e[keep], f[keep]
            slo, shi, ulo, uhi = segment_pair_windows(a[e], b[e], a[f], b[f], radius, height)
            for i in np.flatnonzero(slo < shi):
                ei, fi = int(e[i]), int(f[i])
                for x, y, xl, xh, yl, yh in ((ei, fi, slo[i], shi[i], ulo[i], uhi[i]), (fi, ei, ulo[i], uhi[i], slo[i], shi[i])):
                    w = edge_e[x]
                    w[0].append(y), w[1].append(yl), w[2].append(yh), w[3].append(xl), w[4].append(xh)
        follow = _follow_fraction(b - a, radius, height)

    def pack(w: list[list]) -> Windows:
        arrs = [np.array(x, dtype=float) for x in w]
        other = arrs[0].astype(np.int64)
        if len(w) == 3:
            return Windows(other, arrs[1], arrs[2])
        return Windows(other, arrs[1], arrs[2], arrs[3], arrs[4])

    return Conflicts(
        node_nodes=[np.array(x, dtype=np.int64) for x in node_nodes],
        node_edges=[pack(w) for w in node_e],
        edge_nodes=[pack(w) for w in edge_n],
        edge_edges=[pack(w) for w in edge_e],
        follow_fraction=follow,
    )


def _follow_fraction(vec: np.ndarray, radius: float, height: float) -> np.ndarray:
    """Two bodies on the same edge, the second entering tau later: their offset is vec * tau / T, so
    they touch while |tau| / T < the fraction returned (§IV: cylinders never intersect)."""
    horiz = np.linalg.norm(vec[:, :2], axis=1)
    vert = np.abs(vec[:, 2])
    with np.errstate(divide="ignore"):
        fh = np.where(horiz > 1e-12, 2 * radius / horiz, np.inf)
        fv = np.where(vert > 1e-12, height / vert, np.inf)
    return np.minimum(fh, fv)
