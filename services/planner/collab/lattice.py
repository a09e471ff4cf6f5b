"""The SLC graph of the team (002 §III, §IV-D): states, C(s), edges from Phi, edge costs.

Drone states (the low-dimensional space, 002 §IV-D) are integers d = (level * H + row) * W + col.
UGV states are u = cell * 9 + heading, heading 8 meaning "not yet known" (used only by PAD's
hybrid graph); team states (the high-dimensional space) are (d * nu + u) * 2 + mode (see
`team_succ`). Edge costs are proportional to the distance each vehicle travels (002 §IV-D); a
team transition moves one robot.

The low-dimensional graph holds every drone controller that does not need the UGV plus a
relaxation of GOTOLANDMARK_DYN: an edge d -> q exists when some UGV cell of the UGV's reachable
area would support it (ignoring only the in-flight visibility). Its least-cost paths therefore
underestimate the team's (002 §IV-A, eq. 1), which makes its cost-to-go an admissible heuristic
for both planners.
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from common.team import controllers as ctl
from common.team.sensing import DIRS, Sensing, line_offsets

ANY_HEADING = 8
Edge = tuple[int, float]
Label = tuple[Hashable, ...]


@dataclass(frozen=True)
class SlcOptions:
    """Which drone motion primitives the lattice offers (002 §V-A).

    metric: "corner", the paper's only use of the metric controllers, a group that turns a corner
    (METRICSTEP(0.5 m) -> METRICTURN(+-90 deg) -> METRICSTEP(1.0 m), from a cardinal heading; in the
    plan it is preceded by a METRICTURN to that heading, a no-op when already flying along it); or
    "free", a METRICTURN to any of 8 headings then one METRICSTEP of `TeamModel.metric_cells`.
    obstacle_trigger: offer WALLFOLLOWING's perceptual OBSTACLE trigger (front or back, 1 m) beside
    T(c)'s opening and landmark triggers.

    The default is the lattice as it was first built ("free", no OBSTACLE trigger), which the
    service and the tests plan with; `SlcOptions.paper()` is the paper's set, which the Tables I-II
    reproduction (bench/collab_experiment.py) and `fleet collab plan --slc paper` use.
    """

    metric: Literal["corner", "free"] = "free"
    obstacle_trigger: bool = False

    @classmethod
    def paper(cls) -> SlcOptions:
        return cls(metric="corner", obstacle_trigger=True)


def _dedupe(rows: np.ndarray, cols: np.ndarray, costs: np.ndarray) -> tuple[np.ndarray, ...]:
    """Keep the cheapest of parallel edges."""
    order = np.lexsort((costs, cols, rows))
    rows, cols, costs = rows[order], cols[order], costs[order]
    keep = np.ones(len(rows), dtype=bool)
    keep[1:] = (rows[1:] != rows[:-1]) | (cols[1:] != cols[:-1])
    return rows[keep], cols[keep], costs[keep]


def ugv_area(sensing: Sensing, cell: tuple[int, int]) -> np.ndarray:
    """The cells the UGV can reach from `cell` (4-connected: its diagonal moves never cut corners)."""
    labels, _ = ndimage.label(sensing.ugv_free)
    comp = labels[cell] if sensing.ugv_ok(*cell) else 0
    return (labels == comp) if comp else np.zeros(sensing.shape, dtype=bool)


class Lattice:
    """Successor generation for drone, UGV and team states on one map, for one UGV area."""

    def __init__(self, sensing: Sensing, ugv_area: np.ndarray, options: SlcOptions | None = None) -> None:
        self.s = sensing
        self.m = sensing.model
        self.options = options or SlcOptions()
        h, w = sensing.shape
        self.h, self.w = h, w
        self.ncell = h * w
        self.nd = sensing.levels * self.ncell
        self.nu = self.ncell * 9 + 1
        self.unresolved = self.nu - 1
        """UGV placeholder of PAD's hybrid graph: the UGV may be anywhere (002 §IV-B, lambda^-1)."""
        self.ugv_area = ugv_area
        self._ugv_area = self.ugv_area.tolist()
        self.drone_edges: list[dict[int, tuple[float, Label]]] = [self._drone_edges(d) for d in range(self.nd)]
        self.drone_succ: list[list[Edge]] = [[(t, c) for t, (c, _) in e.items()] for e in self.drone_edges]
        self._dyn_ld = self._relaxed_dyn()
        self.ld_matrix = self._ld_matrix()
        self._dyn_ld_lists: dict[int, list[Edge]] = {}
        self._dyn_hd: dict[int, list[Edge]] = {}
        self._ugv_succ: dict[int, list[Edge]] = {}
        self._seen_ugv: dict[int, list[int]] = {}
        self.ugv_graph = self._ugv_graph()

    # ---- ids ----------------------------------------------------------------------------------
    def drone_id(self, k: int, r: int, c: int) -> int:
        return (k * self.h + r) * self.w + c

    def drone_pose(self, d: int) -> tuple[int, int, int]:
        k, rem = divmod(d, self.ncell)
        return (k, *divmod(rem, self.w))

    def ugv_id(self, r: int, c: int, heading: int) -> int:
        return (r * self.w + c) * 9 + heading

    def ugv_pose(self, u: int) -> tuple[int, int, int]:
        cell, heading = divmod(u, 9)
        return (*divmod(cell, self.w), heading)

    # ---- drone controllers that do not need the UGV: C(s), Phi and costs ------------------------
    def _drone_edges(self, d: int) -> dict[int, tuple[float, Label]]:
        s, m = self.s, self.m
        k, r, c = self.drone_pose(d)
        out: dict[int, tuple[float, Label]] = {}
        if not s.drone_free(k, r, c):
            return out
        res = s.env.resolution

        def add(t: int, cost: float, label: Label) -> None:
            cost += m.cost_action
            if t != d and (t not in out or cost < out[t][0]):
                out[t] = (cost, label)

        for heading in (0, 2, 4, 6):
            for side in ("left", "right"):
                allowed = ctl.triggers(ctl.WallFollowController(side, heading))  # T(c), 002 §III-A
                if self.options.obstacle_trigger:
                    allowed += (ctl.OBSTACLE,)
                for trig, (r2, c2, n) in ctl.follow_wall(s, k, r, c, side, heading).items():
                    if trig is None or trig in allowed:
                        add(self.drone_id(k, r2, c2), n * res * m.cost_follow, ("WF", side, heading, trig))
        bits = s.landmarks_seen(k, r, c)
        i = 0
        while bits >> i:
            if bits >> i & 1:
                for r2, c2 in ctl.stat_targets(s, k, r, c, i):
                    add(self.drone_id(k, r2, c2), math.hypot(r2 - r, c2 - c) * res * m.cost_landmark, ("STAT", i))
            i += 1
        if s.metric_allowed(r, c) and self.options.metric == "corner":
            cells = tuple(round(x / res) for x in ctl.CORNER_M)
            for heading in (0, 2, 4, 6):
                for turn in (2, -2):
                    ends = ctl.corner_target(s, k, r, c, heading, turn, cells)
                    if ends:
                        cost = 2 * m.cost_metric_turn + sum(ctl.CORNER_M) * m.cost_metric
                        add(self.drone_id(k, *ends[1]), cost, ("CORNER", heading, turn, *cells))
        elif s.metric_allowed(r, c):
            for heading in range(8):
                for n in m.metric_cells:
                    end = ctl.metric_target(s, k, r, c, heading, n)
                    if end:
                        length = n * math.hypot(*DIRS[heading]) * res
                        add(self.drone_id(k, *end), m.cost_metric_turn + length * m.cost_metric, ("METRIC", heading, n))
        zs = s.env.z_levels
        for k2 in range(s.levels):
            if ctl.altitude_ok(s, k, r, c, k2):
                add(self.drone_id(k2, r, c), abs(zs[k2] - zs[k]) * m.cost_altitude, ("ALT", k2))
        return out

    # ---- GOTOLANDMARK_DYN ---------------------------------------------------------------------
    def dyn_cost(self, d: int, t: int) -> float:
        _, r, c = self.drone_pose(d)
        _, r2, c2 = self.drone_pose(t)
        return math.hypot(r2 - r, c2 - c) * self.s.env.resolution * self.m.cost_landmark + self.m.cost_action

    def _relaxed_dyn(self) -> sparse.csr_matrix:
        """Low-dimensional GOTOLANDMARK_DYN edges d -> q: some UGV cell u of the UGV's area is seen
        from d and sees q near it, and the flight d -> q is clear (002 §IV-D relaxation)."""
        s, R, mst = self.s, self.s.ugv_cells, self.m.station_cells
        h, w, nc = self.h, self.w, self.ncell
        rows_all, cols_all = [], []
        for k in range(s.levels):
            vr, vc = [], []
            tr, tc = [], []
            for dr in range(-R, R + 1):
                for dc in range(-R, R + 1):
                    seen = s.ugv_view[k, dr + R, dc + R] & self.ugv_area
                    ur, uc = np.nonzero(seen)
                    vr.append((ur + dr) * w + uc + dc)
                    vc.append(ur * w + uc)
                    if abs(dr) <= mst and abs(dc) <= mst:
                        tr.append(ur * w + uc)
                        tc.append((ur + dr) * w + uc + dc)
            vr_, vc_ = np.concatenate(vr), np.concatenate(vc)
            tr_, tc_ = np.concatenate(tr), np.concatenate(tc)
            view = sparse.csr_matrix((np.ones(len(vr_), np.int32), (vr_, vc_)), shape=(nc, nc))
            target = sparse.csr_matrix((np.ones(len(tr_), np.int32), (tr_, tc_)), shape=(nc, nc))
            pairs = (view @ target).tocoo()
            p, q = pairs.row[pairs.row != pairs.col], pairs.col[pairs.row != pairs.col]
            pr, pc, qr, qc = p // w, p % w, q // w, q % w
            ok = np.ones(len(p), dtype=bool)
            span = 2 * (h + w) + 1
            offs = (qr - pr + h + w) * span + (qc - pc + h + w)
            for off in np.unique(offs):
                sel = offs == off
                dr_, dc_ = (v - h - w for v in divmod(int(off), span))
                for a, b in line_offsets(dr_, dc_):
                    rr, cc = pr[sel] + a, pc[sel] + b
                    inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
                    good = inside.copy()
                    good[inside] = ~s.blocked[k][rr[inside], cc[inside]]
                    ok[sel] &= good
            rows_all.append(p[ok] + k * nc)
            cols_all.append(q[ok] + k * nc)
        rows = np.concatenate(rows_all).astype(np.int64)
        cols = np.concatenate(cols_all).astype(np.int64)
        pr, pc = (rows % nc) // w, (rows % nc) % w
        qr, qc = (cols % nc) // w, (cols % nc) % w
        cost = np.hypot(qr - pr, qc - pc) * s.env.resolution * self.m.cost_landmark + self.m.cost_action
        return sparse.csr_matrix((cost, (rows, cols)), shape=(self.nd, self.nd))

    def _ld_matrix(self) -> sparse.csr_matrix:
        rows = [d for d, e in enumerate(self.drone_succ) for _ in e]
        cols = [t for e in self.drone_succ for t, _ in e]
        costs = [c for e in self.drone_succ for _, c in e]
        dyn = self._dyn_ld.tocoo()
        r, c, x = _dedupe(
            np.concatenate([np.array(rows, dtype=np.int64), dyn.row]),
            np.concatenate([np.array(cols, dtype=np.int64), dyn.col]),
            np.concatenate([np.array(costs, dtype=float), dyn.data]),
        )
        return sparse.csr_matrix((x, (r, c)), shape=(self.nd, self.nd))

    def dyn_relaxed(self, d: int) -> list[Edge]:
        """Low-dimensional GOTOLANDMARK_DYN successors of drone state d (see _relaxed_dyn)."""
        out = self._dyn_ld_lists.get(d)
        if out is None:
            m = self._dyn_ld
            lo, hi = m.indptr[d], m.indptr[d + 1]
            out = list(zip(m.indices[lo:hi].tolist(), m.data[lo:hi].tolist(), strict=True))
            self._dyn_ld_lists[d] = out
        return out

    def dyn_exact(self, d: int, ucell: int) -> list[Edge]:
        """GOTOLANDMARK_DYN successors of drone state d with the UGV in cell `ucell` (002 §III-B)."""
        key = d * self.ncell + ucell
        out = self._dyn_hd.get(key)
        if out is None:
            k, r, c = self.drone_pose(d)
            ur, uc = divmod(ucell, self.w)
            out = [(t, self.dyn_cost(d, t)) for t in (self.drone_id(k, r2, c2) for r2, c2 in ctl.dyn_targets(self.s, k, r, c, ur, uc))]
            self._dyn_hd[key] = out
        return out

    def ugv_cells_seen(self, d: int) -> list[int]:
        """UGV cells (in the UGV's area) whose markers drone state d sees: where DYN can start."""
        out = self._seen_ugv.get(d)
        if out is None:
            k, r, c = self.drone_pose(d)
            R = self.s.ugv_cells
            out = [
                (r - dr) * self.w + c - dc
                for dr in range(-R, R + 1)
                for dc in range(-R, R + 1)
                if self.s.inside(r - dr, c - dc) and self._ugv_area[r - dr][c - dc] and self.s.sees_ugv(k, r, c, r - dr, c - dc)
            ]
            self._seen_ugv[d] = out
        return out

    # ---- UGV metric motion --------------------------------------------------------------------
    def ugv_succ(self, u: int) -> list[Edge]:
        """UGV primitives: forward one cell (any direction when the heading is unknown), turn 45 deg."""
        out = self._ugv_succ.get(u)
        if out is None:
            r, c, heading = self.ugv_pose(u)
            res, m = self.s.env.resolution, self.m
            out = []
            for hd in range(8) if heading == ANY_HEADING else (heading,):
                end = ctl.ugv_forward(self.s, r, c, hd)
                if end:
                    out.append((self.ugv_id(*end, hd), math.hypot(*DIRS[hd]) * res * m.cost_ugv))
            if heading != ANY_HEADING:
                out += [(self.ugv_id(r, c, (heading + t) % 8), m.cost_ugv_turn) for t in (1, -1)]
            self._ugv_succ[u] = out
        return out

    def _ugv_graph(self) -> sparse.csr_matrix:
        """UGV positions (headings ignored) as a graph, for distance fields."""
        rows, cols, costs = [], [], []
        for r, c in zip(*np.nonzero(self.ugv_area), strict=True):
            for hd in range(8):
                end = ctl.ugv_forward(self.s, int(r), int(c), hd)
                if end:
                    rows.append(r * self.w + c)
                    cols.append(end[0] * self.w + end[1])
                    costs.append(math.hypot(*DIRS[hd]) * self.s.env.resolution * self.m.cost_ugv)
        return sparse.csr_matrix((costs, (rows, cols)), shape=(self.ncell, self.ncell))

    def ugv_distance(self, cells: list[int]) -> np.ndarray:
        """Least UGV travel cost from every cell to the nearest of `cells` (inf if unreachable)."""
        if not cells:
            return np.full(self.ncell, np.inf)
        return csgraph.dijkstra(self.ugv_graph.T, indices=cells, min_only=True)

    # ---- team (high-dimensional) successors -----------------------------------------------------
    def team_id(self, d: int, u: int, mode: int = 0) -> int:
        return ((d * self.nu + u) << 1) | mode

    def team_decode(self, x: int) -> tuple[int, int, int]:
        """Team state -> (drone state, UGV state, mode)."""
        d, u = divmod(x >> 1, self.nu)
        return d, u, x & 1

    def team_drone(self, x: int) -> int:
        return (x >> 1) // self.nu

    def team_succ(self, x: int) -> list[Edge]:
        """Successors of team state x (002 §IV-D): one robot moves per transition.

        UGV motions commute with the drone's UGV-independent controllers, so every team path can be
        reordered, at equal cost, so that the UGV moves only in blocks that end with a
        GOTOLANDMARK_DYN (motions after the last one are useless). The mode bit enforces that
        order: mode 1 (UGV moving) allows UGV motions and GOTOLANDMARK_DYN only. This keeps the
        least cost and removes the interleavings.
        """
        nu = self.nu
        y, mode = x >> 1, x & 1
        d, u = divmod(y, nu)
        out = [((t * nu + u) << 1, c) for t, c in self.dyn_exact(d, u // 9)]
        if not mode:
            out += [((t * nu + u) << 1, c) for t, c in self.drone_succ[d]]
        base = d * nu
        out += [(((base + v) << 1) | 1, c) for v, c in self.ugv_succ(u)]
        return out

    def cost_to_go(self, goal: int) -> np.ndarray:
        """Least low-dimensional cost from every drone state to `goal` (the planners' heuristic)."""
        return csgraph.dijkstra(self.ld_matrix.T, indices=goal)

    def drone_label(self, d: int, t: int, ucell: int | None) -> tuple[float, Label]:
        """The cheapest drone controller taking d to t (DYN needs the UGV cell)."""
        best = self.drone_edges[d].get(t, (math.inf, ()))
        if ucell is not None:
            for q, c in self.dyn_exact(d, ucell):
                if q == t and c < best[0]:
                    best = (c, ("DYN", ucell))
        return best
