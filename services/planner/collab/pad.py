"""Planning with Adaptive Dimensionality for the ground-air team (002 §IV-A..D, Gochev et al. [2]).

Low-dimensional states are the drone's (x, y, z); high-dimensional states are team states (drone
x, y, z; UGV x, y, heading). Each iteration:

1. Planning phase: weighted A* (eps_plan) on the hybrid graph G_ad, low-dimensional everywhere
   except inside high-dimensional regions (balls and bands of grid cells, all altitudes).
2. Tracking phase: a search of the full team graph restricted to a tunnel (drone within
   `tunnel` cells of the hybrid path). If it finds pi_t with c(pi_t) <= eps_track * c(pi_ad), pi_t
   is the answer; otherwise a region is added (or grown) where tracking got stuck or where its cost
   rose most above the low-dimensional cost-to-go (002 §IV-B).

Hybrid graph (002 §IV-B): a high-dimensional transition leaving all regions is projected to the
drone state; a low-dimensional transition entering a region leads to lambda^-1 of its target,
represented lazily as one state "UGV anywhere"; from there a GOTOLANDMARK_DYN transition branches
into every UGV cell that supports it (heading still unknown). Every team path thus maps to a
hybrid path that costs no more, so c(pi_ad) <= eps_plan * c*(G_hd) and the result satisfies
c(pi_t) <= eps_plan * eps_track * c*(G_hd) (002 §IV-C). The tracking search may use any heuristic:
ours adds to the tunnel's cost-to-go the UGV's distance to the cells that support the next
GOTOLANDMARK_DYN of the hybrid path.
"""

from __future__ import annotations

import bisect
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import csgraph

from services.planner.collab.arastar import SearchResult, weighted_astar
from services.planner.collab.lattice import ANY_HEADING, Edge, Lattice


@dataclass(frozen=True)
class PadConfig:
    eps_plan: float = 1.5
    """First eps of the planning phase; lowered by `eps_step` to 1 while improving."""
    eps_step: float = 0.25
    eps_track: float = 2.5
    tunnel: int = 2
    """Tunnel half-width in cells (002 §IV-B)."""
    region_radius: int = 4
    region_growth: int = 4
    track_eps: float = 1.5
    """Inflation of the tracking search (its cost is checked against eps_track anyway); the last
    improvement round tracks with 1."""


@dataclass
class PadResult:
    path: list[int] | None
    """Team states (`Lattice.team_id`) of the tracked path."""
    cost: float
    eps: float
    """Proven bound: eps_plan * c(pi_t) / c(pi_ad) <= eps_plan * eps_track."""
    expansions: int
    iterations: int
    """PAD iterations (planning + tracking) up to the first solution."""
    first_solution_s: float | None
    elapsed_s: float
    timed_out: bool
    regions: list[tuple[int, int, int]]
    """(row, col, radius) of the high-dimensional balls (bands are not listed)."""


class HybridGraph:
    """G_ad: drone states d < nd outside regions, nd + team state inside them."""

    def __init__(self, lat: Lattice, regions: Regions, goal: int, h_ld: list[float]) -> None:
        self.lat = lat
        self.goal = goal
        self.h_ld = h_ld
        self.inside: list[bool] = np.tile(regions.mask.ravel(), lat.s.levels).tolist()
        self._supports: dict[int, dict[int, list[int]]] = {}

    def drone(self, x: int) -> int:
        nd = self.lat.nd
        return x if x < nd else self.lat.team_drone(x - nd)

    def h(self, x: int) -> float:
        return self.h_ld[self.drone(x)]

    def is_goal(self, x: int) -> bool:
        return self.drone(x) == self.goal

    def project(self, y: int) -> int:
        """Team state y in G_ad: itself inside a region, its drone state outside (lambda)."""
        d = self.lat.team_drone(y)
        return self.lat.nd + y if self.inside[d] else d

    def is_team_path(self, path: list[int]) -> bool:
        """All states high-dimensional with a known UGV pose: then the hybrid path is a team path."""
        nd, unres = self.lat.nd, self.lat.unresolved
        return all(x >= nd and (u := self.lat.team_decode(x - nd)[1]) != unres and u % 9 != ANY_HEADING for x in path)

    def supports(self, d: int) -> dict[int, list[int]]:
        """GOTOLANDMARK_DYN targets of drone state d -> UGV cells supporting them."""
        out = self._supports.get(d)
        if out is None:
            out = {}
            for ucell in self.lat.ugv_cells_seen(d):
                for t, _ in self.lat.dyn_exact(d, ucell):
                    out.setdefault(t, []).append(ucell)
            self._supports[d] = out
        return out

    def succ(self, x: int) -> list[Edge]:
        lat, inside = self.lat, self.inside
        nd, unres = lat.nd, lat.unresolved
        if x < nd:
            return [(nd + lat.team_id(t, unres) if inside[t] else t, c) for t, c in (*lat.drone_succ[x], *lat.dyn_relaxed(x))]
        d, u, _ = lat.team_decode(x - nd)
        if u != unres:
            return [(self.project(y), c) for y, c in lat.team_succ(x - nd)]
        out = [(nd + lat.team_id(t, unres) if inside[t] else t, c) for t, c in lat.drone_succ[d]]
        sup = None
        for t, c in lat.dyn_relaxed(d):
            if not inside[t]:
                out.append((t, c))
                continue
            sup = sup if sup is not None else self.supports(d)
            out += [(nd + lat.team_id(t, ucell * 9 + ANY_HEADING), c) for ucell in sup.get(t, ())]
        return out


def swept_cells(lat: Lattice, path: list[int]) -> set[int]:
    """Grid cells (row * w + col) the drone passes along a path of drone states."""
    _, r, c = lat.drone_pose(path[0])
    cells = {r * lat.w + c}
    for a, b in zip(path, path[1:], strict=False):
        _, r, c = lat.drone_pose(a)
        _, r2, c2 = lat.drone_pose(b)
        cells.update(rr * lat.w + cc for rr, cc in lat.s.flight_cells(r, c, r2, c2) if lat.s.inside(rr, cc))
    return cells


class Tunnel:
    """The tracking phase's subgraph of G_hd around a hybrid path, and its search heuristic.

    Heuristic: the drone's least low-dimensional cost-to-go inside the tunnel, plus the UGV's
    travel to the cells supporting the next GOTOLANDMARK_DYN of the hybrid path ahead of the
    drone, plus the travel between the supports of the later ones.
    """

    def __init__(self, lat: Lattice, drones: list[int], dyn_edges: list[tuple[int, int]], goal: int, width: int) -> None:
        self.lat = lat
        self.goal = goal
        grid = np.zeros((lat.h, lat.w), dtype=bool)
        for cell in swept_cells(lat, drones):
            r, c = divmod(cell, lat.w)
            grid[max(0, r - width) : r + width + 1, max(0, c - width) : c + width + 1] = True
        member = np.tile(grid.ravel(), lat.s.levels)
        self.member: list[bool] = member.tolist()
        idx = np.flatnonzero(member)
        local = np.full(lat.nd, -1)
        local[idx] = np.arange(len(idx))
        h = np.full(lat.nd, math.inf)
        h[idx] = csgraph.dijkstra(lat.ld_matrix[idx][:, idx].T, indices=int(local[goal]))
        self.h_drone: list[float] = h.tolist()
        guides: list[tuple[float, list[int], np.ndarray]] = []
        for p, q in dyn_edges:
            cells = [uc for uc in lat.ugv_cells_seen(p) if any(t == q for t, _ in lat.dyn_exact(p, uc))]
            if cells and math.isfinite(h[p]):
                guides.append((float(h[p]), cells, lat.ugv_distance(cells)))
        guides.sort(key=lambda g: g[0])
        self.keys = [k for k, _, _ in guides]
        self.fields: list[list[float]] = []
        tail = 0.0
        for j in range(len(guides)):  # guides[j - 1] is the DYN after guides[j] (nearer the goal)
            if j:
                tail += float(np.min(guides[j - 1][2][guides[j][1]]))
            self.fields.append((guides[j][2] + tail).tolist())

    def h(self, x: int) -> float:
        d, u, _ = self.lat.team_decode(x)
        hd = self.h_drone[d]
        j = bisect.bisect_right(self.keys, hd + 1e-9) - 1
        return hd + (self.fields[j][u // 9] if j >= 0 else 0.0)

    def is_goal(self, x: int) -> bool:
        return self.lat.team_drone(x) == self.goal

    def succ(self, x: int) -> list[Edge]:
        drone, member = self.lat.team_drone, self.member
        return [(t, c) for t, c in self.lat.team_succ(x) if member[drone(t)]]


def _discrepancy(lat: Lattice, tunnel: Tunnel, track: SearchResult) -> tuple[int, list[int]]:
    """Drone state where tracking got stuck (no path: the furthest progress) or where the tracked
    path's cost rose most above the tunnel's low-dimensional cost-to-go; and the tracked drone
    states leading there."""
    if track.path is None:
        return min((lat.team_drone(x) for x in track.g), key=lambda d: tunnel.h_drone[d]), []
    excess: dict[int, float] = {}
    for a, b in zip(track.path, track.path[1:], strict=False):
        d = lat.team_drone(a)
        jump = track.g[b] - track.g[a] + tunnel.h_drone[lat.team_drone(b)] - tunnel.h_drone[d]
        excess[d] = excess.get(d, 0.0) + jump
    worst = max(excess, key=excess.__getitem__)
    drones = [lat.team_drone(x) for x in track.path]
    return worst, drones[: drones.index(worst) + 1]


class Regions:
    """The high-dimensional regions of G_ad, over grid cells at all altitudes: balls around places
    where tracking failed, and bands along tracked paths leading to them."""

    def __init__(self, lat: Lattice, cfg: PadConfig) -> None:
        self.lat = lat
        self.cfg = cfg
        self.balls: list[tuple[int, int, int]] = []
        self.mask = np.zeros((lat.h, lat.w), dtype=bool)
        self._rows, self._cols = np.mgrid[0 : lat.h, 0 : lat.w]

    def add_ball(self, r: int, c: int, radius: int) -> None:
        self.balls.append((r, c, radius))
        self.mask |= (self._rows - r) ** 2 + (self._cols - c) ** 2 <= radius * radius

    def refine(self, d: int, leading: list[int]) -> None:
        """Introduce high dimensionality around drone state d (002 §IV-B). A new place gets a ball.
        A place already high-dimensional did not capture the discrepancy, which then comes from
        earlier (typically the UGV's approach, free in G_ad when a region is entered from outside):
        add a band along the tracked drone path leading there; if that adds nothing, grow the
        ball around d."""
        _, r, c = self.lat.drone_pose(d)
        if not self.mask[r, c]:
            self.add_ball(r, c, self.cfg.region_radius)
            return
        before = int(self.mask.sum())
        if len(leading) > 1:
            band = np.zeros_like(self.mask)
            for cell in swept_cells(self.lat, leading):
                band[divmod(cell, self.lat.w)] = True
            self.mask |= ndimage.binary_dilation(band, iterations=self.cfg.tunnel)
        if int(self.mask.sum()) > before:
            return
        near = [i for i, (rr, cc, rad) in enumerate(self.balls) if (rr - r) ** 2 + (cc - c) ** 2 <= rad * rad]
        rr, cc, rad = self.balls.pop(near[0]) if near else (r, c, 0)
        self.add_ball(rr, cc, rad + self.cfg.region_growth)


def _dyn_edges(lat: Lattice, graph: HybridGraph, path: list[int]) -> list[tuple[int, int]]:
    """Drone moves of a hybrid path that no UGV-independent controller makes: GOTOLANDMARK_DYN."""
    out = []
    for a, b in zip(path, path[1:], strict=False):
        p, q = graph.drone(a), graph.drone(b)
        if p != q and q not in lat.drone_edges[p]:
            out.append((p, q))
    return out


def pad(
    lat: Lattice,
    start: int,
    goal: int,
    h_ld: np.ndarray,
    cfg: PadConfig = PadConfig(),
    time_limit: float = math.inf,
    improve_s: float = 0.0,
) -> PadResult:
    """PAD from team state `start` to drone state `goal`; `h_ld` is the low-dimensional cost-to-go."""
    t0 = time.perf_counter()
    deadline = t0 + time_limit
    d0 = lat.team_drone(start)
    _, r0, c0 = lat.drone_pose(d0)
    regions = Regions(lat, cfg)
    regions.add_ball(r0, c0, cfg.region_radius)
    hl: list[float] = h_ld.tolist()
    best: tuple[list[int], float, float] | None = None
    expansions = iterations = 0
    first: float | None = None
    eps_plan, track_eps = cfg.eps_plan, cfg.track_eps
    while True:
        graph = HybridGraph(lat, regions, goal, hl)
        left = deadline - time.perf_counter()
        if left <= 0:
            break
        plan = weighted_astar(graph.project(start), graph.succ, graph.h, graph.is_goal, eps_plan, left)
        expansions += plan.expansions
        if plan.path is None:
            break  # timed out, or no team path exists (G_ad is a relaxation)
        drones = [graph.drone(x) for x in plan.path]
        tunnel = Tunnel(lat, drones, _dyn_edges(lat, graph, plan.path), goal, cfg.tunnel)
        if graph.is_team_path(plan.path):  # nothing left to track: pi_ad is a team path
            track = SearchResult([x - lat.nd for x in plan.path], plan.cost, 1.0, 0, 1, 0.0, 0.0, False)
        else:
            left = max(0.0, deadline - time.perf_counter())
            track = weighted_astar(start, tunnel.succ, tunnel.h, tunnel.is_goal, track_eps, left)
        expansions += track.expansions
        if first is None:
            iterations += 1
        if track.path is not None and track.cost <= cfg.eps_track * plan.cost:
            bound = eps_plan * track.cost / plan.cost
            if best is None or track.cost < best[1]:
                best = (track.path, track.cost, bound)
            best = (best[0], best[1], min(best[2], bound))
            if first is None:
                first = time.perf_counter() - t0
                deadline = t0 + first + improve_s
            # improve (002 §V-D): lower eps_plan to 1, then track without inflation
            if best[2] <= 1.0 or (eps_plan <= 1.0 and track_eps <= 1.0):
                break
            if eps_plan > 1.0:
                eps_plan = max(1.0, eps_plan - cfg.eps_step)
            else:
                track_eps = 1.0
            continue
        if track.timed_out:
            break
        regions.refine(*_discrepancy(lat, tunnel, track))
    return PadResult(
        path=best[0] if best else None,
        cost=best[1] if best else math.inf,
        eps=best[2] if best else math.inf,
        expansions=expansions,
        iterations=iterations,
        first_solution_s=first,
        elapsed_s=time.perf_counter() - t0,
        timed_out=best is None and time.perf_counter() >= deadline,
        regions=regions.balls,
    )
