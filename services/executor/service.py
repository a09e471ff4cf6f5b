"""The executor service (paper 000 §VI-C, Fig. 4: trajectory generator, state machine, driving and
flying controllers): one asyncio process running one control loop over the vehicles it owns.

Ownership is rendezvous hashing over the live executors (`common.ownership`), seen through
liveliness tokens: every executor computes the same assignment, so when one dies its vehicles pass
to the others as soon as its token disappears (under 1 s), and the gateways obey the new owner. A
vehicle taken over mid-mission resumes from the last state its previous owner published.

Inputs: `vehicle/*/plan`, `vehicle/*/pose`, `vehicle/*/telemetry`, `vehicle/*/state` (for
take-over), `mission/*/start`, `mission/*/abort`. Outputs for owned vehicles: `vehicle/<vid>/cmd`
at the control rate, `vehicle/<vid>/state` at the state rate, `vehicle/<vid>/event` on faults
(team plans of ground-air teams, paper 002: `services/executor/team.py`).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import time
from collections import deque

import numpy as np

from common.bus import Publisher
from common.messages import (
    Cmd,
    MissionAbort,
    MissionStart,
    Pose,
    Telemetry,
    VehicleEvent,
    VehiclePlan,
    VehicleState,
)
from common.ownership import owner_of
from common.service import Service
from common.svcargs import add_zenoh_args, keys_from_args, run_service, zconfig_from_args
from services.executor.team import TeamExecutor
from services.executor.vehicle_controller import VehicleController

log = logging.getLogger(__name__)

FAULT_MODES = {"emergency_landing": "emergency_landing", "holding": "holding"}


class LoopStats:
    """Tick lateness (how far after its due time a tick started) and tick cost, last N ticks."""

    def __init__(self, n: int = 2000) -> None:
        self.late: deque[float] = deque(maxlen=n)
        self.cost: deque[float] = deque(maxlen=n)
        self.ticks = 0
        self.missed = 0

    def add(self, late: float, cost: float, period: float) -> None:
        self.ticks += 1
        self.late.append(late)
        self.cost.append(cost)
        if late > period:
            self.missed += 1

    def percentiles(self) -> dict[str, float]:
        if not self.late:
            return {}
        late, cost = np.array(self.late), np.array(self.cost)
        return {"late_p50_ms": 1e3 * float(np.percentile(late, 50)), "late_p99_ms": 1e3 * float(np.percentile(late, 99)),
                "cost_p50_ms": 1e3 * float(np.percentile(cost, 50)), "cost_p99_ms": 1e3 * float(np.percentile(cost, 99))}


class ExecutorService(Service):
    def __init__(self, instance: str, *args, rate_hz: float = 100.0, state_hz: float = 20.0, **kwargs) -> None:
        super().__init__("executor", instance, *args, **kwargs)
        self.team = TeamExecutor(self)
        self.period = 1.0 / rate_hz
        self.state_every = max(1, round(rate_hz / state_hz))
        self.plans: dict[str, VehiclePlan] = {}
        self.starts: dict[str, float] = {}
        self.aborts: dict[str, str] = {}
        self.last_state: dict[str, VehicleState] = {}
        self.last_pose: dict[str, Pose] = {}
        """The latest pose of every vehicle, owned or not: a take-over starts from it."""
        self.controllers: dict[str, VehicleController] = {}
        self.live: frozenset[str] = frozenset()
        self.stats = LoopStats()
        self._cmd: dict[str, Publisher[Cmd]] = {}
        self._state: dict[str, Publisher[VehicleState]] = {}
        self._event: dict[str, Publisher[VehicleEvent]] = {}
        self._last_mode: dict[str, str] = {}

    # ---- wiring ---------------------------------------------------------------------------------
    async def main(self) -> None:
        k = self.keys
        self.subscribe(k.all_vehicles("plan"), VehiclePlan, self._on_plan)
        self.subscribe(k.all_vehicles("pose"), Pose, self._on_pose, maxlen=4096)
        self.subscribe(k.all_vehicles("telemetry"), Telemetry, self._on_telemetry, maxlen=1024)
        self.subscribe(k.all_vehicles("state"), VehicleState, self._on_state, maxlen=4096)
        self.subscribe(k.all_missions("start"), MissionStart, self._on_start)
        self.subscribe(k.all_missions("abort"), MissionAbort, self._on_abort)
        self.team.open()
        alive = await self.watch_alive("executor", lambda _i, _a, live: self._reassign(live))
        self._reassign(alive.instances)
        await self._control_loop()

    def _publisher(self, table: dict, vid: str, topic: str, typ: type) -> Publisher:
        pub = table.get(vid)
        if pub is None:
            pub = table[vid] = self.publisher(self.keys.vehicle(vid, topic), typ)
        return pub

    # ---- ownership ------------------------------------------------------------------------------
    def _reassign(self, live: frozenset[str]) -> None:
        """Take the vehicles that hash to us, release the others (rendezvous hashing)."""
        self.live = live | {self.instance}
        for vid in list(self.plans):
            mine = owner_of(vid, self.live) == self.instance
            if mine and vid not in self.controllers:
                self._take(vid)
            elif not mine and vid in self.controllers:
                log.info("%s: vehicle %s passes to %s", self.instance, vid, owner_of(vid, self.live))
                del self.controllers[vid]
        self.team.reassign(self.live)

    def _take(self, vid: str) -> None:
        plan = self.plans[vid]
        ctl = VehicleController(vid, plan.model, owner=self.instance)
        ctl.load(plan)
        t0 = plan.t0 or self.starts.get(plan.mission)
        if t0:
            ctl.start(t0)
        prev = self.last_state.get(vid)
        if prev is not None and prev.mission == plan.mission and prev.owner != self.instance:
            ctl.take_over(prev, time.time())
            pose = self.last_pose.get(vid)
            if pose is not None and pose.t > prev.t:  # after a partition the last state is a lease (~1 s) old
                ctl.on_pose(pose)
            log.warning("%s: took over %s from %s in mode %s", self.instance, vid, prev.owner, prev.mode)
        if plan.mission in self.aborts:
            ctl.abort(self.aborts[plan.mission])
        self.controllers[vid] = ctl

    # ---- inputs ---------------------------------------------------------------------------------
    def _on_plan(self, plan: VehiclePlan, _key: str) -> None:
        known = self.plans.get(plan.vid)
        if known is not None and known.mission == plan.mission and known.steps == plan.steps:
            if plan.t0 and plan.vid in self.controllers and self.controllers[plan.vid].t0 is None:
                self.controllers[plan.vid].start(plan.t0)
            self.plans[plan.vid] = plan
            return
        ctl = self.controllers.get(plan.vid)
        if ctl is not None:
            if ctl.load(plan):  # refused while airborne: the old plan stays until it has landed
                self.plans[plan.vid] = plan
                t0 = plan.t0 or self.starts.get(plan.mission)
                if t0:
                    ctl.start(t0)
            return
        self.plans[plan.vid] = plan
        if owner_of(plan.vid, self.live | {self.instance}) == self.instance:
            self._take(plan.vid)

    def _on_start(self, start: MissionStart, _key: str) -> None:
        if self.starts.get(start.mission) == start.t0:
            return
        self.starts[start.mission] = start.t0
        self.team.on_start(start)
        for vid, ctl in self.controllers.items():
            if self.plans[vid].mission == start.mission:
                ctl.start(start.t0)

    def _on_abort(self, abort: MissionAbort, _key: str) -> None:
        if abort.mission in self.aborts:
            return
        self.aborts[abort.mission] = abort.reason
        self.team.on_abort(abort)
        for vid, ctl in self.controllers.items():
            if self.plans[vid].mission == abort.mission:
                ctl.abort(abort.reason)

    def _on_pose(self, pose: Pose, _key: str) -> None:
        self.last_pose[pose.vid] = pose
        ctl = self.controllers.get(pose.vid)
        if ctl is not None:
            ctl.on_pose(pose)

    def _on_telemetry(self, tel: Telemetry, _key: str) -> None:
        ctl = self.controllers.get(tel.vid)
        if ctl is not None:
            ctl.on_telemetry(tel, time.time())

    def _on_state(self, state: VehicleState, _key: str) -> None:
        self.team.on_state(state)
        if state.owner != self.instance:
            self.last_state[state.vid] = state

    # ---- the loop -------------------------------------------------------------------------------
    async def _control_loop(self) -> None:
        due = time.monotonic()
        n = 0
        while True:
            start = time.monotonic()
            now = time.time()
            for vid, ctl in list(self.controllers.items()):
                cmd, state = ctl.tick(now)
                self._publisher(self._cmd, vid, "cmd", Cmd).put(cmd)
                if n % self.state_every == 0:
                    self._publisher(self._state, vid, "state", VehicleState).put(state)
                self._report_mode(vid, state, now)
            n += 1
            end = time.monotonic()
            self.stats.add(start - due, end - start, self.period)
            due += self.period
            if end - due > 10 * self.period:  # hopelessly behind (suspended?): skip, don't burst
                due = end
            await asyncio.sleep(max(0.0, due - time.monotonic()))

    def _report_mode(self, vid: str, state: VehicleState, now: float) -> None:
        prev = self._last_mode.get(vid)
        self._last_mode[vid] = state.mode
        if prev != state.mode and state.mode in FAULT_MODES:
            self._publisher(self._event, vid, "event", VehicleEvent).put(
                VehicleEvent(vid=vid, t=now, kind=FAULT_MODES[state.mode], detail=f"from {prev}"))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("executor", help="run an executor: control loops for the vehicles it owns")
    p.add_argument("--rate", type=float, default=100.0, help="control rate (Hz)")
    p.add_argument("--state-rate", type=float, default=20.0, help="state publication rate (Hz)")
    add_zenoh_args(p, default_instance="executor")
    p.set_defaults(handler=cmd_executor)


def cmd_executor(args: argparse.Namespace) -> int:
    svc = ExecutorService(args.instance, zconfig_from_args(args), keys_from_args(args),
                          rate_hz=args.rate, state_hz=args.state_rate)
    return run_service(svc)
