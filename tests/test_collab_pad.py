"""PAD (002 §IV): on small maps solved optimally, PAD's team plans cost at most
eps_plan * eps_track times the optimum (002 §IV-C), its hybrid graph underestimates the team graph,
and regions are introduced when tracking costs too much."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.team.env import LandmarkSpec, grid_env
from common.team.maps import load_env
from common.team.sensing import Sensing
from common.team.team_model import TeamModel
from services.planner.collab.arastar import weighted_astar
from services.planner.collab.lattice import Lattice, ugv_area
from services.planner.collab.pad import HybridGraph, PadConfig, Regions, pad

pytestmark = pytest.mark.compute

# Two rooms the UGV may use, joined through a hallway it may not enter; no optical flow in rooms.
TWO_ROOMS = [
    "##############",
    "#.....#......#",
    "#.....#......#",
    "#..t..#..tt..#",
    "#.....#......#",
    "#.....#......#",
    "#............#",
    "#............#",
    "#.....#......#",
    "##############",
]


def lattice(env) -> Lattice:
    s = Sensing(env, TeamModel())
    r, c = map(int, np.argwhere(s.ugv_free)[0])
    return Lattice(s, ugv_area(s, (r, c)))


@pytest.fixture(scope="module", params=["two-rooms", "demo-room"])
def lat(request) -> Lattice:
    if request.param == "demo-room":
        return lattice(load_env("demo-room"))
    env = grid_env(TWO_ROOMS, legend={"t": 0.75}, landmarks=[LandmarkSpec("L", 0.6, 0.6, 1.2)],
                   no_ugv=[(0.0, 2.9, 7.0, 4.1)], no_metric=[(0.0, 0.0, 3.0, 3.0), (3.5, 0.0, 7.0, 3.0)])
    return lattice(env)


def problems(lat: Lattice, n: int, seed: int) -> list[tuple[int, int, np.ndarray]]:
    """Random (team start, drone goal, low-dimensional cost-to-go) the drone-only graph connects."""
    rng = np.random.default_rng(seed)
    s = lat.s
    ugv_cells = np.argwhere(lat.ugv_area)
    free = np.argwhere(~s.blocked[0])
    out = []
    while len(out) < n:
        ur, uc = map(int, ugv_cells[rng.integers(len(ugv_cells))])
        dr, dc = map(int, free[rng.integers(len(free))])
        k = int(rng.integers(s.levels))
        gr, gc = map(int, free[rng.integers(len(free))])
        if not s.drone_free(k, gr, gc) or (dr, dc) == (gr, gc):
            continue
        goal = lat.drone_id(k, gr, gc)
        h = lat.cost_to_go(goal)
        d0 = lat.drone_id(0, dr, dc)
        if math.isfinite(h[d0]):
            out.append((lat.team_id(d0, lat.ugv_id(ur, uc, int(rng.integers(8)))), goal, h))
    return out


def optimum(lat: Lattice, start: int, goal: int, h: np.ndarray) -> float:
    hl = h.tolist()
    res = weighted_astar(start, lat.team_succ, lambda x: hl[lat.team_drone(x)], lambda x: lat.team_drone(x) == goal, 1.0)
    return res.cost


def path_cost(lat: Lattice, path: list[int]) -> float:
    return sum(min(c for t, c in lat.team_succ(a) if t == b) for a, b in zip(path, path[1:], strict=False))


@pytest.mark.parametrize("eps_plan,eps_track", [(1.0, 1.1), (1.5, 1.3), (2.0, 2.5)])
def test_pad_cost_within_eps_plan_times_eps_track_of_optimal(lat, eps_plan, eps_track):
    cfg = PadConfig(eps_plan=eps_plan, eps_track=eps_track)
    for start, goal, h in problems(lat, 4, seed=int(eps_plan * 10 + eps_track * 100)):
        opt = optimum(lat, start, goal, h)
        res = pad(lat, start, goal, h, cfg)
        assert res.path is not None and res.path[0] == start and lat.team_drone(res.path[-1]) == goal
        assert path_cost(lat, res.path) == pytest.approx(res.cost)  # a real team path
        assert res.cost <= eps_plan * eps_track * opt + 1e-9
        assert res.cost <= res.eps * opt + 1e-9 and res.eps <= eps_plan * eps_track + 1e-9


def test_hybrid_graph_underestimates_the_team_graph(lat):
    cfg = PadConfig()
    for i, (start, goal, h) in enumerate(problems(lat, 5, seed=7)):
        regions = Regions(lat, cfg)
        d0 = lat.team_drone(start)
        _, r0, c0 = lat.drone_pose(d0)
        regions.add_ball(r0, c0, 2 + i)  # regions of several sizes, some holding the goal
        _, rg, cg = lat.drone_pose(goal)
        regions.add_ball(rg, cg, i)
        graph = HybridGraph(lat, regions, goal, h.tolist())
        hybrid = weighted_astar(graph.project(start), graph.succ, graph.h, graph.is_goal, 1.0)
        assert h[d0] - 1e-9 <= hybrid.cost <= optimum(lat, start, goal, h) + 1e-9


def test_pad_introduces_regions_when_tracking_costs_too_much(lat):
    iterations = []
    for start, goal, h in problems(lat, 6, seed=11):
        res = pad(lat, start, goal, h, PadConfig(eps_plan=1.0, eps_track=1.05))
        assert res.cost <= 1.05 * optimum(lat, start, goal, h) + 1e-9
        iterations.append(res.iterations)
        assert len(res.regions) >= 1
    assert max(iterations) > 1
