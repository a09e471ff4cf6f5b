"""The map file: YAML decoded strictly into msgspec Structs (maps/README.md documents every field).

Unknown keys, wrong types, invalid YAML and references to missing nodes are `InputError`s naming the
file, the field and the problem. Geometric checks that need the built graph (spots too close,
unreachable parking) live in `services.planner.graph.fleet_graph`.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import msgspec
import yaml

from common.domain.vehicle_model import VehicleModel
from common.errors import InputError

MAPS_DIR = Path(__file__).resolve().parents[2] / "maps"

_Strict = {"frozen": True, "forbid_unknown_fields": True}

MAX_AIR_NODES = 10_000
"""Most air grid points a map may ask for (the shipped maps have at most 722): a finer grid is a typo."""


class RoadNode(msgspec.Struct, **_Strict):
    x: float
    y: float


class Roads(msgspec.Struct, **_Strict):
    """The road network on the ground (z = 0): nodes by id, two-way and one-way edges."""

    nodes: dict[str, RoadNode]
    two_way: list[tuple[str, str]] = []
    one_way: list[tuple[str, str]] = []


class ParkingSpot(msgspec.Struct, **_Strict):
    """A spot beside a road, joined to road node `road` by a short two-way drive edge."""

    id: str
    x: float
    y: float
    road: str


class Helipad(msgspec.Struct, **_Strict):
    """An elevated pad at height z: a start or goal reached only through the air."""

    id: str
    x: float
    y: float
    z: float


class AirRegion(msgspec.Struct, **_Strict):
    """Air nodes on a square grid of `spacing` inside `bounds` [xmin, ymin, xmax, ymax], one layer per height."""

    bounds: tuple[float, float, float, float]
    layers: list[float]
    spacing: float
    diagonals: bool = True


class NoFlyZone(msgspec.Struct, **_Strict):
    """A prism: a polygon [[x, y], ...] between z[0] and z[1]."""

    name: str
    polygon: list[tuple[float, float]]
    z: tuple[float, float] = (0.0, 1.0e9)


class Obstacle(msgspec.Struct, **_Strict):
    """An axis-aligned box from `min` [x, y, z] to `max` [x, y, z]."""

    name: str
    min: tuple[float, float, float]
    max: tuple[float, float, float]


class MapSpec(msgspec.Struct, **_Strict):
    name: str
    roads: Roads
    size: tuple[float, float] | None = None
    parking: list[ParkingSpot] = []
    helipads: list[Helipad] = []
    air: AirRegion | None = None
    no_fly: list[NoFlyZone] = []
    obstacles: list[Obstacle] = []
    vehicle: VehicleModel = VehicleModel()
    time_step: float = 2.0
    description: str = ""


_PATH_IN_ERROR = re.compile(r"at `\$(\.[^`]*)`")


def _split_msgspec_error(exc: Exception) -> tuple[str, str]:
    """msgspec says 'Object missing required field `x` - at `$.roads.nodes.a`': split field and problem."""
    text = str(exc)
    match = _PATH_IN_ERROR.search(text)
    if not match:
        return "", text
    problem = text[: match.start()].rstrip(" -")
    return match.group(1).lstrip("."), problem


def decode_yaml(data: bytes | str, typ: type, source: str):
    """Decode YAML strictly into `typ`; any failure is an InputError naming source, field and problem."""
    try:
        raw = yaml.safe_load(data)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else ""
        raise InputError(source, where, f"invalid YAML ({getattr(exc, 'problem', None) or exc})") from None
    if raw is None:
        raise InputError(source, "", "file is empty")
    try:
        return msgspec.convert(raw, typ, strict=True)
    except msgspec.ValidationError as exc:
        field, problem = _split_msgspec_error(exc)
        raise InputError(source, field, problem) from None


def resolve_map_path(name_or_path: str | Path) -> Path:
    """A shipped map name ('town') or a path to a YAML file."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.exists():
        return path
    return MAPS_DIR / f"{name_or_path}.yaml"


def read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(str(path), "", f"cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise InputError(str(path), f"byte {exc.start}", "not UTF-8 text") from None


def load_map(name_or_path: str | Path) -> MapSpec:
    """Read and check a map file. References are checked here; geometry in the graph builder."""
    path = resolve_map_path(name_or_path)
    spec: MapSpec = decode_yaml(read_text(path), MapSpec, str(path))
    check_references(spec, str(path))
    return spec


def spot_pose(spec: MapSpec, spot: str, source: str = "") -> tuple[float, float, float, float]:
    """Where a vehicle starting at `spot` stands: (x, y, z, yaw). A parked car faces the road node
    its spot leads to (the graph's access edge, §V-A); on a helipad or a road node (where a vehicle
    that only flies starts) it faces +x."""
    for p in spec.parking:
        if p.id == spot:
            road = spec.roads.nodes[p.road]
            return p.x, p.y, 0.0, math.atan2(road.y - p.y, road.x - p.x)
    for h in spec.helipads:
        if h.id == spot:
            return h.x, h.y, h.z, 0.0
    if spot in spec.roads.nodes:
        node = spec.roads.nodes[spot]
        return node.x, node.y, 0.0, 0.0
    raise InputError(source or spec.name, spot, f"not a parking spot, helipad or road node of map {spec.name!r}")


def _check_finite(value: object, field: str, source: str) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise InputError(source, field, "must be a finite number")
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list | tuple) else ()
    for key, item in items:
        _check_finite(item, f"{field}[{key}]" if isinstance(key, int) else f"{field}.{key}".lstrip("."), source)


def check_references(spec: MapSpec, source: str) -> None:
    """Edges and spots must name existing road nodes; ids must be unique; numbers must make sense."""
    _check_finite(msgspec.to_builtins(spec), "", source)
    road = spec.roads.nodes
    for field in ("two_way", "one_way"):
        for i, (u, v) in enumerate(getattr(spec.roads, field)):
            for end in (u, v):
                if end not in road:
                    raise InputError(source, f"roads.{field}[{i}]", f"edge names unknown road node {end!r}")
            if u == v:
                raise InputError(source, f"roads.{field}[{i}]", f"edge from {u!r} to itself")
    seen: set[str] = set(road)
    for field, items in (("parking", spec.parking), ("helipads", spec.helipads)):
        for i, item in enumerate(items):
            if item.id in seen:
                raise InputError(source, f"{field}[{i}].id", f"id {item.id!r} is used twice")
            seen.add(item.id)
    for i, spot in enumerate(spec.parking):
        if spot.road not in road:
            raise InputError(source, f"parking[{i}].road", f"unknown road node {spot.road!r}")
    if spec.air is not None:
        xmin, ymin, xmax, ymax = spec.air.bounds
        if xmax < xmin or ymax < ymin:
            raise InputError(source, "air.bounds", "must be [xmin, ymin, xmax, ymax] with min <= max")
        if spec.air.spacing <= 0:
            raise InputError(source, "air.spacing", "must be positive")
        if not spec.air.layers or any(z <= 0 for z in spec.air.layers):
            raise InputError(source, "air.layers", "needs at least one layer, every height above 0")
        if sorted(spec.air.layers) != list(spec.air.layers) or len(set(spec.air.layers)) != len(spec.air.layers):
            raise InputError(source, "air.layers", "heights must be strictly increasing")
        points = len(spec.air.layers) * math.prod(math.floor(d / spec.air.spacing) + 1 for d in (xmax - xmin, ymax - ymin))
        if points > MAX_AIR_NODES:
            raise InputError(source, "air.spacing", f"{points} air grid points (at most {MAX_AIR_NODES}): too fine for the bounds")
    for i, zone in enumerate(spec.no_fly):
        if len(zone.polygon) < 3:
            raise InputError(source, f"no_fly[{i}].polygon", "needs at least 3 corners")
        if zone.z[1] <= zone.z[0]:
            raise InputError(source, f"no_fly[{i}].z", "must be [zmin, zmax] with zmin < zmax")
    for i, box in enumerate(spec.obstacles):
        if any(hi <= lo for lo, hi in zip(box.min, box.max, strict=True)):
            raise InputError(source, f"obstacles[{i}]", "max must exceed min on every axis")
    if spec.time_step <= 0:
        raise InputError(source, "time_step", "must be positive")
