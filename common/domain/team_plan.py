"""The team plan of a ground-air team (paper 002 §IV-E): per robot a sequence of controller actions
with synchronisation points, and the bookkeeping of those sync points during execution.

A `Step` with `wait_for = n` may start only once the other robot has completed its first n steps:
a GOTOLANDMARK_DYN waits for every UGV motion planned before it, and the UGV's next motion waits
for that GOTOLANDMARK_DYN to finish, so the UGV is where the drone expects it. Everything is in
metres and degrees (heading 0 = +x, counter-clockwise). Frozen msgspec Structs: JSON in files,
msgpack on the bus (it crosses process boundaries: planner -> executors -> robots).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import msgspec

from common.domain.mapfile import _split_msgspec_error, read_text
from common.errors import InputError

PLAN_FORMAT = "fleet-collab-plan/1"
Vec3 = tuple[float, float, float]
_S = {"frozen": True, "forbid_unknown_fields": True, "tag_field": "type"}


class WallFollowing(msgspec.Struct, tag="WALLFOLLOWING", **_S):
    """Fly along `heading_deg` holding the distance to the wall on `side`; stop at `trigger`
    (null: the intrinsic end, WALL_END or OBSTACLE next to the drone; "OBSTACLE": an obstacle within
    1 m of the IR sensor facing the travel, front or back, common/team/controllers.py)."""

    side: Literal["left", "right"]
    heading_deg: float
    trigger: Literal["OPENING_LEFT", "OPENING_RIGHT", "LANDMARK_SIGHTED", "OBSTACLE"] | None = None


class GoToLandmarkStat(msgspec.Struct, tag="GOTOLANDMARK_STAT", **_S):
    """Fly straight to `target`, localizing on static landmark `landmark`."""

    landmark: str
    target: Vec3


class GoToLandmarkDyn(msgspec.Struct, tag="GOTOLANDMARK_DYN", **_S):
    """Fly straight to the point `offset` from the UGV's markers, localizing on them; `target`
    is where that is when the UGV is where the plan puts it."""

    offset: Vec3
    target: Vec3


class MetricTurn(msgspec.Struct, tag="METRICTURN", **_S):
    heading_deg: float


class MetricStep(msgspec.Struct, tag="METRICSTEP", **_S):
    """Move `distance_m` forward along the current heading (IMU and optical flow)."""

    distance_m: float


class Altitude(msgspec.Struct, tag="ALTITUDE", **_S):
    """Climb or descend to `z` (laser altimeter)."""

    z: float


class MetricMotion(msgspec.Struct, tag="METRICMOTION", **_S):
    """UGV: turn in place by `turn_deg`, then drive `distance_m` straight ahead."""

    turn_deg: float = 0.0
    distance_m: float = 0.0


DroneAction = WallFollowing | GoToLandmarkStat | GoToLandmarkDyn | MetricTurn | MetricStep | Altitude


class Step(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One controller action. `end` is the pose it should end in: drone (x, y, z), UGV (x, y,
    heading_deg). `wait_for`: how many of the other robot's steps must be complete first."""

    action: DroneAction | MetricMotion
    end: Vec3
    cost: float
    wait_for: int = 0


class TeamPlan(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    format: Literal["fleet-collab-plan/1"]
    map: str
    planner: str
    drone_start: Vec3
    ugv_start: Vec3
    goal: Vec3
    drone: tuple[Step, ...]
    ugv: tuple[Step, ...]
    cost: float
    epsilon: float
    """Proven sub-optimality bound of `cost`."""
    planning_time_s: float
    expansions: int


def action_name(step: Step) -> str:
    """The controller's name as the paper writes it (the action's tag, e.g. GOTOLANDMARK_DYN)."""
    return str(type(step.action).__struct_config__.tag)


def encode_json(plan: TeamPlan) -> bytes:
    return msgspec.json.encode(plan)


def decode_json(data: bytes | str) -> TeamPlan:
    return msgspec.json.decode(data, type=TeamPlan, strict=True)


def read_plan(path: str | Path) -> TeamPlan:
    """A team plan JSON file; bad input is an InputError naming the file and the field."""
    try:
        return decode_json(read_text(Path(path)))
    except msgspec.DecodeError as exc:
        field, problem = _split_msgspec_error(exc)
        raise InputError(str(path), field, problem) from None


def encode_msgpack(plan: TeamPlan) -> bytes:
    return msgspec.msgpack.encode(plan)


def decode_msgpack(data: bytes) -> TeamPlan:
    return msgspec.msgpack.decode(data, type=TeamPlan)


Robot = Literal["drone", "ugv"]
ROBOTS: tuple[Robot, Robot] = ("drone", "ugv")


class PlanProgress:
    """Execution bookkeeping of a TeamPlan's sync points (002 §IV-E), for simulated or real robots:
    a robot may start its next step only when the other robot has completed `wait_for` steps."""

    def __init__(self, plan: TeamPlan) -> None:
        self.steps: dict[Robot, tuple[Step, ...]] = {"drone": plan.drone, "ugv": plan.ugv}
        self.done: dict[Robot, int] = {"drone": 0, "ugv": 0}

    @staticmethod
    def other(robot: Robot) -> Robot:
        return "ugv" if robot == "drone" else "drone"

    def next_step(self, robot: Robot) -> Step | None:
        i = self.done[robot]
        return self.steps[robot][i] if i < len(self.steps[robot]) else None

    def can_start(self, robot: Robot) -> bool:
        step = self.next_step(robot)
        return step is not None and self.done[self.other(robot)] >= step.wait_for

    def complete(self, robot: Robot) -> None:
        if self.next_step(robot) is None:
            raise ValueError(f"{robot} has no step left to complete")
        self.done[robot] += 1

    def observe(self, robot: Robot, done: int) -> bool:
        """`robot` reports `done` steps complete (e.g. its executor, over the bus): progress only
        grows, so late or repeated reports change nothing. True if it grew."""
        done = min(done, len(self.steps[robot]))
        if done <= self.done[robot]:
            return False
        self.done[robot] = done
        return True

    @property
    def finished(self) -> bool:
        return all(self.next_step(r) is None for r in ROBOTS)


def parse_vec3(text: str, what: str, source: str) -> Vec3:
    """'x,y,z' (or 'x,y,heading_deg') -> three floats; an InputError naming the option otherwise."""
    try:
        x, y, z = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(source, what, f"expected three comma-separated numbers, got {text!r}") from None
    return x, y, z


def format_team_plan(plan: TeamPlan) -> str:
    """A readable listing of a team plan: one line per step, sync points as 'after <robot> <n>'."""
    lines = [f"team plan on {plan.map} ({plan.planner}): cost {plan.cost:.2f} (within {plan.epsilon:.2f} x optimal), "
             f"{plan.planning_time_s:.2f} s, {plan.expansions} expansions",
             f"drone start {plan.drone_start}, UGV start {plan.ugv_start}, goal {plan.goal}"]
    for robot, steps in (("drone", plan.drone), ("ugv", plan.ugv)):
        lines.append(f"{robot}:")
        other = PlanProgress.other(robot)
        for i, step in enumerate(steps):
            fields = " ".join(f"{k}={_short(v)}" for k, v in _fields(step.action).items())
            sync = f"  [after {other} {step.wait_for}]" if step.wait_for else ""
            end = ", ".join(f"{v:.2f}" for v in step.end)
            lines.append(f"  {i:3d} {action_name(step):18s} {fields} -> ({end}){sync}")
    return "\n".join(lines)


def _fields(struct: msgspec.Struct) -> dict:
    return {f: getattr(struct, f) for f in struct.__struct_fields__}


def _short(v: object) -> object:
    if isinstance(v, float):
        return f"{v:.2f}"
    if isinstance(v, tuple):
        return "(" + ", ".join(_short(x) for x in v) + ")"
    return v
