"""Indoor environments for the ground-air team (002 §V-B): a height map, static landmarks, zones.

A map is a grid of cells of `resolution` metres. Each cell holds the height of the obstacle top
standing on it (0 = free floor, inf = wall to the ceiling), so low furniture, cubicle partitions
and walls differ for a drone flying at one of the map's `z_levels`. Landmarks are static visual
markers; `no_ugv` zones are free space the ground robot may not enter (002 §V-B: hallways closed to
the UGV); `no_metric` zones are where the drone's optical flow cannot support metric motions.

Inputs: our YAML (`fleet-collab-map/1`, decoded strictly with msgspec) and MovingAI `.map` grids.
Cell (row, col) has its centre at x = (col + 0.5) * resolution, y = (row + 0.5) * resolution;
`rows[0]` of a YAML map (and the first grid line of a MovingAI map) is y = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np

from common.domain.mapfile import decode_yaml, read_text
from common.domain.movingai import read_grid
from common.errors import InputError

MAP_FORMAT = "fleet-collab-map/1"
BASE_LEGEND = {".": 0.0, "#": math.inf}

Rect = tuple[float, float, float, float]


class LandmarkSpec(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A static visual landmark (a fiducial on a wall or stand) at (x, y, z) metres."""

    id: str
    x: float
    y: float
    z: float = 1.5


class TeamMapSpec(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The YAML map file. `legend` maps extra grid characters to obstacle-top heights in metres;
    '.' (free) and '#' (wall) are built in. Zones are [xmin, ymin, xmax, ymax] rectangles in metres
    and cover the cells whose centres lie inside."""

    format: Literal["fleet-collab-map/1"]
    name: str
    rows: list[str]
    resolution: float = 0.5
    z_levels: list[float] = msgspec.field(default_factory=lambda: [1.0, 2.0])
    legend: dict[str, float] = {}
    landmarks: list[LandmarkSpec] = []
    no_ugv: list[Rect] = []
    no_metric: list[Rect] = []


@dataclass(frozen=True, eq=False)
class Landmark:
    id: str
    x: float
    y: float
    z: float


@dataclass(frozen=True, eq=False)
class Env:
    """A loaded map: `heights[row, col]` obstacle tops, zones as boolean grids, landmarks, altitudes."""

    name: str
    resolution: float
    heights: np.ndarray
    z_levels: tuple[float, ...]
    landmarks: tuple[Landmark, ...]
    no_ugv: np.ndarray
    no_metric: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.heights.shape  # type: ignore[return-value]

    def cell_of(self, x: float, y: float) -> tuple[int, int]:
        """The (row, col) holding point (x, y)."""
        return int(math.floor(y / self.resolution)), int(math.floor(x / self.resolution))

    def center(self, row: int, col: int) -> tuple[float, float]:
        return ((col + 0.5) * self.resolution, (row + 0.5) * self.resolution)

    def level_of(self, z: float) -> int:
        """Index of the altitude level nearest to z."""
        return min(range(len(self.z_levels)), key=lambda k: abs(self.z_levels[k] - z))


def _zone_mask(rects: list[Rect], shape: tuple[int, int], res: float, source: str, field: str) -> np.ndarray:
    mask = np.zeros(shape, dtype=bool)
    ys = (np.arange(shape[0]) + 0.5) * res
    xs = (np.arange(shape[1]) + 0.5) * res
    for i, (x0, y0, x1, y1) in enumerate(rects):
        if x1 <= x0 or y1 <= y0:
            raise InputError(source, f"{field}[{i}]", "needs xmin < xmax and ymin < ymax")
        rows = (ys > y0) & (ys < y1)
        cols = (xs > x0) & (xs < x1)
        mask |= rows[:, None] & cols[None, :]
    return mask


def env_from_spec(spec: TeamMapSpec, source: str) -> Env:
    """Check a decoded map and build its grids; every problem is an InputError naming the field."""
    if spec.resolution <= 0:
        raise InputError(source, "resolution", "must be positive")
    if not spec.z_levels or any(z <= 0 for z in spec.z_levels) or sorted(set(spec.z_levels)) != spec.z_levels:
        raise InputError(source, "z_levels", "needs strictly increasing positive altitudes")
    if not spec.rows or not spec.rows[0]:
        raise InputError(source, "rows", "the grid is empty")
    width = len(spec.rows[0])
    legend = {**BASE_LEGEND, **spec.legend}
    for ch, h in legend.items():
        if len(ch) != 1 or not h >= 0:
            raise InputError(source, f"legend.{ch}", "needs a single character and a height >= 0")
    heights = np.zeros((len(spec.rows), width))
    for r, row in enumerate(spec.rows):
        if len(row) != width:
            raise InputError(source, f"rows[{r}]", f"has {len(row)} cells, expected {width}")
        unknown = set(row) - legend.keys()
        if unknown:
            raise InputError(source, f"rows[{r}]", f"unknown cell characters {sorted(unknown)} (add them to legend)")
        heights[r] = [legend[ch] for ch in row]
    res = spec.resolution
    landmarks = []
    for i, lm in enumerate(spec.landmarks):
        if not (0 <= lm.x < width * res and 0 <= lm.y < len(spec.rows) * res and lm.z > 0):
            raise InputError(source, f"landmarks[{i}]", f"{lm.id} lies outside the map")
        landmarks.append(Landmark(lm.id, lm.x, lm.y, lm.z))
    if len({lm.id for lm in landmarks}) != len(landmarks):
        raise InputError(source, "landmarks", "landmark ids must be unique")
    return Env(
        name=spec.name,
        resolution=res,
        heights=heights,
        z_levels=tuple(spec.z_levels),
        landmarks=tuple(landmarks),
        no_ugv=_zone_mask(spec.no_ugv, heights.shape, res, source, "no_ugv"),
        no_metric=_zone_mask(spec.no_metric, heights.shape, res, source, "no_metric"),
    )


def grid_env(
    rows: list[str],
    legend: dict[str, float] | None = None,
    landmarks: list[LandmarkSpec] | None = None,
    no_ugv: list[Rect] | None = None,
    no_metric: list[Rect] | None = None,
    name: str = "grid",
) -> Env:
    """An Env from grid rows (rows[0] is y = 0) at 0.5 m cells: quick maps for code and tests."""
    spec = TeamMapSpec(
        format=MAP_FORMAT, name=name, rows=rows, legend=legend or {}, landmarks=landmarks or [],
        no_ugv=no_ugv or [], no_metric=no_metric or [],
    )
    return env_from_spec(spec, name)


def load_yaml_map(path: str | Path) -> Env:
    """A `fleet-collab-map/1` YAML file -> Env (strict: unknown keys are InputErrors)."""
    spec = decode_yaml(read_text(Path(path)), TeamMapSpec, str(path))
    return env_from_spec(spec, str(path))


def load_movingai_map(path: str | Path, resolution: float = 0.5) -> Env:
    """A MovingAI `.map` grid -> Env: blocked cells are walls, no landmarks, no zones."""
    free = read_grid(path)
    heights = np.where(free, 0.0, math.inf)
    return Env(
        name=Path(path).stem,
        resolution=resolution,
        heights=heights,
        z_levels=(1.0, 2.0),
        landmarks=(),
        no_ugv=np.zeros(free.shape, dtype=bool),
        no_metric=np.zeros(free.shape, dtype=bool),
    )
