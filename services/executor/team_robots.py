"""Team plans on the executor (paper 002 §IV-E: plan execution with synchronisation points).

An executor that owns a robot of a team plan (`vehicle/<vid>/team_plan`; the same rendezvous
ownership as flying cars) runs that robot's steps in order, from the mission's start time on. A
step with `wait_for = n` starts only once the partner robot has completed n steps: the partner's
progress is its `VehicleState.step`, published by whichever executor owns it (this one or
another). The step goes to the robot as a `TeamAction` on `vehicle/<vid>/action`, re-sent every
`RESEND_S` until the robot reports it done or failed on `vehicle/<vid>/action_status`; every
change of progress is published at once as a `VehicleState` (step = steps done, mode), and again
every `HEARTBEAT_S`. A failed action stops the robot's sequence with a `VehicleEvent`
("action_failed"), except a drone action that ended near, but not at, its planned end: under
sensing noise (002 §III-B; `services/sim/team/world.py` `SensingNoise`) a trigger fires early or
late, or a landmark is mis-measured, and the drone stops in a neighbouring cell. That step is
re-tried from where the drone is (a new `attempt` of the same index, up to `RETRIES` times): its
perceptual controller localizes afresh on the wall, landmark or UGV it needs, so the re-try ends
where the plan does unless the noise strikes again; the partner waits meanwhile (the step is not
done). A robot taken over from a dead executor resumes at the step its last state named: robots run
each (mission, index, attempt) once, so re-sending the step in flight (or a re-try) is safe.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable

from common.bus.messages import (
    ActionStatus,
    MissionAbort,
    MissionStart,
    TeamAction,
    VehicleEvent,
    VehicleState,
    VehicleTeamPlan,
)
from common.bus.service import Service
from common.domain.team_plan import PlanProgress, Vec3, action_name
from services.executor.takeover import VehicleOwnership

log = logging.getLogger(__name__)

RESEND_S = 0.5
"""An unanswered or unfinished action is sent again this often (zenoh keeps no history)."""
HEARTBEAT_S = 0.5
"""A team robot's state is re-published this often without changes (late joiners, take-over)."""
TICK_S = 0.05
"""Period of the timer that starts sequences at their start time, re-sends and heartbeats."""
RETRIES = 2
"""Re-tries of a drone step that ended off its planned end before the robot's sequence fails."""
RETRY_RADIUS_M = 0.75
"""An off-plan end this near the planned one (a neighbouring cell of the 0.5 m lattice, diagonals
included) is a trigger fired early or late; farther away, the plan no longer fits the world."""


class TeamRobot:
    """One robot's side of a team plan on the executor that owns it; no I/O (TeamExecutor does it).

    Modes: `loaded` (not started), `waiting` (at a sync point), `acting` (an action is with the
    robot), `done`, `failed`, `aborted`.
    """

    def __init__(self, assignment: VehicleTeamPlan, owner: str, resume: VehicleState | None = None) -> None:
        self.assignment = assignment
        self.owner = owner
        self.robot = assignment.robot
        self.progress = PlanProgress(assignment.plan)
        self.steps = self.progress.steps[self.robot]
        plan = assignment.plan
        self.pose: Vec3 = plan.drone_start if self.robot == "drone" else plan.ugv_start
        self.t0: float | None = None
        self.inflight: int | None = None
        self.attempt = 0
        """Of the step in flight: 0, then 1.. for its re-tries."""
        self.retries = 0
        """Re-tries made over the whole sequence (sensing noise at work)."""
        self.sent_from: Vec3 | None = None
        """The robot's reported pose when the step in flight was first sent."""
        self.sent_at = -math.inf
        self.failure = ""
        self.aborted = ""
        if resume is not None:
            self.progress.observe(self.robot, resume.step)
            self.pose = _pose_of(resume, self.robot)
            if resume.mode == "failed":
                self.failure = f"failed under {resume.owner}"

    @property
    def done(self) -> int:
        return self.progress.done[self.robot]

    @property
    def finished(self) -> bool:
        return self.progress.next_step(self.robot) is None

    @property
    def mode(self) -> str:
        if self.failure:
            return "failed"
        if self.aborted:
            return "aborted"
        if self.finished:
            return "done"
        if self.t0 is None:
            return "loaded"
        return "acting" if self.inflight is not None else "waiting"

    def start(self, t0: float) -> None:
        self.t0 = t0

    def abort(self, reason: str) -> None:
        if not (self.finished or self.failure):
            self.aborted = reason

    def partner_progress(self, done: int) -> bool:
        """The partner has completed `done` steps; True if that is news."""
        return self.progress.observe(PlanProgress.other(self.robot), done)

    def action(self, now: float) -> TeamAction | None:
        """The action to send now: the next step once the mission has started and its sync point is
        met, then the same again every RESEND_S until the robot reports it done or failed."""
        if self.failure or self.aborted or self.t0 is None or now < self.t0:
            return None
        if self.inflight is None:
            if not self.progress.can_start(self.robot):
                return None
            self.inflight, self.attempt, self.sent_at, self.sent_from = self.done, 0, -math.inf, self.pose
        if now - self.sent_at < RESEND_S:
            return None
        self.sent_at = now
        return TeamAction(vid=self.assignment.vid, owner=self.owner, mission=self.assignment.mission, index=self.inflight,
                          step=self.steps[self.inflight], t=now, attempt=self.attempt)

    def on_status(self, status: ActionStatus) -> bool:
        """The robot's report on its current step (also one a previous owner sent); True if the
        robot's progress, pose or mode changed. A failed drone step that ended off its planned end
        is re-tried (`retry`) instead of failing the sequence."""
        if (status.mission != self.assignment.mission or status.index != self.done or self.failure
                or status.status == "started" or status.attempt < self.attempt):
            return False
        self.pose = status.pose
        self.attempt = status.attempt
        if status.status == "failed" and self.retry(status):
            self.attempt += 1
            self.retries += 1
            self.inflight, self.sent_at, self.sent_from = status.index, -math.inf, status.pose
            log.info("%s: step %d (%s) ended at %s, off its planned end: re-try %d", self.assignment.vid,
                     status.index, action_name(self.steps[status.index]), status.pose, self.attempt)
            return True
        self.inflight = None
        if status.status == "failed":
            tries = f" (after {status.attempt} re-tries)" if status.attempt else ""
            self.failure = f"step {status.index} ({action_name(self.steps[status.index])}): {status.detail}{tries}"
        else:
            self.progress.complete(self.robot)
            self.attempt = 0
        return True

    def retry(self, status: ActionStatus) -> bool:
        """Whether a failed step is re-tried: a drone step, re-tries left, and the drone moved (the
        action ran) to within `RETRY_RADIUS_M` of the planned end at its altitude, but not onto it."""
        end = self.steps[status.index].end
        moved = self.sent_from is None or math.dist(status.pose, self.sent_from) > 1e-6
        off = math.dist(status.pose[:2], end[:2])
        return (self.robot == "drone" and status.attempt < RETRIES and moved and abs(status.pose[2] - end[2]) < 1e-6
                and 1e-6 < off <= RETRY_RADIUS_M)

    def state(self, now: float) -> VehicleState:
        """Progress for the partner's executor and the mission: step = steps done; the pose the robot
        reported last; tracking error = its distance from where the plan put it."""
        x, y, third = self.pose
        planned = self.steps[self.done - 1].end if self.done else self.pose
        drone = self.robot == "drone"
        return VehicleState(
            vid=self.assignment.vid, t=now, owner=self.owner, mode=self.mode, x=x, y=y, z=third if drone else 0.0,
            yaw=0.0 if drone else math.radians(third), mission=self.assignment.mission, step=self.done, steps=len(self.steps),
            tracking_error=math.dist(self.pose[:2], planned[:2]), arrived=self.finished and not self.failure)


def _pose_of(state: VehicleState, robot: str) -> Vec3:
    """A team robot's pose from its VehicleState (the inverse of `TeamRobot.state`)."""
    return (state.x, state.y, state.z) if robot == "drone" else (state.x, state.y, math.degrees(state.yaw))


class TeamExecutor:
    """The team-plan side of an executor service: holds the team plans it hears of, runs the robots
    it owns, and publishes their actions, states and failures. The service calls `open()` from its
    main and forwards ownership changes, states, mission starts and aborts."""

    def __init__(self, service: Service, publish_states: Callable[[list[VehicleState], float], None]) -> None:
        self.svc = service
        self._publish_states = publish_states
        self.plans: dict[str, VehicleTeamPlan] = {}
        self.robots: dict[str, TeamRobot] = {}
        self.ownership = VehicleOwnership(service.instance, lambda vid: vid in self.robots, self._take,
                                          lambda vid: self.robots.pop(vid, None))
        self.progress: dict[tuple[str, str], int] = {}
        """(mission, vid) -> steps done, from every team robot's state."""
        self.starts: dict[str, float] = {}
        self.aborts: dict[str, str] = {}
        self._stated: dict[str, tuple[float, str, int]] = {}
        """vid -> (time, mode, steps done) of its last published state."""

    def open(self) -> None:
        k = self.svc.keys
        self._actions = self.svc.publishers(lambda vid: k.vehicle(vid, "action"), TeamAction)
        self._events = self.svc.publishers(lambda vid: k.vehicle(vid, "event"), VehicleEvent)
        self.svc.subscribe(k.all_vehicles("team_plan"), VehicleTeamPlan, self._on_plan)
        self.svc.subscribe(k.all_vehicles("action_status"), ActionStatus, self._on_status)
        self.svc.spawn(self._timer(), name="team timer")

    # ---- hooks of the executor service --------------------------------------------------------
    def reassign(self, live: frozenset[str]) -> None:
        """Take the team robots that hash to this executor, release the others."""
        self.ownership.reassign(live, self.plans)

    def on_state(self, state: VehicleState) -> None:
        self.ownership.on_state(state)
        if state.mission and state.vid in self.plans:
            self._progressed(state.mission, state.vid, state.step)

    def on_start(self, start: MissionStart) -> None:
        self.starts[start.mission] = start.t0
        for vid, robot in self.robots.items():
            if robot.assignment.mission == start.mission and robot.t0 is None:
                robot.start(start.t0)
                self._advance(vid)

    def on_abort(self, abort: MissionAbort) -> None:
        if not abort.vehicles:
            self.aborts[abort.mission] = abort.reason
        for vid, robot in self.robots.items():
            if robot.assignment.mission == abort.mission and (not abort.vehicles or vid in abort.vehicles):
                robot.abort(abort.reason)
                self._advance(vid)

    # ---- inputs ---------------------------------------------------------------------------------
    def _on_plan(self, assigned: VehicleTeamPlan, _key: str) -> None:
        robot = self.robots.get(assigned.vid)
        if robot is not None and robot.assignment.mission == assigned.mission:
            if assigned.t0 and robot.t0 is None:
                robot.start(assigned.t0)
                self._advance(assigned.vid)
            return
        if robot is not None and robot.mode == "acting":
            return  # a new mission waits until the robot has finished its action (the mission re-sends)
        self.plans[assigned.vid] = assigned
        self.ownership.claim(assigned.vid)

    def _on_status(self, status: ActionStatus, _key: str) -> None:
        robot = self.robots.get(status.vid)
        if robot is None or not robot.on_status(status):
            return
        if robot.failure:
            log.warning("%s: team robot %s failed: %s", self.svc.instance, status.vid, robot.failure)
            self._events.put(status.vid, VehicleEvent(vid=status.vid, t=time.time(), kind="action_failed", detail=robot.failure))
        self._advance(status.vid)

    # ---- running --------------------------------------------------------------------------------
    def _take(self, vid: str) -> None:
        assigned = self.plans[vid]
        resume = self.ownership.resume_from(vid, assigned.mission)
        if resume is not None:
            log.warning("%s: took over team robot %s from %s at step %d", self.svc.instance, vid, resume.owner, resume.step)
        robot = self.robots[vid] = TeamRobot(assigned, self.svc.instance, resume)
        robot.partner_progress(self.progress.get((assigned.mission, assigned.partner), 0))
        t0 = assigned.t0 or self.starts.get(assigned.mission)
        if t0:
            robot.start(t0)
        if assigned.mission in self.aborts:
            robot.abort(self.aborts[assigned.mission])
        self._stated.pop(vid, None)
        self._advance(vid)

    def _progressed(self, mission: str, vid: str, done: int) -> None:
        """`vid` has completed `done` steps of `mission`: its partner may go on."""
        if self.progress.get((mission, vid), -1) >= done:
            return
        self.progress[(mission, vid)] = done
        for other, robot in self.robots.items():
            if robot.assignment.partner == vid and robot.assignment.mission == mission and robot.partner_progress(done):
                self._advance(other)

    def _advance(self, vid: str) -> None:
        """Send what is due for robot `vid`; publish its state when its mode or progress changed,
        or when the heartbeat is due."""
        robot = self.robots.get(vid)
        if robot is None:
            return
        now = time.time()
        action = robot.action(now)
        if action is not None:
            self._actions.put(vid, action)
        last = self._stated.get(vid)
        if last is None or last[1:] != (robot.mode, robot.done) or now - last[0] >= HEARTBEAT_S:
            self._stated[vid] = (now, robot.mode, robot.done)
            self._publish_states([robot.state(now)], now)
            self._progressed(robot.assignment.mission, vid, robot.done)

    async def _timer(self) -> None:
        while True:
            for vid in list(self.robots):
                self._advance(vid)
            await asyncio.sleep(TICK_S)
