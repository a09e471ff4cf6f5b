"""The team plan (002 §IV-E): per robot a sequence of controller actions with synchronisation points.

A `Step` with `wait_for = n` may start only once the other robot has completed its first n steps:
a GOTOLANDMARK_DYN waits for every UGV motion planned before it, and the UGV's next motion waits
for that GOTOLANDMARK_DYN to finish, so the UGV is where the drone expects it. Everything is in
metres and degrees (heading 0 = +x, counter-clockwise). Frozen msgspec Structs: JSON or msgpack.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import msgspec

from common.errors import InputError
from common.mapfile import _split_msgspec_error, read_text
from services.planner.collab.lattice import Lattice
from services.planner.collab.sensing import DIRS

PLAN_FORMAT = "fleet-collab-plan/1"
Vec3 = tuple[float, float, float]
_S = {"frozen": True, "forbid_unknown_fields": True, "tag_field": "type"}


class WallFollowing(msgspec.Struct, tag="WALLFOLLOWING", **_S):
    """Fly along `heading_deg` holding the distance to the wall on `side`; stop at `trigger`
    (null: the intrinsic end, WALL_END or OBSTACLE)."""

    side: Literal["left", "right"]
    heading_deg: float
    trigger: Literal["OPENING_LEFT", "OPENING_RIGHT", "LANDMARK_SIGHTED"] | None = None


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


class _Builder:
    """Turns a team path into the two robots' step lists with sync points and merged UGV motions."""

    def __init__(self) -> None:
        self.drone: list[Step] = []
        self.ugv: list[Step] = []
        self.ugv_barrier = 0
        self.ugv_mergeable = False

    def add_drone(self, action: DroneAction, end: Vec3, cost: float, coupled: bool) -> None:
        self.drone.append(Step(action, end, cost, len(self.ugv) if coupled else 0))
        if coupled:
            self.ugv_barrier = len(self.drone)
            self.ugv_mergeable = False

    def add_ugv(self, motion: MetricMotion, end: Vec3, cost: float) -> None:
        last = self.ugv[-1] if self.ugv and self.ugv_mergeable else None
        if last is not None and isinstance(last.action, MetricMotion):
            prev = last.action
            if motion.turn_deg == 0.0 or prev.distance_m == 0.0:
                merged = MetricMotion(prev.turn_deg + motion.turn_deg, prev.distance_m + motion.distance_m)
                self.ugv[-1] = Step(merged, end, last.cost + cost, last.wait_for)
                return
        self.ugv.append(Step(motion, end, cost, self.ugv_barrier))
        self.ugv_mergeable = True


def _xyz(lat: Lattice, d: int) -> Vec3:
    k, r, c = lat.drone_pose(d)
    x, y = lat.s.env.center(r, c)
    return (x, y, lat.s.env.z_levels[k])


def _ugv_pose(lat: Lattice, u: int) -> Vec3:
    r, c, heading = lat.ugv_pose(u)
    x, y = lat.s.env.center(r, c)
    return (x, y, 45.0 * heading)


def build_team_plan(
    lat: Lattice, path: list[int], planner: str, cost: float, eps: float, planning_time_s: float, expansions: int
) -> TeamPlan:
    """A team path (`Lattice.team_id` states) -> TeamPlan, relabelling each transition with the cheapest
    controller that makes it (002 §III-A: several controller/trigger pairs may join two states)."""
    env, res = lat.s.env, lat.s.env.resolution
    b = _Builder()
    for a, z in zip(path, path[1:], strict=False):
        (d, u, _), (d2, u2, _) = lat.team_decode(a), lat.team_decode(z)
        if u != u2:
            r, c, h = lat.ugv_pose(u)
            r2, c2, h2 = lat.ugv_pose(u2)
            step_cost = next(cst for v, cst in lat.ugv_succ(u) if v == u2)
            if (r, c) == (r2, c2):
                motion = MetricMotion(turn_deg=45.0 * (((h2 - h + 4) % 8) - 4))
            else:
                motion = MetricMotion(distance_m=math.hypot(r2 - r, c2 - c) * res)
            b.add_ugv(motion, _ugv_pose(lat, u2), step_cost)
            continue
        step_cost, label = lat.drone_label(d, d2, u // 9)
        end = _xyz(lat, d2)
        kind = label[0]
        if kind == "WF":
            _, side, heading, trig = label
            b.add_drone(WallFollowing(side, 45.0 * heading, trig), end, step_cost, False)
        elif kind == "STAT":
            b.add_drone(GoToLandmarkStat(env.landmarks[label[1]].id, end), end, step_cost, False)
        elif kind == "METRIC":
            _, heading, n = label
            turn = lat.m.cost_metric_turn + lat.m.cost_action
            b.add_drone(MetricTurn(45.0 * heading), _xyz(lat, d), turn, False)
            b.add_drone(MetricStep(n * math.hypot(*DIRS[heading]) * res), end, step_cost - turn, False)
        elif kind == "ALT":
            b.add_drone(Altitude(end[2]), end, step_cost, False)
        else:
            ux, uy, _ = _ugv_pose(lat, u)
            offset = (end[0] - ux, end[1] - uy, end[2] - lat.m.ugv_height)
            b.add_drone(GoToLandmarkDyn(offset, end), end, step_cost, True)
    d0, u0, _ = lat.team_decode(path[0])
    return TeamPlan(
        format=PLAN_FORMAT,
        map=env.name,
        planner=planner,
        drone_start=_xyz(lat, d0),
        ugv_start=_ugv_pose(lat, u0),
        goal=_xyz(lat, lat.team_drone(path[-1])),
        drone=tuple(b.drone),
        ugv=tuple(b.ugv),
        cost=cost,
        epsilon=eps,
        planning_time_s=planning_time_s,
        expansions=expansions,
    )


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

    @property
    def finished(self) -> bool:
        return all(self.next_step(r) is None for r in ROBOTS)
