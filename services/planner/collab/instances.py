"""Random start/goal pairs for the experiments (002 §V-C): the drone's start and goal anywhere,
the UGV starting near the drone; only pairs the low-dimensional graph connects are kept."""

from __future__ import annotations

import math

import numpy as np

from common.team.problem import TeamProblem
from services.planner.collab.planner import TeamPlanner

NEAR_CELLS = 4
"""The UGV starts within this many cells of the drone (002 §V-C: the robots start near each other)."""
MIN_DISTANCE_M = 5.0


def sample_problem(planner: TeamPlanner, seed: int) -> TeamProblem:
    """A reproducible random problem for `seed`."""
    rng = np.random.default_rng(seed)
    s = planner.sensing
    ugv_cells = np.argwhere(s.ugv_free)
    res = s.env.resolution
    while True:
        ur, uc = (int(v) for v in ugv_cells[rng.integers(len(ugv_cells))])
        near = [
            (0, r, c)
            for r in range(ur - NEAR_CELLS, ur + NEAR_CELLS + 1)
            for c in range(uc - NEAR_CELLS, uc + NEAR_CELLS + 1)
            if (r, c) != (ur, uc) and s.drone_free(0, r, c)
        ]
        if not near:
            continue
        start = near[rng.integers(len(near))]
        k, r, c = int(rng.integers(s.levels)), int(rng.integers(s.shape[0])), int(rng.integers(s.shape[1]))
        if not s.drone_free(k, r, c) or math.hypot(r - start[1], c - start[2]) * res < MIN_DISTANCE_M:
            continue
        lat = planner.lattice((ur, uc))
        if math.isfinite(lat.cost_to_go(lat.drone_id(k, r, c))[lat.drone_id(*start)]):
            return TeamProblem(drone_start=start, ugv_start=(ur, uc, int(rng.integers(8))), goal=(k, r, c))
