"""`fleet mission run`: ask the planner for a plan, hand it out, start every executor at a common
time, show progress, and end with a summary (arrived, time, energy per vehicle, largest tracking
error, smallest separation between bodies in ground truth). Aborts on request (SIGINT/SIGTERM) or
on a vehicle fault, landing every vehicle. A fault is a fault event (`FAULT_EVENTS`), a vehicle
state in emergency landing, or no state from a vehicle for `contact_timeout_s` (2 s: its executor or the
router is gone: events published meanwhile are lost, and the gateways land what they cannot hear
commands for). Fails fast when no executor or no planner is alive.

While the mission runs, plans and the start message are re-published every second so that an
executor that joins late or takes over a vehicle has them (zenoh keeps no history by itself).
"""

from __future__ import annotations

import asyncio
import logging
import time
import uuid
from dataclasses import dataclass, field

from common.bus.messages import (
    MissionAbort,
    MissionStart,
    PlanReply,
    PlanRequest,
    SimTruth,
    VehicleEvent,
    VehicleState,
)
from common.bus.pubsub import QueryError, QueryTimeout, query
from common.bus.service import Service
from common.bus.vehicle_plans import PlanPublisher, vehicle_plans
from common.domain.planfile import Plan, Task
from services.mission.separation import SeparationMonitor

log = logging.getLogger(__name__)

FAULT_EVENTS = frozenset({"emergency_landing", "low_battery", "link_lost", "crash", "stale_cmd_landing",
                          "controller_failed"})
"""Events that abort a mission. A motion-capture dropout (`mocap_lost`) is not one by itself: the
executor predicts through short dropouts and reports what it does about long ones (an emergency
landing, or holding on the ground)."""


@dataclass(frozen=True)
class MissionSpec:
    map: str
    tasks: dict[str, Task]
    planner: str = "sipp"
    mu: float = 0.5
    time_limit: float = 30.0
    mission: str = field(default_factory=lambda: f"m{uuid.uuid4().hex[:8]}")
    start_lead_s: float = 2.0
    ready_timeout_s: float = 20.0
    planner_timeout_s: float = 10.0
    slack_s: float = 20.0
    abort_on_fault: bool = True
    contact_timeout_s: float = 2.0


@dataclass
class VehicleReport:
    vid: str
    arrived: bool = False
    arrival_s: float | None = None
    planned_s: float = 0.0
    energy_j: float = 0.0
    max_tracking_error: float = 0.0
    sq_error: dict[str, float] = field(default_factory=lambda: {"ground": 0.0, "air": 0.0})
    samples: dict[str, int] = field(default_factory=lambda: {"ground": 0, "air": 0})
    mode: str = "?"
    step: int = 0
    steps: int = 0
    owner: str = ""

    def rms_error(self, where: str) -> float:
        """RMS tracking error on the ground or in the air, from the executors' states (m)."""
        n = self.samples[where]
        return (self.sq_error[where] / n) ** 0.5 if n else 0.0


AIRBORNE_MODES = frozenset({"taking_off", "flying", "landing", "emergency_landing"})


@dataclass
class MissionResult:
    mission: str
    ok: bool
    reason: str
    vehicles: dict[str, VehicleReport]
    min_gap: float
    min_pair: tuple[str, str]
    contacts: int
    duration_s: float
    plan: Plan | None = None
    events: list[str] = field(default_factory=list)

    def summary(self) -> str:
        lines = [f"mission {self.mission}: {'OK' if self.ok else 'FAILED'} ({self.reason}) in {self.duration_s:.1f} s"]
        lines.append(f"{'vehicle':<8} {'arrived':>7} {'time s':>7} {'plan s':>7} {'energy J':>9} {'max err m':>9} "
                     f"{'rms ground':>10} {'rms air':>8}  mode")
        for r in self.vehicles.values():
            t = f"{r.arrival_s:.1f}" if r.arrival_s is not None else "-"
            lines.append(f"{r.vid:<8} {str(r.arrived):>7} {t:>7} {r.planned_s:>7.1f} {r.energy_j:>9.1f} "
                         f"{r.max_tracking_error:>9.3f} {r.rms_error('ground'):>10.3f} {r.rms_error('air'):>8.3f}  {r.mode}")
        gap = "none closer than 1 m" if self.min_gap == float("inf") else f"{self.min_gap * 100:.1f} cm ({self.min_pair[0]}-{self.min_pair[1]})"
        lines.append(f"smallest separation between bodies (ground truth, beyond contact): {gap}; contacts: {self.contacts}")
        lines.extend(f"event: {e}" for e in self.events[:20])
        return "\n".join(lines)


class MissionRunner(Service):
    """One mission, as a short-lived service (`alive/mission/<id>`)."""

    def __init__(self, spec: MissionSpec, *args, progress: bool = True, **kwargs) -> None:
        super().__init__("mission", spec.mission, *args, **kwargs)
        self.spec = spec
        self.progress = progress
        self.result: MissionResult | None = None
        self.reports = {vid: VehicleReport(vid) for vid in spec.tasks}
        self.states: dict[str, VehicleState] = {}
        self.events: list[str] = []
        self.fault: str | None = None
        self.heard: dict[str, float] = {}  # vid -> arrival of its latest state
        self.t0: float | None = None
        self.voltage = 3.7

    async def main(self) -> None:
        started = time.time()
        try:
            self.result = await self._run(started)
        except asyncio.CancelledError:
            self.result = self._finish(started, False, "interrupted")
            raise

    async def _run(self, started: float) -> MissionResult:
        spec = self.spec
        executors = await self.watch_alive("executor")
        if not executors.instances:
            return self._finish(started, False, "no executor is alive: start executors (fleet executor / fleet up)")
        if not (await self.watch_alive("planner")).instances:
            return self._finish(started, False, "no planner is alive: start one (fleet planner / fleet up)")
        try:
            reply = await query(self.session, self.keys.planner_plan,
                                PlanRequest(map=spec.map, tasks=spec.tasks, planner=spec.planner, mu=spec.mu,
                                            time_limit=spec.time_limit, mission=spec.mission),
                                PlanReply, timeout=spec.time_limit + spec.planner_timeout_s)
        except QueryTimeout:
            return self._finish(started, False, f"the planner did not answer within {spec.time_limit + spec.planner_timeout_s:.0f} s")
        except QueryError as exc:
            return self._finish(started, False, f"the planner is unreachable or failed: {exc}")
        if not reply.ok or reply.plan is None:
            return self._finish(started, False, f"planning failed: {reply.error}")
        plan = reply.plan
        self.voltage = plan.model.voltage
        for vid, path in plan.paths.items():
            self.reports[vid].planned_s = path[-1].t
        sep = SeparationMonitor(*plan.model.body())  # physical bodies, not the planning envelope
        self.subscribe(self.keys.all_vehicles("state"), VehicleState, self._on_state)
        self.subscribe(self.keys.all_vehicles("event"), VehicleEvent, self._on_event)
        self.subscribe(self.keys.all_sim_truth, SimTruth, lambda t, _k: sep.update(t))
        plans = PlanPublisher(self)
        start_pub = self.publisher(self.keys.mission(spec.mission, "start"), MissionStart)
        abort_pub = self.publisher(self.keys.mission(spec.mission, "abort"), MissionAbort)
        handed = vehicle_plans(plan, spec.mission)
        plans.put(handed)
        ready = await self._wait_ready(spec.ready_timeout_s, lambda: plans.put(handed))
        if not ready:
            missing = sorted(v for v in spec.tasks if self.states.get(v, None) is None or self.states[v].mission != spec.mission)
            return self._finish(started, False, f"executors did not take the plans of {', '.join(missing)}", plan)
        self.t0 = time.time() + spec.start_lead_s
        start = MissionStart(mission=spec.mission, t0=self.t0, vehicles=list(spec.tasks))
        handed = vehicle_plans(plan, spec.mission, self.t0)
        deadline = self.t0 + max(r.planned_s for r in self.reports.values()) + spec.slack_s
        last_print = 0.0
        reason = ""
        try:
            while True:
                now = time.time()
                plans.put(handed)
                start_pub.put(start)
                for _ in range(10):
                    sep.sample()
                    await asyncio.sleep(0.1)
                if self.progress and now - last_print > 2.0:
                    last_print = now
                    print(self._progress_line(now), flush=True)
                if all(r.arrived for r in self.reports.values()):
                    reason = "every vehicle arrived"
                    break
                self._check_contact(time.time())
                if self.fault and spec.abort_on_fault:
                    reason = f"aborted on fault: {self.fault}"
                    break
                if now > deadline:
                    reason = "time limit: not every vehicle arrived"
                    break
        except asyncio.CancelledError:
            reason = "aborted on request"
            abort_pub.put(MissionAbort(mission=spec.mission, reason=reason))
            raise
        if not all(r.arrived for r in self.reports.values()):
            abort_pub.put(MissionAbort(mission=spec.mission, reason=reason))
            await self._wait_landed(10.0, lambda: abort_pub.put(MissionAbort(mission=spec.mission, reason=reason)))
        ok = reason == "every vehicle arrived" and not sep.contacts  # landing at its goal after a fault is no success
        if sep.contacts:
            reason += f"; bodies came into contact {len(sep.contacts)} times"
        result = self._finish(started, ok, reason, plan)
        result.min_gap, result.min_pair, result.contacts = sep.min_gap, sep.min_pair, len(sep.contacts)
        return result

    async def _wait_ready(self, timeout: float, again) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(self.states.get(v) is not None and self.states[v].mission == self.spec.mission for v in self.spec.tasks):
                return True
            again()
            await asyncio.sleep(0.5)
        return False

    async def _wait_landed(self, timeout: float, again) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(s.mode in ("done", "parked", "holding") for s in self.states.values()):
                return
            again()
            await asyncio.sleep(0.5)

    def _on_state(self, state: VehicleState, _key: str) -> None:
        r = self.reports.get(state.vid)
        if r is None:
            return
        self.states[state.vid] = state
        self.heard[state.vid] = time.time()
        r.mode, r.step, r.steps, r.owner = state.mode, state.step, state.steps, state.owner
        if state.mission != self.spec.mission or self.t0 is None:
            return
        r.energy_j = state.charge_used_ah * 3600.0 * self.voltage  # eq. 4-5 backwards
        r.max_tracking_error = max(r.max_tracking_error, state.tracking_error)
        if state.mode in AIRBORNE_MODES or state.mode in ("driving",):
            where = "air" if state.mode in AIRBORNE_MODES else "ground"
            r.sq_error[where] += state.tracking_error**2
            r.samples[where] += 1
        if state.mode == "emergency_landing":  # its event may have been lost with the router
            self.fault = self.fault or f"{state.vid}: in emergency landing"
        if state.arrived and not r.arrived:
            r.arrived, r.arrival_s = True, state.t - self.t0

    def _check_contact(self, now: float) -> None:
        """A vehicle not heard from for `contact_timeout_s` is a fault (its owner or the router is gone)."""
        for vid in self.spec.tasks:
            silent = now - self.heard.get(vid, now)
            if silent > self.spec.contact_timeout_s:
                self.fault = self.fault or f"{vid}: lost contact (no state for {silent:.1f} s)"

    def _on_event(self, event: VehicleEvent, _key: str) -> None:
        text = f"{event.vid}: {event.kind} {event.detail}".strip()
        self.events.append(text)
        log.warning("vehicle event: %s", text)
        if event.kind in FAULT_EVENTS and event.vid in self.reports:
            self.fault = self.fault or text

    def _progress_line(self, now: float) -> str:
        t = now - (self.t0 or now)
        parts = [f"{r.vid}:{r.mode[:4]} {r.step}/{r.steps}{'*' if r.arrived else ''}" for r in self.reports.values()]
        return f"t={t:6.1f}s  " + "  ".join(parts)

    def _finish(self, started: float, ok: bool, reason: str, plan: Plan | None = None) -> MissionResult:
        self.result = MissionResult(self.spec.mission, ok, reason, self.reports, float("inf"), ("", ""), 0,
                                    time.time() - started, plan, self.events)
        return self.result
