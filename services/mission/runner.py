"""`fleet mission run`: a mission of flying cars (paper 000) on the skeleton of `client.py`: plan
the tasks on a map, hand each vehicle its `VehiclePlan`, start them together, and end with a
summary (arrived, time, energy per vehicle, largest tracking error, smallest separation between
bodies in ground truth). Over when every vehicle arrived, at the plan's makespan plus `slack_s`, or
on a fault (`client.FAULT_EVENTS`), landing every vehicle.
"""

from __future__ import annotations

import asyncio
import time
import uuid
from dataclasses import dataclass, field

import msgspec
import zenoh

from common.bus.messages import PlanReply, PlanRequest, SimTruth, Telemetry, VehiclePlan, VehicleState
from common.bus.vehicle_plans import vehicle_plans
from common.domain.battery import charge_used_ah
from common.domain.planfile import Plan, Task
from common.domain.vehicle_model import VehicleModel
from services.mission.client import MissionClient, MissionTiming
from services.mission.separation import SeparationMonitor


@dataclass(frozen=True)
class MissionSpec:
    map: str
    tasks: dict[str, Task]
    planner: str = "sipp"
    mu: float = 0.5
    time_limit: float = 30.0
    mission: str = field(default_factory=lambda: f"m{uuid.uuid4().hex[:8]}")
    slack_s: float = 20.0
    timing: MissionTiming = MissionTiming()


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


ARRIVED = "every vehicle arrived"
CAPABILITIES_WAIT_S = 1.0
"""How long a mission waits for its vehicles' telemetry (their capabilities, 5 Hz) before planning."""

AIRBORNE_MODES = frozenset({"taking_off", "flying", "landing", "hovering", "emergency_landing"})


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


class MissionRunner(MissionClient[MissionResult]):
    """One mission of flying cars, as a short-lived service (`alive/mission/<id>`)."""

    def __init__(self, spec: MissionSpec, *args, progress: bool = True, **kwargs) -> None:
        super().__init__(spec.mission, spec.tasks, spec.timing, *args, progress=progress, **kwargs)
        self.spec = spec
        self.tasks = dict(spec.tasks)
        self.reports = {vid: VehicleReport(vid) for vid in spec.tasks}
        self.plan: Plan | None = None
        self.model = VehicleModel()
        """The battery model a vehicle's resting voltage is read with (the planner's map may say
        otherwise for the plan itself)."""
        self.voltage = 3.7
        self.sep: SeparationMonitor | None = None
        self._plans = None

    async def prepare(self) -> None:
        """Each vehicle is what its gateway says (`Telemetry`): its capabilities (from the radios
        file: a stock Crazyflie's task is planned on flight edges only, whatever the scenario
        assumed) and its battery (issue 16: the charge used, read from its resting voltage, and the
        voltage go into eq. 4-6 through `Task.charge_used_ah` and `Task.voltage`). Waits up to
        `CAPABILITIES_WAIT_S` for every vehicle's telemetry; a silent one keeps its task's."""
        seen: dict[str, Telemetry] = {}
        self.subscribe(self.keys.all_vehicles("telemetry"), Telemetry, lambda tel, _k: seen.__setitem__(tel.vid, tel))
        deadline = time.monotonic() + CAPABILITIES_WAIT_S
        while not set(self.tasks) <= set(seen) and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        for vid, task in self.tasks.items():
            tel = seen.get(vid)
            if tel is None:
                continue
            if tel.capabilities != task.capabilities:
                self.events.append(f"{vid}: planned as {tel.capabilities} (its gateway's word), not {task.capabilities}")
                task = msgspec.structs.replace(task, capabilities=tel.capabilities)
            if tel.vbat > 0.0 and not task.charge_used_ah and not task.voltage:
                task = msgspec.structs.replace(task, charge_used_ah=round(charge_used_ah(tel.vbat, self.model), 6),
                                               voltage=round(tel.vbat, 3))
            self.tasks[vid] = task

    def plan_request(self) -> PlanRequest:
        s = self.spec
        return PlanRequest(map=s.map, tasks=self.tasks, planner=s.planner, mu=s.mu, time_limit=s.time_limit,
                           mission=s.mission)

    def planner_wait_s(self) -> float:
        return self.spec.time_limit + self.timing.planner_timeout_s

    def accept(self, reply: PlanReply) -> str | None:
        if reply.plan is None:
            return "planning failed: the planner's reply carries no plan"
        self.plan = plan = reply.plan
        self.voltage = plan.model.voltage
        for vid, path in plan.paths.items():
            self.reports[vid].planned_s = path[-1].t
        self.sep = sep = SeparationMonitor(*plan.model.body())  # physical bodies, not the planning envelope
        self.subscribe(self.keys.all_sim_truth, SimTruth, lambda t, _k: sep.update(t))
        self._plans = self.publishers(lambda vid: self.keys.vehicle(vid, "plan"), VehiclePlan,
                                      congestion_control=zenoh.CongestionControl.BLOCK)
        return None

    def hand_out(self, t0: float) -> None:
        assert self.plan is not None and self._plans is not None
        self._plans.put_all(vehicle_plans(self.plan, self.mission, t0))

    def sample(self) -> None:
        if self.sep is not None:
            self.sep.sample()

    def end_reason(self, now: float) -> str | None:
        if all(r.arrived for r in self.reports.values()):
            return ARRIVED
        assert self.t0 is not None
        if now > self.t0 + max(r.planned_s for r in self.reports.values()) + self.spec.slack_s:
            return "time limit: not every vehicle arrived"
        return None

    def succeeded(self, reason: str) -> bool:
        return reason == ARRIVED  # landing at its goal after a fault is no success

    def conclude(self, ok: bool, reason: str) -> MissionResult:
        sep = self.sep
        contacts = len(sep.contacts) if sep is not None else 0
        if contacts:
            ok, reason = False, f"{reason}; bodies came into contact {contacts} times"
        self.result = MissionResult(self.mission, ok, reason, self.reports, float("inf"), ("", ""), contacts,
                                    self.elapsed(), self.plan, self.events)
        if sep is not None:
            self.result.min_gap, self.result.min_pair = sep.min_gap, sep.min_pair
        return self.result

    def on_state(self, state: VehicleState) -> None:
        r = self.reports[state.vid]
        r.mode, r.step, r.steps, r.owner = state.mode, state.step, state.steps, state.owner
        if state.mission != self.mission or self.t0 is None:
            return
        r.energy_j = state.charge_used_ah * 3600.0 * self.voltage  # eq. 4-5 backwards
        r.max_tracking_error = max(r.max_tracking_error, state.tracking_error)
        if state.mode in AIRBORNE_MODES or state.mode in ("driving",):
            where = "air" if state.mode in AIRBORNE_MODES else "ground"
            r.sq_error[where] += state.tracking_error**2
            r.samples[where] += 1
        if state.arrived and not r.arrived:
            r.arrived, r.arrival_s = True, state.t - self.t0

    def progress_line(self, now: float) -> str:
        t = now - (self.t0 or now)
        parts = [f"{r.vid}:{r.mode[:4]} {r.step}/{r.steps}{'*' if r.arrived else ''}" for r in self.reports.values()]
        return f"t={t:6.1f}s  " + "  ".join(parts)
