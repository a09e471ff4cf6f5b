"""Simulated execution of a TeamPlan (002 §IV-E) in a simulated world, one action at a time.

`TeamWorld` is the world: the two robots' poses and the sensing their controllers need (side IR
ranges, landmark and UGV sightings, through `Sensing`). It runs one controller action with
`controllers.phi` from the robots' actual poses: a GOTOLANDMARK_DYN flies to its offset from
wherever the UGV actually is, so a broken sync point shows up as a failed precondition or a wrong
end pose. `TeamSim` runs both robots' sequences of a plan in simulated time, honouring the sync
points; the team sim service (`service.py`, `fleet sim team`) runs the actions executors send over zenoh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from common.domain import team_plan as tp
from common.team import controllers as ctl
from common.team.sensing import DIRS, Sensing


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

    def __init__(self, sensing: Sensing, drone_start: tp.Vec3, ugv_start: tp.Vec3) -> None:
        self.s = sensing
        self.env = sensing.env
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
        dz = abs(env.z_levels[after.level] - env.z_levels[before.level])
        dist = math.hypot(after.row - before.row, after.col - before.col) * env.resolution + dz
        return ActionOutcome(after, dist / m.drone_speed + (1.0 if isinstance(a, tp.MetricTurn) else 0.0))

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

    def __init__(self, sensing: Sensing, plan: tp.TeamPlan) -> None:
        self.world = TeamWorld(sensing, plan.drone_start, plan.ugv_start)
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
