"""The plan file (DESIGN.md, "Plan file"): the contract between planners, validator and executors.

``{"format": "fleet-plan/1", "map", "planner", "mu", "model", "graph", "tasks", "paths", "cost",
"planning_time_s"}`` plus ``dt`` for plans made on the uniform-time-step graph (ILP) and the ILP's
proven ``mip_gap``. A path entry is the time a vehicle is at a node; consecutive entries at different
nodes traverse the edge between them linearly; before the first entry a vehicle sits at its start,
after the last at its goal forever.

Every encoded plan names its format first (``"format": "fleet-plan/1"``); a reader refuses a file
without it or with another one, naming the field, before reading anything else.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal

import msgspec

from common.domain.battery import usable_ah
from common.domain.vehicle_model import Capabilities, EdgeKind, NodeKind, VehicleModel
from common.errors import InputError

PLAN_FORMAT = "fleet-plan/1"


def _plan_format() -> str:
    """The `format` field's default, as a factory: msgspec's omit_defaults cannot tell a factory's
    value from a set one, so the field is always encoded (DESIGN.md: "The `format` field is always
    written")."""
    return PLAN_FORMAT


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


class Task(msgspec.Struct, frozen=True, forbid_unknown_fields=True, omit_defaults=True):
    """A vehicle's start and goal node; `capabilities` restricts the edge kinds it may use
    (`CAPABLE_EDGES`: a stock Crazyflie only flies, a ground robot only drives). `charge_used_ah`
    and `voltage` are the vehicle's battery as measured (0: full, at the model's voltage): the
    planner's eq. 6 budget is what is left (`common.domain.battery.usable_ah`)."""

    start: str
    goal: str
    capabilities: Capabilities = "fly+drive"
    charge_used_ah: float = 0.0
    voltage: float = 0.0

    def usable_ah(self, model: VehicleModel) -> float:
        """Eq. 6's budget of this vehicle in the planner's units."""
        return usable_ah(model, self.charge_used_ah, self.voltage)


class PathEntry(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    node: str
    t: float


class Plan(msgspec.Struct, frozen=True, forbid_unknown_fields=True, omit_defaults=True, kw_only=True):
    format: Literal["fleet-plan/1"] = msgspec.field(default_factory=_plan_format)
    map: str
    planner: str
    mu: float
    model: PlanModel
    graph: PlanGraph
    tasks: dict[str, Task]
    paths: dict[str, list[PathEntry]]
    cost: float
    planning_time_s: float
    dt: float | None = None
    mip_gap: float | None = None

    def position(self, vid: str, t: float) -> tuple[float, float, float]:
        """Where the plan has `vid` at `t` s: at its start before its first entry, linear between
        entries, at its goal after its last (DESIGN.md, "Plan file")."""
        path, nodes = self.paths[vid], self.graph.nodes
        if t <= path[0].t:
            return nodes[path[0].node].pos
        for a, b in zip(path, path[1:], strict=False):
            if t <= b.t:
                f = 0.0 if b.t == a.t else (t - a.t) / (b.t - a.t)
                pa, pb = nodes[a.node].pos, nodes[b.node].pos
                return (pa[0] + f * (pb[0] - pa[0]), pa[1] + f * (pb[1] - pa[1]), pa[2] + f * (pb[2] - pa[2]))
        return nodes[path[-1].node].pos


class PlanFileError(InputError, ValueError):
    """A plan file that cannot be read: `source: field: problem` (field empty when the file as a whole
    is unreadable)."""


class _Header(msgspec.Struct):
    """A plan file's format, read before the rest (unknown fields skipped)."""

    format: Any = msgspec.UNSET


_AT_FIELD = re.compile(r"\s*-\s*at `\$\.?([^`]*)`")


def encode_plan(plan: Plan) -> bytes:
    return msgspec.json.format(msgspec.json.encode(plan), indent=1)


def check_format(data: bytes | str, source: str = "<plan>") -> None:
    """A plan file names its format, and it is the one this reader reads (else PlanFileError)."""
    try:
        header = msgspec.json.decode(data, type=_Header)
    except msgspec.DecodeError:
        return  # not a JSON object: the full decode says what is wrong
    if header.format is msgspec.UNSET:
        raise PlanFileError(source, "format", f"missing: a plan file names its format ({PLAN_FORMAT!r})")
    if header.format != PLAN_FORMAT:
        raise PlanFileError(source, "format", f"{header.format!r} is not a format this reader reads ({PLAN_FORMAT!r})")


def decode_plan(data: bytes | str, source: str = "<plan>") -> Plan:
    check_format(data, source)
    try:
        return msgspec.json.decode(data, type=Plan)
    except msgspec.DecodeError as exc:
        text = str(exc)
        match = _AT_FIELD.search(text)
        if match is None:
            raise PlanFileError(source, "", text) from None
        raise PlanFileError(source, match.group(1), text[: match.start()]) from None


def write_plan(plan: Plan, path: str | Path) -> None:
    Path(path).write_bytes(encode_plan(plan))


def read_plan(path: str | Path) -> Plan:
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise PlanFileError(f"{path}: cannot read ({exc.strerror})") from None
    return decode_plan(data, str(path))
