"""ARA* and weighted A* (002 §IV-B) on random grids, and the team lattice (002 §IV-D): its
low-dimensional graph underestimates team costs (002 eq. 1) and its canonical move order keeps
the optimum."""

from __future__ import annotations

import heapq
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.team.env import grid_env
from common.team.sensing import Sensing
from common.team.team_model import TeamModel
from services.planner.collab.arastar import arastar, weighted_astar
from services.planner.collab.lattice import Lattice, ugv_area


def grid_graph(free: np.ndarray, weights: np.ndarray):
    """8-connected grid; entering a cell costs its weight times the step length."""
    h, w = free.shape

    def succ(x: int) -> list[tuple[int, float]]:
        r, c = divmod(x, w)
        out = []
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = r + dr, c + dc
                if (dr or dc) and 0 <= rr < h and 0 <= cc < w and free[rr, cc]:
                    out.append((rr * w + cc, math.hypot(dr, dc) * weights[rr, cc]))
        return out

    return succ


def dijkstra(succ, start: int, goal: int) -> float:
    dist, heap = {start: 0.0}, [(0.0, start)]
    while heap:
        d, x = heapq.heappop(heap)
        if x == goal:
            return d
        if d > dist[x]:
            continue
        for y, c in succ(x):
            if d + c < dist.get(y, math.inf):
                dist[y] = d + c
                heapq.heappush(heap, (d + c, y))
    return math.inf


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), eps0=st.sampled_from([1.0, 1.5, 3.0]))
def test_arastar_bounds_and_final_optimum(seed, eps0):
    rng = np.random.default_rng(seed)
    free = rng.random((12, 12)) > 0.25
    free[0, 0] = free[11, 11] = True
    weights = 1.0 + 3.0 * rng.random((12, 12))
    succ = grid_graph(free, weights)
    goal = 143

    def h(x: int) -> float:  # straight-line distance, admissible as every cell costs >= 1 per step
        return math.hypot(*np.subtract(divmod(x, 12), divmod(goal, 12)))

    opt = dijkstra(succ, 0, goal)
    first = weighted_astar(0, succ, h, lambda x: x == goal, eps0)
    final = arastar(0, succ, h, lambda x: x == goal, eps0=eps0, eps_step=0.5, improve_s=math.inf)
    if math.isinf(opt):
        assert first.path is None and final.path is None and not final.timed_out
        return
    assert first.cost <= eps0 * opt + 1e-9
    assert opt - 1e-9 <= first.cost <= first.eps * opt + 1e-9
    assert final.cost == pytest.approx(opt) and final.eps == 1.0
    assert final.path[0] == 0 and final.path[-1] == goal
    assert sum(c for a, b in zip(final.path, final.path[1:], strict=False) for t, c in succ(a) if t == b) == pytest.approx(opt)


def test_arastar_improves_over_iterations_and_reuses_incons():
    rng = np.random.default_rng(3)
    free = rng.random((30, 30)) > 0.2
    free[0, 0] = free[29, 29] = True
    succ = grid_graph(free, 1.0 + 4.0 * rng.random((30, 30)))
    goal = 899
    res = arastar(0, succ, lambda x: 0.0 if x == goal else 1.0, lambda x: x == goal, eps0=5.0, eps_step=1.0,
                  improve_s=math.inf)
    assert res.iterations >= 2 and res.eps == 1.0
    assert res.cost == pytest.approx(dijkstra(succ, 0, goal))


def test_arastar_stops_at_the_time_limit_without_a_solution():
    res = arastar(0, lambda x: [(x + 1, 1.0)], lambda x: 0.0, lambda x: x == -1, time_limit=0.05)  # endless chain
    assert res.path is None and res.timed_out and res.expansions > 0


# A room (UGV allowed, no metric motions) left of a hallway (no UGV): the drone needs the UGV to
# reach the middle of the room.
ROOM = ["##########", "#........#", "#........#", "#........#", "#........#", "#........#", "#........#", "##########"]


def small_lattice() -> Lattice:
    s = Sensing(grid_env(ROOM, no_metric=[(0.0, 0.0, 5.0, 4.0)]), TeamModel())
    return Lattice(s, ugv_area(s, (1, 1)))


def brute_team_succ(lat: Lattice, x: int) -> list[tuple[int, float]]:
    """Every team transition, in any order (no mode bit): the graph the canonical one reduces."""
    d, u, _ = lat.team_decode(x)
    out = [(lat.team_id(t, u), c) for t, c in (*lat.drone_succ[d], *lat.dyn_exact(d, u // 9))]
    return out + [(lat.team_id(d, v), c) for v, c in lat.ugv_succ(u)]


def test_canonical_team_graph_keeps_the_optimum_and_ld_underestimates():
    lat = small_lattice()
    starts = [(lat.drone_id(0, 1, 2), lat.ugv_id(1, 1, 0)), (lat.drone_id(1, 6, 8), lat.ugv_id(6, 1, 4))]
    goals = [lat.drone_id(1, 4, 5), lat.drone_id(0, 3, 4)]
    for (d0, u0), goal in zip(starts, goals, strict=True):
        h = lat.cost_to_go(goal).tolist()
        start = lat.team_id(d0, u0)

        def hx(x: int, h=h) -> float:
            return h[lat.team_drone(x)]

        def is_goal(x: int, goal=goal) -> bool:
            return lat.team_drone(x) == goal

        canonical = weighted_astar(start, lat.team_succ, hx, is_goal, 1.0)
        brute = weighted_astar(start, lambda x: brute_team_succ(lat, x), hx, is_goal, 1.0)
        assert canonical.cost == pytest.approx(brute.cost)
        assert h[d0] <= canonical.cost + 1e-9  # 002 eq. 1: the drone-only graph underestimates
        assert any(lat.team_decode(x)[1] != u0 for x in canonical.path)  # the UGV had to help
