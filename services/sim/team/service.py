"""`fleet sim team`: a simulated ground-air team on a map (paper 002 §V), over zenoh.

It holds one `TeamWorld` (the map, the drone, the UGV and the sensing their controllers need) and
runs each `TeamAction` an executor sends on `vehicle/<vid>/action` through the same code as
`TeamSim`: the controller's Phi from the robots' actual poses, so the drone follows walls by its
side ranges and flies to landmarks and to the UGV's markers only when it sees them (002 §III-B).
An action takes its simulated duration divided by `time_scale` in real time; the robot reports
`started`, then `done` or `failed` with its pose, on `vehicle/<vid>/action_status`. Its outcome is
decided from the world as the action starts and the robot moves when it ends: a drone that flies to
a UGV still on its way sees it where it was. Each robot runs one action at a time and each
(mission, index, attempt) once (an executor's re-try is a new attempt); a repeated action is answered with its status (also an earlier one: an
executor that takes a robot over without its last state replays the finished steps). Ground truth
(`sim/truth/<vid>`) for both robots at `truth_hz`, moving linearly during an action.
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass

from common.bus.messages import ActionStatus, SimTruth, TeamAction
from common.bus.pubsub import Publisher
from common.bus.service import Service
from common.bus.session import ZenohConfig
from common.domain.team_plan import Robot, Vec3
from services.sim.team.world import ActionOutcome, TeamWorld


@dataclass
class _Run:
    """A robot's latest action: its status now, and its motion for the ground truth."""

    mission: str
    index: int
    attempt: int
    status: ActionStatus
    outcome: ActionOutcome
    start: Vec3
    started: float
    ends: float


class TeamSimService(Service):
    """The world of one team: `vids` names the drone's and the UGV's vehicle ids."""

    def __init__(self, instance: str, zconfig: ZenohConfig, keys, world: TeamWorld, vids: dict[Robot, str],
                 time_scale: float = 1.0, truth_hz: float = 10.0) -> None:
        super().__init__("team-sim", instance, zconfig, keys)
        if time_scale <= 0 or truth_hz <= 0:
            raise ValueError("time_scale and truth_hz must be positive")
        self.world = world
        self.robots: dict[str, Robot] = {vid: robot for robot, vid in vids.items()}
        self.time_scale = time_scale
        self.truth_period = 1.0 / truth_hz
        self.runs: dict[str, _Run] = {}
        self.finished: dict[tuple[str, str, int, int], ActionStatus] = {}
        """(vid, mission, index, attempt) -> how the action ended."""
        self._status: dict[str, Publisher[ActionStatus]] = {}
        self._truth: dict[str, Publisher[SimTruth]] = {}

    async def main(self) -> None:
        for vid in self.robots:
            self._status[vid] = self.publisher(self.keys.vehicle(vid, "action_status"), ActionStatus)
            self._truth[vid] = self.publisher(self.keys.sim_truth(vid), SimTruth)
        self.subscribe(self.keys.all_vehicles("action"), TeamAction, self._on_action)
        while True:
            now = time.time()
            for vid, robot in self.robots.items():
                self._truth[vid].put(self._truth_of(vid, robot, now))
            await asyncio.sleep(self.truth_period)

    def _on_action(self, action: TeamAction, _key: str) -> None:
        robot = self.robots.get(action.vid)
        if robot is None:
            return
        run = self.runs.get(action.vid)
        key = (action.mission, action.index, action.attempt)
        ended = self.finished.get((action.vid, *key))
        if ended is not None or (run is not None and (run.mission, run.index, run.attempt) == key):
            self._status[action.vid].put(ended or run.status)  # a repeat: its status
            return
        if run is not None and run.status.status == "started":
            self.counters.inc(f"busy:{action.vid}")  # one action at a time: the sender asks again
            return
        start = self.world.xyz(robot)
        out = self.world.outcome(robot, action.step)
        now = time.time()
        status = ActionStatus(vid=action.vid, mission=action.mission, index=action.index, status="started",
                              pose=start, t=now, attempt=action.attempt)
        run = self.runs[action.vid] = _Run(action.mission, action.index, action.attempt, status, out, start, now,
                                           now + out.duration_s / self.time_scale)
        self._status[action.vid].put(status)
        self.spawn(self._finish(action.vid, robot, run), name=f"{action.vid} step {action.index}")

    async def _finish(self, vid: str, robot: Robot, run: _Run) -> None:
        await asyncio.sleep(max(0.0, run.ends - time.time()))
        self.world.apply(robot, run.outcome)
        run.status = ActionStatus(vid=vid, mission=run.mission, index=run.index,
                                  status="done" if run.outcome.ok else "failed", pose=self.world.xyz(robot),
                                  t=time.time(), detail=run.outcome.detail, attempt=run.attempt)
        self.finished[(vid, run.mission, run.index, run.attempt)] = run.status
        self._status[vid].put(run.status)

    def _truth_of(self, vid: str, robot: Robot, now: float) -> SimTruth:
        pose = self.world.xyz(robot)
        run = self.runs.get(vid)
        if run is not None and run.status.status == "started":
            end = self.world.metres(run.outcome.pose)
            pose = _between(run.start, end, (now - run.started) / max(run.ends - run.started, 1e-9), robot)
        x, y, third = pose
        if robot == "drone":
            return SimTruth(vid=vid, t=now, x=x, y=y, z=third, yaw=0.0, airborne=True, motors=True)
        return SimTruth(vid=vid, t=now, x=x, y=y, z=0.0, yaw=math.radians(third), motors=True)


def _between(a: Vec3, b: Vec3, f: float, robot: Robot) -> Vec3:
    """Linear motion from a to b at fraction f (the UGV's heading turns the short way)."""
    f = min(max(f, 0.0), 1.0)
    third = a[2] + (b[2] - a[2]) * f if robot == "drone" else a[2] + ((b[2] - a[2] + 180.0) % 360.0 - 180.0) * f
    return (a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, third)
