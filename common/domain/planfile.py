"""The plan file (DESIGN.md, "Plan file"): the contract between planners, validator and executors.

``{"format": "fleet-plan/1", "map", "planner", "mu", "model", "graph", "tasks", "paths", "cost",
"planning_time_s"}`` plus ``dt`` for plans made on the uniform-time-step graph (ILP) and the ILP's
proven ``mip_gap``. A path entry is the time a vehicle is at a node; consecutive entries at different
nodes traverse the edge between them linearly; before the first entry a vehicle sits at its start,
after the last at its goal forever.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import msgspec

from common.domain.vehicle_model import EdgeKind, NodeKind, VehicleModel

PLAN_FORMAT = "fleet-plan/1"


class PlanModel(VehicleModel, frozen=True, forbid_unknown_fields=True):
    """The vehicle model plus the graph's eq. 3 normalisers W_max (J) and t_max (s)."""

    w_max: float = 1.0
    t_max: float = 1.0


class GraphNode(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    pos: tuple[float, float, float]
    kind: NodeKind


class PlanGraph(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Nodes by id and directed edges ``[u, v, kind]`` (a two-way road appears once per direction)."""

    nodes: dict[str, GraphNode]
    edges: list[tuple[str, str, EdgeKind]]


class Task(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    start: str
    goal: str


class PathEntry(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    node: str
    t: float


class Plan(msgspec.Struct, frozen=True, forbid_unknown_fields=True, omit_defaults=True):
    map: str
    planner: str
    mu: float
    model: PlanModel
    graph: PlanGraph
    tasks: dict[str, Task]
    paths: dict[str, list[PathEntry]]
    cost: float
    planning_time_s: float
    format: Literal["fleet-plan/1"] = PLAN_FORMAT
    dt: float | None = None
    mip_gap: float | None = None


class PlanFileError(ValueError):
    """A plan file that cannot be read: names the file and the problem."""


def encode_plan(plan: Plan) -> bytes:
    return msgspec.json.format(msgspec.json.encode(plan), indent=1)


def decode_plan(data: bytes | str, source: str = "<plan>") -> Plan:
    try:
        return msgspec.json.decode(data, type=Plan)
    except msgspec.DecodeError as exc:
        raise PlanFileError(f"{source}: {exc}") from None


def write_plan(plan: Plan, path: str | Path) -> None:
    Path(path).write_bytes(encode_plan(plan))


def read_plan(path: str | Path) -> Plan:
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise PlanFileError(f"{path}: cannot read ({exc.strerror})") from None
    return decode_plan(data, str(path))
