"""Simulated execution of a TeamPlan (002 §IV-E) in a simulated world, one action at a time.

`TeamWorld` is the world: the two robots' poses and the sensing their controllers need (side IR
ranges, landmark and UGV sightings, through `Sensing`). It runs one controller action with
`controllers.phi` from the robots' actual poses: a GOTOLANDMARK_DYN flies to its offset from
wherever the UGV actually is, so a broken sync point shows up as a failed precondition or a wrong
end pose. `TeamSim` runs both robots' sequences of a plan in simulated time, honouring the sync
points; the team sim service (`service.py`, `fleet sim team`) runs the actions executors send over zenoh.

Sensing noise (`SensingNoise`): the paper's drone localizes only by its sensors (002 §III-B, §V-A:
IR ranges, a camera on landmarks and the UGV's fiducials), so range and bearing errors move where its
perceptual actions end. The world draws that error per action and moves the drone to the lattice
cell its true end falls in: an action whose trigger fires early or late, or that servos onto a
mis-measured landmark, can end in a neighbouring cell, and is then reported failed ("ended at ...,
expected ..."), which the executor may re-try (`services/executor/team_robots.py`). Errors do not
build up across actions: each perceptual controller localizes afresh on the features it senses.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

from common.domain import team_plan as tp
from common.team import controllers as ctl
from common.team.sensing import DIRS, Sensing


@dataclass(frozen=True)
class SensingNoise:
    """Gaussian errors of the drone's sensing (002 §III-B): `range_std` (m) on every range it
    measures (the IR ranges of wall following and its OBSTACLE trigger, the camera's range to a
    landmark or the UGV's markers), `bearing_std_deg` on every bearing (a sighting's direction, and
    where a side IR beam sees a wall end or an opening). How they move an action's end:

    - WALLFOLLOWING: along the travel by N(0, range_std) when a range ends it (OBSTACLE, intrinsic
      or perceptual; LANDMARK_SIGHTED at the camera's range), by N(0, d tan(bearing)) when a side
      beam's edge does (WALL_END, OPENING_*; d the distance to the wall); across by N(0, range_std)
      (the held wall distance);
    - GOTOLANDMARK_STAT/DYN: servoing onto a point at distance d from the landmark or the markers,
      N(0, range_std) along the line of sight and N(0, d tan(bearing)) across it;
    - METRICTURN, METRICSTEP and ALTITUDE sense nothing (IMU, optical flow, altimeter): unchanged,
      as are the UGV's motions (it localizes well, §I)."""

    range_std: float = 0.0
    bearing_std_deg: float = 0.0

    def __post_init__(self) -> None:
        if self.range_std < 0 or self.bearing_std_deg < 0:
            raise ValueError("sensing noise must not be negative")

    @property
    def zero(self) -> bool:
        return self.range_std == 0 and self.bearing_std_deg == 0


_RANGE_TRIGGERS = (ctl.OBSTACLE, ctl.LANDMARK_SIGHTED)
"""WALLFOLLOWING triggers a range reading fires; the others (WALL_END, OPENING_*) are beam edges."""


@dataclass(frozen=True)
class ActionOutcome:
    """What one action does in the world: where the robot ends up (on failure: where it stopped),
    how long it takes (simulated seconds) and why it failed ("" if it did not)."""

    pose: ctl.DronePose | ctl.UgvPose
    duration_s: float
    detail: str = ""

    @property
    def ok(self) -> bool:
        return not self.detail


class TeamWorld:
    """The drone and the UGV in the world `sensing` describes. Poses are lattice cells; `xyz()` gives
    metres (drone x, y, z; UGV x, y, heading_deg)."""

    def __init__(self, sensing: Sensing, drone_start: tp.Vec3, ugv_start: tp.Vec3,
                 noise: SensingNoise = SensingNoise(), seed: int = 0) -> None:
        """`noise`: the drone's sensing errors, drawn from a generator seeded with `seed`."""
        self.s = sensing
        self.env = sensing.env
        self.noise = noise
        self.rng = random.Random(seed)
        x, y, z = drone_start
        self.drone = ctl.DronePose(self.env.level_of(z), *self.env.cell_of(x, y))
        ux, uy, heading = ugv_start
        self.ugv = ctl.UgvPose(*self.env.cell_of(ux, uy), round(heading / 45.0) % 8)

    def xyz(self, robot: tp.Robot) -> tp.Vec3:
        return self.metres(self.drone if robot == "drone" else self.ugv)

    def outcome(self, robot: tp.Robot, step: tp.Step) -> ActionOutcome:
        """Run `robot`'s action from the current poses without moving anything; a result that ends
        more than half a cell from the step's `end` is a failure."""
        out = self._drone(step) if robot == "drone" else self._ugv(step)
        if out.ok:
            pose = self.metres(out.pose)
            if math.dist(pose[:2], step.end[:2]) > self.env.resolution / 2:
                return ActionOutcome(out.pose, out.duration_s, f"ended at {_fmt(pose)}, expected {_fmt(step.end)}")
        return out

    def apply(self, robot: tp.Robot, out: ActionOutcome) -> None:
        """Put `robot` where `out` left it."""
        if robot == "drone":
            assert isinstance(out.pose, ctl.DronePose)
            self.drone = out.pose
        else:
            assert isinstance(out.pose, ctl.UgvPose)
            self.ugv = out.pose

    def metres(self, pose: ctl.DronePose | ctl.UgvPose) -> tp.Vec3:
        """A lattice pose in metres: drone (x, y, z), UGV (x, y, heading_deg)."""
        x, y = self.env.center(pose.row, pose.col)
        return (x, y, self.env.z_levels[pose.level] if isinstance(pose, ctl.DronePose) else 45.0 * pose.heading)

    # ---- controllers ----------------------------------------------------------------------------
    def _drone(self, step: tp.Step) -> ActionOutcome:
        a, env, m = step.action, self.env, self.s.model
        before = self.drone
        trigger = None
        if isinstance(a, tp.WallFollowing):
            c: ctl.DroneController = ctl.WallFollowController(a.side, round(a.heading_deg / 45.0) % 8)
            trigger = a.trigger
        elif isinstance(a, tp.GoToLandmarkStat):
            ids = [lm.id for lm in env.landmarks]
            if a.landmark not in ids:
                return ActionOutcome(before, 0.0, f"unknown landmark {a.landmark}")
            c = ctl.GoToLandmarkStatController(ids.index(a.landmark), env.cell_of(a.target[0], a.target[1]))
        elif isinstance(a, tp.GoToLandmarkDyn):
            ux, uy, _ = self.xyz("ugv")
            c = ctl.GoToLandmarkDynController(env.cell_of(ux + a.offset[0], uy + a.offset[1]))
        elif isinstance(a, tp.MetricTurn):
            c = ctl.MetricTurnController(round(a.heading_deg / 45.0) % 8)
        elif isinstance(a, tp.MetricStep):
            c = ctl.MetricStepController(round(a.distance_m / (env.resolution * math.hypot(*DIRS[before.heading]))))
        elif isinstance(a, tp.Altitude):
            c = ctl.AltitudeController(env.level_of(a.z))
        else:
            return ActionOutcome(before, 0.0, f"{type(a).__name__} is not a drone action")
        after = ctl.phi(self.s, before, c, trigger, self.ugv)
        if after is None:
            return ActionOutcome(before, 0.0, f"{type(a).__name__} not available at {_fmt(self.xyz('drone'))}")
        if not self.noise.zero:
            after = self._sensed_end(a, before, after)
        dz = abs(env.z_levels[after.level] - env.z_levels[before.level])
        dist = math.hypot(after.row - before.row, after.col - before.col) * env.resolution + dz
        return ActionOutcome(after, dist / m.drone_speed + (1.0 if isinstance(a, tp.MetricTurn) else 0.0))

    def _sensed_end(self, a: tp.DroneAction, before: ctl.DronePose, after: ctl.DronePose) -> ctl.DronePose:
        """Where the drone really ends an action that ends at `after` with perfect sensing: the
        cell its displaced end falls in (see `SensingNoise`), unless that cell is blocked (the
        drone senses the obstacle and stops short of it)."""
        n, env, g = self.noise, self.env, self.rng.gauss
        tan_b = math.tan(math.radians(n.bearing_std_deg))
        x, y = env.center(after.row, after.col)
        if isinstance(a, tp.WallFollowing):
            dr, dc = DIRS[round(a.heading_deg / 45.0) % 8]
            along = n.range_std if a.trigger in _RANGE_TRIGGERS else self._wall_distance(a, after) * tan_b
            e_along, e_across = g(0.0, along), g(0.0, n.range_std)
            x += dc * e_along - dr * e_across
            y += dr * e_along + dc * e_across
        elif isinstance(a, tp.GoToLandmarkStat | tp.GoToLandmarkDyn):
            if isinstance(a, tp.GoToLandmarkStat):
                lm = next(m for m in env.landmarks if m.id == a.landmark)
                seen = (lm.x, lm.y, lm.z)
            else:
                ux, uy, _ = self.xyz("ugv")
                seen = (ux, uy, self.s.model.ugv_height)
            z = env.z_levels[after.level]
            d = math.dist((x, y, z), seen)
            ux_, uy_ = ((x - seen[0]) / d, (y - seen[1]) / d) if d > 1e-9 else (1.0, 0.0)
            e_along, e_across = g(0.0, n.range_std), g(0.0, d * tan_b)
            x += ux_ * e_along - uy_ * e_across
            y += uy_ * e_along + ux_ * e_across
        else:
            return after
        row, col = env.cell_of(x, y)
        if not self.s.drone_free(after.level, row, col):
            return after
        return ctl.DronePose(after.level, row, col, after.heading)

    def _wall_distance(self, a: tp.WallFollowing, at: ctl.DronePose) -> float:
        """Metres from the drone to the wall it follows (the side IR reading; one cell if unseen)."""
        side = ctl.wall_side(a.side, round(a.heading_deg / 45.0) % 8)
        cells = self.s.side_range(at.level, at.row, at.col, side) if side % 2 == 0 else 0
        return (cells or 1) * self.env.resolution

    def _ugv(self, step: tp.Step) -> ActionOutcome:
        a, m = step.action, self.s.model
        if not isinstance(a, tp.MetricMotion):
            return ActionOutcome(self.ugv, 0.0, f"{type(a).__name__} is not a UGV action")
        turns = round(a.turn_deg / 45.0)
        pose = self.ugv
        for _ in range(abs(turns)):
            pose = ctl.phi_ugv(self.s, pose, ctl.UgvTurnController(1 if turns > 0 else -1))
        n = round(a.distance_m / (self.env.resolution * math.hypot(*DIRS[pose.heading])))
        for _ in range(n):
            nxt = ctl.phi_ugv(self.s, pose, ctl.UgvForwardController())
            if nxt is None:
                return ActionOutcome(pose, 0.0, f"UGV blocked at {_fmt(self.metres(pose))}")
            pose = nxt
        return ActionOutcome(pose, abs(a.turn_deg) / m.ugv_turn_rate + a.distance_m / m.ugv_speed)


@dataclass(frozen=True)
class StepEvent:
    robot: tp.Robot
    index: int
    action: str
    start_s: float
    end_s: float
    pose: tuple[float, float, float]
    """Drone (x, y, z) or UGV (x, y, heading_deg) after the step."""
    ok: bool
    detail: str = ""


@dataclass
class SimReport:
    reached_goal: bool
    failure: str | None
    makespan_s: float
    events: list[StepEvent] = field(default_factory=list)


class TeamSim:
    """A TeamPlan executed in the world `sensing` describes (by default the planning map). An
    executor can drive it step by step: `ready()` lists the robots that may start their next
    action, `step(robot)` runs it."""

    def __init__(self, sensing: Sensing, plan: tp.TeamPlan, noise: SensingNoise = SensingNoise(), seed: int = 0) -> None:
        """`noise`, `seed`: the drone's sensing errors (`SensingNoise`); an off-plan end fails the
        run (this offline executor does not re-try, the fleet's executors do)."""
        self.world = TeamWorld(sensing, plan.drone_start, plan.ugv_start, noise, seed)
        self.plan = plan
        self.progress = tp.PlanProgress(plan)
        self.clock: dict[tp.Robot, float] = {"drone": 0.0, "ugv": 0.0}
        self.finish_times: dict[tp.Robot, list[float]] = {"drone": [], "ugv": []}
        self.events: list[StepEvent] = []
        self.failure: str | None = None

    def ready(self) -> list[tp.Robot]:
        """Robots whose next step may start now (its sync point is satisfied)."""
        if self.failure:
            return []
        return [r for r in tp.ROBOTS if self.progress.can_start(r)]

    def start_time(self, robot: tp.Robot) -> float:
        """When `robot`'s next step starts: its own clock, or the end of the step it waits for."""
        step = self.progress.next_step(robot)
        other = tp.PlanProgress.other(robot)
        wait = self.finish_times[other][step.wait_for - 1] if step and step.wait_for else 0.0
        return max(self.clock[robot], wait)

    def step(self, robot: tp.Robot) -> StepEvent:
        """Run `robot`'s next action to completion in the world."""
        if robot not in self.ready():
            raise ValueError(f"{robot} cannot start a step now")
        index = self.progress.done[robot]
        step = self.progress.next_step(robot)
        assert step is not None
        t0 = self.start_time(robot)
        out = self.world.outcome(robot, step)
        self.world.apply(robot, out)
        self.clock[robot] = t0 + out.duration_s
        event = StepEvent(robot, index, type(step.action).__name__, t0, t0 + out.duration_s,
                          self.world.xyz(robot), out.ok, out.detail)
        self.events.append(event)
        if out.ok:
            self.progress.complete(robot)
            self.finish_times[robot].append(self.clock[robot])
        else:
            self.failure = f"{robot} step {index} ({event.action}): {out.detail}"
        return event

    def run(self) -> SimReport:
        """Run both sequences to the end (earliest-starting ready robot first) and report."""
        while not self.failure and not self.progress.finished:
            ready = self.ready()
            if not ready:
                self.failure = "deadlock: each robot waits for the other"
                break
            self.step(min(ready, key=self.start_time))
        return self.report()

    def report(self) -> SimReport:
        at_goal = math.dist(self.world.xyz("drone"), self.plan.goal) <= self.world.env.resolution / 2
        return SimReport(
            reached_goal=self.failure is None and self.progress.finished and at_goal,
            failure=self.failure,
            makespan_s=max(self.clock.values()),
            events=self.events,
        )


def _fmt(v: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in v) + ")"
