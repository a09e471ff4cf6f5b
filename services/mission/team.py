"""`fleet collab mission`: one ground-air team plan run end to end through the executors (paper 002
§IV-E, plan execution with synchronisation points).

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
import itertools
import math
import time
import uuid
from dataclasses import dataclass, field

from common.bus.messages import (
    ActionStatus,
    MissionAbort,
    MissionStart,
    PlanReply,
    PlanRequest,
    SimTruth,
    TeamTask,
    VehicleEvent,
    VehicleState,
)
from common.bus.pubsub import QueryError, QueryTimeout, query
from common.bus.service import Service
from common.domain.team_plan import PlanProgress, Robot, TeamPlan, action_name
from services.planner.collab.cli import format_plan
from services.planner.collab.request import PLANNER, TeamPlanPublisher, robot_plans

GOAL_TOLERANCE_M = 0.25
"""The drone is at the goal within half a lattice cell (002 maps: 0.5 m cells)."""
TICK_S = 0.2
"""How often the mission looks at the robots' progress."""
RESEND_TICKS = 5
"""Plans and the start are re-sent every RESEND_TICKS ticks (late joiners, take-overs)."""
TRUTH_WAIT_S = 2.0
"""At the end, how long to wait for a ground truth of the drone newer than its last state."""


@dataclass(frozen=True)
class TeamMissionSpec:
    map: str
    team: TeamTask
    time_limit: float = 30.0
    mission: str = field(default_factory=lambda: f"t{uuid.uuid4().hex[:8]}")
    start_lead_s: float = 1.0
    ready_timeout_s: float = 20.0
    planner_timeout_s: float = 20.0
    stall_s: float = 60.0


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


class TeamMission(Service):
    """One team mission, as a short-lived service (`alive/mission/<id>`)."""

    def __init__(self, spec: TeamMissionSpec, *args, progress: bool = True, **kwargs) -> None:
        super().__init__("mission", spec.mission, *args, **kwargs)
        self.spec = spec
        self.print_progress = progress
        team = spec.team
        self.reports = {team.drone: RobotReport(team.drone, "drone"), team.ugv: RobotReport(team.ugv, "ugv")}
        self.states: dict[str, VehicleState] = {}
        self.statuses: list[ActionStatus] = []
        self.truth: dict[str, SimTruth] = {}
        self.events: list[str] = []
        self.t0: float | None = None
        self.plan: TeamPlan | None = None
        self.result: TeamMissionResult | None = None

    async def main(self) -> None:
        started = time.time()
        try:
            self.result = await self._run(started)
        except asyncio.CancelledError:
            self.result = self._finish(started, False, "interrupted")
            raise

    async def _run(self, started: float) -> TeamMissionResult:
        spec, team = self.spec, self.spec.team
        executors = await self.watch_alive("executor")
        if not executors.instances:
            return self._finish(started, False, "no executor is alive: start executors (fleet executor / fleet up)")
        request = PlanRequest(map=spec.map, tasks={}, planner=PLANNER, time_limit=spec.time_limit,
                              mission=spec.mission, team=team)
        wait = spec.time_limit + team.improve_s + spec.planner_timeout_s
        try:
            reply = await query(self.session, self.keys.planner_plan, request, PlanReply, timeout=wait)
        except QueryTimeout:
            return self._finish(started, False, f"the planner did not answer within {wait:.0f} s")
        except QueryError as exc:
            return self._finish(started, False, f"the planner is unreachable or failed: {exc}")
        if not reply.ok or reply.team_plan is None:
            return self._finish(started, False, f"planning failed: {reply.error}")
        self.plan = plan = reply.team_plan
        if self.print_progress:
            print(format_plan(plan), flush=True)
        for r in self.reports.values():
            r.steps = len(plan.drone if r.robot == "drone" else plan.ugv)
        k = self.keys
        self.subscribe(k.all_vehicles("state"), VehicleState, self._on_state)
        self.subscribe(k.all_vehicles("event"), VehicleEvent, self._on_event)
        self.subscribe(k.all_vehicles("action_status"), ActionStatus, self._on_status)
        self.subscribe(k.all_sim_truth, SimTruth, self._on_truth)
        plans = TeamPlanPublisher(self)
        start_pub = self.publisher(k.mission(spec.mission, "start"), MissionStart)
        abort_pub = self.publisher(k.mission(spec.mission, "abort"), MissionAbort)
        handed = robot_plans(plan, team, spec.mission)
        if not await self._wait_ready(spec.ready_timeout_s, lambda: plans.put(handed)):
            missing = sorted(v for v in self.reports if v not in self.states)
            return self._finish(started, False, f"executors did not take the team plan of {', '.join(missing)}")
        self.t0 = time.time() + spec.start_lead_s
        start = MissionStart(mission=spec.mission, t0=self.t0, vehicles=list(self.reports))
        handed = robot_plans(plan, team, spec.mission, self.t0)
        last_done, last_progress = -1, time.time()
        try:
            for tick in itertools.count():
                if tick % RESEND_TICKS == 0:
                    plans.put(handed)
                    start_pub.put(start)
                await asyncio.sleep(TICK_S)
                now = time.time()
                done = sum(r.done for r in self.reports.values())
                if done != last_done:
                    last_done, last_progress = done, now
                if all(r.mode == "done" for r in self.reports.values()):
                    reason = "both robots finished their sequences"
                    break
                failed = [r for r in self.reports.values() if r.mode == "failed"]
                if failed:
                    reason = f"{failed[0].vid} failed" + next((f": {e}" for e in self.events if "action_failed" in e), "")
                    break
                if now - last_progress > spec.stall_s:
                    reason = f"no step completed for {spec.stall_s:.0f} s"
                    break
        except asyncio.CancelledError:
            abort_pub.put(MissionAbort(mission=spec.mission, reason="aborted on request"))
            raise
        finished = all(r.mode == "done" for r in self.reports.values())
        if not finished:
            abort_pub.put(MissionAbort(mission=spec.mission, reason=reason))
        await self._fresh_truth(TRUTH_WAIT_S)
        result = self._finish(started, finished, reason)
        if finished and not (result.goal_error_m is not None and result.goal_error_m <= GOAL_TOLERANCE_M):
            result.ok = False
            result.reason += "; but the drone is not at the goal"
        if result.sync_violations:
            result.ok = False
            result.reason += "; sync points were broken"
        return result

    async def _fresh_truth(self, timeout: float) -> None:
        """Wait for a ground truth of the drone newer than its last state (if a simulator publishes one)."""
        drone = self.spec.team.drone
        deadline = time.monotonic() + timeout
        while drone in self.truth and drone in self.states and self.truth[drone].t < self.states[drone].t:
            if time.monotonic() > deadline:
                return
            await asyncio.sleep(0.02)

    async def _wait_ready(self, timeout: float, again) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            again()
            if all(v in self.states for v in self.reports):
                return True
            await asyncio.sleep(0.5)
        return False

    # ---- inputs ---------------------------------------------------------------------------------
    def _on_state(self, state: VehicleState, _key: str) -> None:
        r = self.reports.get(state.vid)
        if r is None or state.mission != self.spec.mission:
            return
        self.states[state.vid] = state
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

    def _on_event(self, event: VehicleEvent, _key: str) -> None:
        if event.vid in self.reports:
            self.events.append(f"{event.vid}: {event.kind} {event.detail}".strip())

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

    def _finish(self, started: float, ok: bool, reason: str) -> TeamMissionResult:
        drone = self.drone_position()
        goal_error = math.dist(drone, self.plan.goal) if self.plan is not None and drone is not None else None
        count, broken = self.sync_violations()
        self.result = TeamMissionResult(self.spec.mission, ok, reason, time.time() - started, self.plan, self.reports,
                                        goal_error, count, broken, self.events)
        return self.result
