"""`fleet mission team`: one ground-air team plan run end to end through the executors (paper 002
§IV-E, plan execution with synchronisation points), on the skeleton of `client.py`.

The mission asks the planner for a team plan (`PlanRequest(planner="collab", team=...)`), hands
each robot its copy (`vehicle/<vid>/team_plan`, re-sent every second: zenoh keeps no history),
waits until the executors that own the robots report the plan loaded, starts both at a common time
(`mission/<id>/start`), prints every action the robots report, and ends when both have finished
their sequences, one has failed, or neither has completed a step for `stall_s`. The summary says
whether the drone reached the goal (in ground truth when a simulator publishes it), each robot's
steps and time, and whether every sync point was honoured: each waiting step started only after
the partner's steps it waits for were reported done.
"""

from __future__ import annotations

import asyncio
import math
import time
import uuid
from dataclasses import dataclass, field

import zenoh

from common.bus.messages import (
    ActionStatus,
    PlanReply,
    PlanRequest,
    SimTruth,
    TeamTask,
    VehicleState,
    VehicleTeamPlan,
)
from common.bus.vehicle_plans import robot_plans
from common.domain.team_plan import PlanProgress, Robot, TeamPlan, action_name, format_team_plan
from services.mission.client import MissionClient, MissionTiming

FINISHED = "both robots finished their sequences"
GOAL_TOLERANCE_M = 0.25
"""The drone is at the goal within half a lattice cell (002 maps: 0.5 m cells)."""
TRUTH_WAIT_S = 2.0
"""At the end, how long to wait for a ground truth of the drone newer than its last state."""


@dataclass(frozen=True)
class TeamMissionSpec:
    map: str
    team: TeamTask
    time_limit: float = 30.0
    mission: str = field(default_factory=lambda: f"t{uuid.uuid4().hex[:8]}")
    stall_s: float = 60.0
    timing: MissionTiming = MissionTiming(start_lead_s=1.0, planner_timeout_s=20.0)


@dataclass
class RobotReport:
    vid: str
    robot: Robot
    steps: int = 0
    done: int = 0
    mode: str = "?"
    owner: str = ""
    finished_s: float | None = None
    pose: tuple[float, float, float] | None = None


@dataclass
class TeamMissionResult:
    mission: str
    ok: bool
    reason: str
    duration_s: float
    plan: TeamPlan | None = None
    robots: dict[str, RobotReport] = field(default_factory=dict)
    goal_error_m: float | None = None
    sync_points: int = 0
    sync_violations: list[str] = field(default_factory=list)
    events: list[str] = field(default_factory=list)

    def summary(self) -> str:
        lines = [f"team mission {self.mission}: {'OK' if self.ok else 'FAILED'} ({self.reason}) in {self.duration_s:.1f} s"]
        lines.append(f"{'robot':<6} {'vehicle':<10} {'steps':>7} {'time s':>7}  {'owner':<12} {'mode':<8} pose")
        for r in self.robots.values():
            t = f"{r.finished_s:.1f}" if r.finished_s is not None else "-"
            pose = "(" + ", ".join(f"{v:.2f}" for v in r.pose) + ")" if r.pose else "-"
            lines.append(f"{r.robot:<6} {r.vid:<10} {f'{r.done}/{r.steps}':>7} {t:>7}  {r.owner:<12} {r.mode:<8} {pose}")
        if self.plan is not None:
            where = "-" if self.goal_error_m is None else f"{self.goal_error_m:.2f} m from it"
            lines.append(f"goal {self.plan.goal}: drone {where}")
        lines.append(f"sync points honoured: {self.sync_points - len(self.sync_violations)}/{self.sync_points}")
        lines.extend(f"sync point broken: {v}" for v in self.sync_violations)
        lines.extend(f"event: {e}" for e in self.events[:20])
        return "\n".join(lines)


class TeamMission(MissionClient[TeamMissionResult]):
    """One team mission, as a short-lived service (`alive/mission/<id>`)."""

    def __init__(self, spec: TeamMissionSpec, *args, progress: bool = True, **kwargs) -> None:
        team = spec.team
        super().__init__(spec.mission, (team.drone, team.ugv), spec.timing, *args, progress=progress, **kwargs)
        self.spec = spec
        self.reports = {team.drone: RobotReport(team.drone, "drone"), team.ugv: RobotReport(team.ugv, "ugv")}
        self.statuses: list[ActionStatus] = []
        self.truth: dict[str, SimTruth] = {}
        self.plan: TeamPlan | None = None
        self._plans = None
        self._last_done, self._last_progress = -1, 0.0

    def plan_request(self) -> PlanRequest:
        s = self.spec
        return PlanRequest(map=s.map, tasks={}, planner="collab", time_limit=s.time_limit, mission=s.mission, team=s.team)

    def planner_wait_s(self) -> float:
        return self.spec.time_limit + self.spec.team.improve_s + self.timing.planner_timeout_s

    def accept(self, reply: PlanReply) -> str | None:
        if reply.team_plan is None:
            return "planning failed: the planner's reply carries no team plan"
        self.plan = plan = reply.team_plan
        if self.print_progress:
            print(format_team_plan(plan), flush=True)
        for r in self.reports.values():
            r.steps = len(plan.drone if r.robot == "drone" else plan.ugv)
        k = self.keys
        self.subscribe(k.all_vehicles("action_status"), ActionStatus, self._on_status)
        self.subscribe(k.all_sim_truth, SimTruth, self._on_truth)
        self._plans = self.publishers(lambda vid: k.vehicle(vid, "team_plan"), VehicleTeamPlan,
                                      congestion_control=zenoh.CongestionControl.BLOCK)
        self._last_progress = time.time()
        return None

    def hand_out(self, t0: float) -> None:
        assert self.plan is not None and self._plans is not None
        self._plans.put_all(robot_plans(self.plan, self.spec.team, self.mission, t0))

    def end_reason(self, now: float) -> str | None:
        done = sum(r.done for r in self.reports.values())
        if done != self._last_done:
            self._last_done, self._last_progress = done, now
        if all(r.mode == "done" for r in self.reports.values()):
            return FINISHED
        failed = [r for r in self.reports.values() if r.mode == "failed"]
        if failed:
            return f"{failed[0].vid} failed" + next((f": {e}" for e in self.events if "action_failed" in e), "")
        if now - self._last_progress > self.spec.stall_s:
            return f"no step completed for {self.spec.stall_s:.0f} s"
        return None

    def succeeded(self, reason: str) -> bool:
        return reason == FINISHED

    async def before_result(self) -> None:
        """Wait for a ground truth of the drone newer than its last state (if a simulator publishes one)."""
        drone = self.spec.team.drone
        deadline = time.monotonic() + TRUTH_WAIT_S
        while drone in self.truth and drone in self.states and self.truth[drone].t < self.states[drone].t:
            if time.monotonic() > deadline:
                return
            await asyncio.sleep(0.02)

    def progress_line(self, now: float) -> str:
        t = now - (self.t0 or now)
        return f"t={t:6.1f}s  " + "  ".join(f"{r.vid}:{r.mode} {r.done}/{r.steps}" for r in self.reports.values())

    # ---- inputs ---------------------------------------------------------------------------------
    def on_state(self, state: VehicleState) -> None:
        r = self.reports[state.vid]
        if state.mission != self.mission:
            return
        r.mode, r.done, r.owner = state.mode, state.step, state.owner
        r.pose = (state.x, state.y, state.z if r.robot == "drone" else math.degrees(state.yaw))
        if state.arrived and r.finished_s is None and self.t0 is not None:
            r.finished_s = state.t - self.t0

    def _on_status(self, status: ActionStatus, _key: str) -> None:
        r = self.reports.get(status.vid)
        if r is None or status.mission != self.spec.mission or self.plan is None:
            return
        if any(s.vid == status.vid and s.index == status.index and s.status == status.status for s in self.statuses):
            return  # a repeat (the robot answers re-sent actions with its status)
        self.statuses.append(status)
        if self.print_progress:
            steps = self.plan.drone if r.robot == "drone" else self.plan.ugv
            t = status.t - (self.t0 or status.t)
            pose = ", ".join(f"{v:.2f}" for v in status.pose)
            print(f"t={t:6.1f}s {r.robot:<5} {status.vid:<8} {status.index:3d} {action_name(steps[status.index]):<18} "
                  f"{status.status:<7} ({pose}) {status.detail}".rstrip(), flush=True)

    def _on_truth(self, truth: SimTruth, _key: str) -> None:
        if truth.vid in self.reports:
            self.truth[truth.vid] = truth

    # ---- the end --------------------------------------------------------------------------------
    def sync_violations(self) -> tuple[int, list[str]]:
        """Sync points of the plan, and those whose step started before the partner's awaited step
        was reported done (from the robots' own reports, one clock: the world's)."""
        if self.plan is None:
            return 0, []
        started = {(s.vid, s.index): s.t for s in self.statuses if s.status == "started"}
        done = {(s.vid, s.index): s.t for s in self.statuses if s.status == "done"}
        vids = {r.robot: vid for vid, r in self.reports.items()}
        count, broken = 0, []
        for robot in ("drone", "ugv"):
            partner = vids[PlanProgress.other(robot)]
            for i, step in enumerate(self.plan.drone if robot == "drone" else self.plan.ugv):
                if not step.wait_for or (vids[robot], i) not in started:
                    continue
                count += 1
                awaited = done.get((partner, step.wait_for - 1))
                if awaited is None or started[(vids[robot], i)] < awaited:
                    broken.append(f"{robot} step {i} started before {partner} step {step.wait_for - 1} was done")
        return count, broken

    def drone_position(self) -> tuple[float, float, float] | None:
        """The drone's position in ground truth if a simulator publishes it, else as reported."""
        truth = self.truth.get(self.spec.team.drone)
        if truth is not None:
            return (truth.x, truth.y, truth.z)
        return self.reports[self.spec.team.drone].pose

    def conclude(self, ok: bool, reason: str) -> TeamMissionResult:
        drone = self.drone_position()
        goal_error = math.dist(drone, self.plan.goal) if self.plan is not None and drone is not None else None
        count, broken = self.sync_violations()
        if ok and not (goal_error is not None and goal_error <= GOAL_TOLERANCE_M):
            ok, reason = False, f"{reason}; but the drone is not at the goal"
        if broken:
            ok, reason = False, f"{reason}; sync points were broken"
        self.result = TeamMissionResult(self.mission, ok, reason, self.elapsed(), self.plan, self.reports,
                                        goal_error, count, broken, self.events)
        return self.result
