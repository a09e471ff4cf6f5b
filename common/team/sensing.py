"""The robots' sensors on a map (002 §III-B, §V-A), precomputed per altitude level with numpy.

Both the planner's forward simulation Phi and the simulated execution read the world only
through this class: side IR ranges (wall following), landmark sightings (GOTOLANDMARK_STAT and the
LANDMARK_SIGHTED trigger), sightings of the UGV's fiducials (GOTOLANDMARK_DYN) and free space.
Line of sight is 3D: a sight line is blocked where it passes below an obstacle top.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from common.team.env import Env
from common.team.team_model import TeamModel

# 8 headings, counter-clockwise from +x: (drow, dcol) per 45 degrees. Cardinal ones are even.
DIRS: tuple[tuple[int, int], ...] = ((0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1))
_SAMPLES_PER_CELL = 4


def _shifted(a: np.ndarray, dr: int, dc: int, fill: bool) -> np.ndarray:
    """out[r, c] = a[r + dr, c + dc], `fill` outside the grid."""
    h, w = a.shape
    out = np.full_like(a, fill)
    rs, re = max(0, -dr), min(h, h - dr)
    cs, ce = max(0, -dc), min(w, w - dc)
    if rs < re and cs < ce:
        out[rs:re, cs:ce] = a[rs + dr:re + dr, cs + dc:ce + dc]
    return out


@lru_cache(maxsize=4096)
def line_offsets(dr: int, dc: int) -> tuple[tuple[int, int], ...]:
    """Cells (relative to the start cell) a straight flight between two cell centres sweeps, in order.

    The line is sampled with a small sideways margin so that diagonal moves cannot cut corners.
    """
    n = max(1, int(math.ceil(math.hypot(dr, dc) * 2 * _SAMPLES_PER_CELL)))
    norm = math.hypot(dr, dc) or 1.0
    pr, pc = -dc / norm * 0.05, dr / norm * 0.05
    seen: dict[tuple[int, int], None] = {}
    for i in range(n + 1):
        t = i / n
        for side in (0.0, 1.0, -1.0):
            cell = (math.floor(0.5 + t * dr + side * pr), math.floor(0.5 + t * dc + side * pc))
            seen.setdefault(cell, None)
    return tuple(seen)


class Sensing:
    """Precomputed sensor readings of an Env for a TeamModel.

    Drone readings are indexed [level, row, col]; `blocked` is the drone's occupancy per level and
    `ugv_free` the cells the ground robot may occupy.
    """

    def __init__(self, env: Env, model: TeamModel) -> None:
        self.env = env
        self.model = model
        res = env.resolution
        h, w = env.shape
        self.levels = len(env.z_levels)
        self.blocked = np.stack([env.heights > z - model.clearance for z in env.z_levels])
        self.sensed = np.stack([env.heights > z for z in env.z_levels])
        self.ugv_free = (env.heights <= 0.0) & ~env.no_ugv
        self.metric_ok = ~env.no_metric
        self.ir_cells = max(1, int(math.floor(model.ir_range / res + 1e-9)))
        self.side = self._side_ranges()
        self.landmark_bits = self._landmark_bits()
        self.ugv_cells = max(1, int(math.floor(model.ugv_range / res + 1e-9)))
        self.ugv_view = self._ugv_views()
        # Plain-Python mirrors for the hot loops of the searches.
        self._blocked = self.blocked.tolist()
        self._sensed = self.sensed.tolist()
        self._side = self.side.tolist()
        self._bits = self.landmark_bits.tolist()
        self._ugv_free = self.ugv_free.tolist()
        self._metric_ok = self.metric_ok.tolist()
        self.shape = (h, w)

    # ---- precomputation ---------------------------------------------------------------------
    def _side_ranges(self) -> np.ndarray:
        """side[k, d, r, c]: distance in cells to the first obstacle the horizontal IR beam at level
        k hits (top above the drone's altitude) along cardinal heading 2*d, if in range, else 0."""
        out = np.zeros((self.levels, 4, *self.env.shape), dtype=np.int8)
        for k in range(self.levels):
            for d in range(4):
                dr, dc = DIRS[2 * d]
                found = np.zeros(self.env.shape, dtype=bool)
                for j in range(1, self.ir_cells + 1):
                    hit = _shifted(self.sensed[k], dr * j, dc * j, True) & ~found
                    out[k, d][hit] = j
                    found |= hit
        return out

    def los(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """3D line of sight between points a[i] and b[i] (metres); the end cells are not checked."""
        a = np.asarray(a, dtype=float).reshape(-1, 3)
        b = np.asarray(b, dtype=float).reshape(-1, 3)
        if len(a) == 0:
            return np.zeros(0, dtype=bool)
        res = self.env.resolution
        h, w = self.env.shape
        n = int(np.ceil(np.max(np.linalg.norm((b - a)[:, :2], axis=1)) / res * _SAMPLES_PER_CELL)) + 2
        t = np.linspace(0.0, 1.0, n)[None, :, None]
        pts = a[:, None, :] + (b - a)[:, None, :] * t
        rows = np.floor(pts[..., 1] / res).astype(int)
        cols = np.floor(pts[..., 0] / res).astype(int)
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        tops = np.where(inside, self.env.heights[np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)], np.inf)
        ends = ((rows == rows[:, :1]) & (cols == cols[:, :1])) | ((rows == rows[:, -1:]) & (cols == cols[:, -1:]))
        return ~np.any((tops > pts[..., 2]) & ~ends, axis=1)

    def _landmark_bits(self) -> np.ndarray:
        """bits[k, r, c]: bit i set when landmark i is in camera range and sight at level k."""
        env = self.env
        if len(env.landmarks) > 62:
            raise ValueError("at most 62 landmarks per map")
        bits = np.zeros((self.levels, *env.shape), dtype=np.int64)
        rows, cols = np.nonzero(np.ones(env.shape, dtype=bool))
        xs, ys = (cols + 0.5) * env.resolution, (rows + 0.5) * env.resolution
        for i, lm in enumerate(env.landmarks):
            near = np.hypot(xs - lm.x, ys - lm.y) <= self.model.landmark_range
            for k, z in enumerate(env.z_levels):
                sel = near & ~self.blocked[k][rows, cols]
                a = np.stack([xs[sel], ys[sel], np.full(sel.sum(), z)], axis=1)
                b = np.tile([lm.x, lm.y, lm.z], (len(a), 1))
                seen = self.los(a, b)
                bits[k, rows[sel][seen], cols[sel][seen]] |= np.int64(1) << i
        return bits

    def _ugv_views(self) -> np.ndarray:
        """view[k, dr + R, dc + R, r, c]: a drone at level k in cell (r + dr, c + dc) sees the UGV's
        markers in cell (r, c) (within camera range, line of sight, drone cell free)."""
        env, R = self.env, self.ugv_cells
        res = env.resolution
        h, w = env.shape
        view = np.zeros((self.levels, 2 * R + 1, 2 * R + 1, h, w), dtype=bool)
        ur, uc = np.nonzero(self.ugv_free)
        for k, z in enumerate(env.z_levels):
            for dr in range(-R, R + 1):
                for dc in range(-R, R + 1):
                    if math.hypot(dr, dc) * res > self.model.ugv_range + 1e-9:
                        continue
                    r2, c2 = ur + dr, uc + dc
                    ok = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
                    ok[ok] &= ~self.blocked[k][r2[ok], c2[ok]]
                    a = np.stack([(uc[ok] + 0.5) * res, (ur[ok] + 0.5) * res, np.full(ok.sum(), self.model.ugv_height)], 1)
                    b = np.stack([(c2[ok] + 0.5) * res, (r2[ok] + 0.5) * res, np.full(ok.sum(), z)], 1)
                    seen = self.los(a, b)
                    view[k, dr + R, dc + R, ur[ok][seen], uc[ok][seen]] = True
        return view

    # ---- queries (cells) --------------------------------------------------------------------
    def inside(self, r: int, c: int) -> bool:
        return 0 <= r < self.shape[0] and 0 <= c < self.shape[1]

    def drone_free(self, k: int, r: int, c: int) -> bool:
        return 0 <= r < self.shape[0] and 0 <= c < self.shape[1] and not self._blocked[k][r][c]

    def front_sensed(self, k: int, r: int, c: int) -> bool:
        """The front IR sensor at level k sees an obstacle (or the map edge) in cell (r, c)."""
        return not (0 <= r < self.shape[0] and 0 <= c < self.shape[1]) or self._sensed[k][r][c]

    def ugv_ok(self, r: int, c: int) -> bool:
        return 0 <= r < self.shape[0] and 0 <= c < self.shape[1] and self._ugv_free[r][c]

    def metric_allowed(self, r: int, c: int) -> bool:
        return self._metric_ok[r][c]

    def side_range(self, k: int, r: int, c: int, heading: int) -> int:
        """Cells to the wall along cardinal `heading` (0, 2, 4, 6) if within IR range, else 0."""
        return self._side[k][heading // 2][r][c]

    def landmarks_seen(self, k: int, r: int, c: int) -> int:
        """Bit set of the landmarks the drone's camera sees from this cell."""
        return self._bits[k][r][c]

    def sees_ugv(self, k: int, r: int, c: int, ur: int, uc: int) -> bool:
        """The drone at (k, r, c) sees the UGV's markers in cell (ur, uc)."""
        R = self.ugv_cells
        dr, dc = r - ur, c - uc
        if abs(dr) > R or abs(dc) > R or not self.ugv_ok(ur, uc):
            return False
        return bool(self.ugv_view[k, dr + R, dc + R, ur, uc])

    def flight_cells(self, r: int, c: int, r2: int, c2: int) -> list[tuple[int, int]]:
        """Absolute cells swept by a straight flight from (r, c) to (r2, c2)."""
        return [(r + a, c + b) for a, b in line_offsets(r2 - r, c2 - c)]
