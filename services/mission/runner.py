"""`fleet mission run`: a mission of flying cars (paper 000) on the skeleton of `client.py`: plan
the tasks on a map, hand each vehicle its `VehiclePlan`, start them together, and end with a
summary (arrived, time, energy per vehicle, largest tracking error, smallest separation between
bodies in ground truth). Over when every vehicle arrived, or at the plan's makespan plus `slack_s`,
on the plan's clock (`common/flight/plan_clock.py`: it waits for the vehicles behind their plans;
its waits count up to the makespan again, no more: a fleet that keeps falling behind does not fly
for ever).

A fault of one vehicle (issue 16; `on_fault="replan"`, the default) does not end the mission: the
vehicle leaves it (its executor lands or stops it), and the planner plans the others on from
`REPLAN_LEAD_S` ahead around where it comes to rest (`Replan`); the executors switch to the new
paths without stopping; a vehicle whose goal the fault put out of reach (a road closed by a
vehicle that came down on it) stops at the nearest node it can reach (`Replan.strand`). The mission
then ends when every other vehicle arrived (not a success: a vehicle left or stopped short). A
vehicle on the ground that cannot be placed (it drives into the space a vehicle that left closed)
is stopped where it is, alone (`MissionAbort.vehicles`), and leaves too. A fault the others cannot be planned around (the planner finds no plan, or does
not answer in time), a fault that is not one vehicle's own (`stale_cmd_landing` whose commands
did not come back: `stale_commands.py`; an executor's `aborted` after losing its router; a crash,
a controller that failed) or `on_fault="abort"` ends it, landing every vehicle (`client.FAULT_EVENTS`).
"""

from __future__ import annotations

import asyncio
import math
import random
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import msgspec
import zenoh

from common.bus.messages import (
    MissionAbort,
    PlanReply,
    PlanRequest,
    PoseFrame,
    Replan,
    SimTruthFrame,
    Sweep,
    TaskAdd,
    TaskAddReply,
    Telemetry,
    VehiclePlan,
    VehicleState,
)
from common.bus.pubsub import Publisher, QueryError, QueryTimeout, query
from common.bus.vehicle_plans import vehicle_plans
from common.domain.battery import charge_used_ah
from common.domain.planfile import PathEntry, Plan, Task
from common.domain.vehicle_model import VehicleModel
from services.mission.client import MissionClient, MissionTiming
from services.mission.rejoin import REJOINS, Candidate, progress_at, shifted_path
from services.mission.separation import SeparationMonitor
from services.mission.sweeps import Point, left_vehicle


def ground_height(plan: Plan) -> float:
    """The lowest ground node's height: where a column below a held vehicle ends (`sweeps.py`)."""
    return min(n.pos[2] for n in plan.graph.nodes.values() if n.kind != "air")


def plan_end(plan: Plan) -> float:
    """When the plan's last vehicle arrives (mission time): from then on a held vehicle's column is
    closed too (`sweeps.held`); 0 for a plan of no vehicle (every one left: the column at once)."""
    return max((path[-1].t for path in plan.paths.values() if path), default=0.0)


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
    on_fault: Literal["replan", "abort"] = "replan"
    lifelong_s: float = 0.0
    """Lifelong operation (issue 16): for this long, every vehicle that arrives gets a random new goal
    (a free parking spot), planned against the others' paths; then the last tasks are flown out."""
    seed: int = 0
    replanner: Literal["sipp", "ilp"] = "sipp"
    """Who plans the mission on after a fault or a new task: SIPP (fast), or the ILP where its time
    limit allows (a mission the ILP planned; SIPP takes over when it finds no plan in time)."""
    rejoins: int = REJOINS
    """How often a held vehicle (`rejoinable`) may be brought back into the plan (`rejoin.py`;
    0: never, it stays held as any held vehicle)."""
    hover: bool = False
    """A task may end at an air node (issue 19: single-vehicle take-off, go to, land): the vehicle
    hovers there until given another goal (`add_task`), and the mission has no time limit while a
    vehicle's goal is in the air; it ends when every vehicle has arrived on the ground (or on abort)."""


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
REPLAN_KINDS = frozenset({"low_battery", "link_lost", "emergency_landing", "tracking_hold"})
"""Faults of one vehicle that the others are planned around (it lands, stops or hovers on its own).
Not these: `stale_cmd_landing` whose commands did not come back (its gateway hears no executor:
the bus, not the vehicle, failed; one that came back is no fault: `stale_commands.py`),
`aborted` (an executor that lost its router aborted its vehicles' plans), a crash, a failed controller."""
LEFT_CLEARANCE = 0.5
"""m: a lifelong goal is no parking spot this close to where a vehicle that left rests."""
BYSTANDER_CLEARANCE = 0.5
"""m: a lifelong goal is no parking spot this close to where a vehicle of the fleet outside the
mission stands (its motion-capture pose; issue 19: a lifelong mission of a few of the fleet's vehicles)."""
ARRIVAL_SLACK_S = 0.5
"""s: an executor's `arrived` counts from this long before its current plan's end on (an arrival at
a goal before a new goal's plan reached the executor is the old one's)."""
REPLAN_LEAD_S = 1.0
"""s: the switch time of a replan is this far ahead of the fault (planning + handing the plans out)."""
BYSTANDERS_EVERY_S = 0.1
"""s: the motion capture's frames are read for the bystanders at most this often."""
GONE_KINDS = frozenset({"emergency_landing", "low_battery", "crash"})
"""Faults after which a vehicle that left does not come back (nor after a fault landing to a node)."""
GROUND_MODES = frozenset({"driving", "parked", "holding"})
"""Modes of a vehicle on the ground that can stop where it is."""
AIR_MODES = frozenset({"taking_off", "flying", "landing"})
"""Modes of a vehicle in the air, on its plan, that can hold where it is (hovering)."""
REPLAN_TIME_LIMITS_S = (0.6, 1.2)
"""s: the planner's time limit for a replan (SIPP, paper 000 §V-D), try by try: a replan is asked
for again when the planner's answer does not come before its switch time, or says its time limit
ran out with more to try (`PlanReply.timed_out`; an 80-vehicle soak's mission aborted so, on a
machine whose planner got a share of a core); each try gives the planner one `REPLAN_LEAD_S` more
(a loaded machine's planner is slow for a while). The executors' reflex to a held vehicle looks as
far ahead as the tries reach (`FaultParams.yield_s`)."""
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
    """The plan the mission started with."""
    events: list[str] = field(default_factory=list)
    final_plan: Plan | None = None
    """The plan of the vehicles that stayed, after the last replan (None: never replanned)."""
    replans: list[float] = field(default_factory=list)
    """Planning time of each replan (s)."""
    tasks_done: int = 0
    """Arrivals at a goal (the first tasks and every added one)."""
    tasks_added: int = 0
    replans_skipped: int = 0
    """Fault replans left out because a later one, queued behind them, planned around their vehicles too."""
    delay_s: float = 0.0
    """How long the plan's clock waited for vehicles that lagged their references (`common/flight/plan_clock.py`)."""

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
        if self.delay_s > 0.0:
            lines.append(f"the plan's clock waited {self.delay_s:.2f} s for vehicles behind their plans")
        if self.replans or self.tasks_added:
            ms = sorted(1e3 * t for t in self.replans)
            lines.append(f"tasks: {self.tasks_done} done ({self.tasks_added} added while flying) in "
                         f"{self.duration_s / 60:.1f} min: {self.tasks_done / max(self.duration_s / 60, 1e-9):.1f} per minute; "
                         f"replans: {len(ms)}, median {ms[len(ms) // 2] if ms else 0:.0f} ms, max {ms[-1] if ms else 0:.0f} ms"
                         + (f" ({self.replans_skipped} more left to a later one)" if self.replans_skipped else ""))
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
        self.first_plan: Plan | None = None
        """The plan the mission started with."""
        self.voltage = 3.7
        self.sep: SeparationMonitor | None = None
        self._plans = None
        self._handed: tuple[Plan, float, dict[str, VehiclePlan]] | None = None
        """The plan, start time and vehicles' plans last handed out."""
        self.left: dict[str, str] = {}
        """Vehicles that left the mission on a fault -> why."""
        self.sweeps: list[Sweep] = []
        """Where the vehicles that left go and rest (mission time), for every replan."""
        self.replans: list[float] = []
        """Planning time of each replan (s)."""
        self._replanning: asyncio.Task | None = None
        self._fault_replans = 0
        """Replans asked for by faults so far (`_replan`: only the last one queued plans)."""
        self.replans_skipped = 0
        """Fault replans that a later one queued behind them made unnecessary."""
        self._blocked: list[str] = []
        """The vehicles the last replan could not place (`PlanReply.failed_vehicle`, `unplaceable`)."""
        self._refused: dict[str, str] = {}
        """The held vehicles the last replan could not bring back yet, and why (`PlanReply.refused`)."""
        self._abort_pub: Publisher | None = None
        self.stranded: dict[str, str] = {}
        """Vehicles a replan gave a goal short of theirs (`Replan.strand`) -> which goal it was."""
        self.tasks_done = 0
        """Tasks finished: arrivals at a goal, the first ones and every added one."""
        self.tasks_added = 0
        self._pending: set[str] = set()
        """Vehicles with a new goal being planned."""
        self._rejoin: dict[str, Candidate] = {}
        """Held vehicles that may come back (`rejoin.py`)."""
        self._rejoined: dict[str, int] = {}
        """How often each vehicle came back."""
        self._back: frozenset[str] = frozenset()
        """The held vehicles the current plan brings back (`VehiclePlan.rejoin`)."""
        self._all_in: float | None = None
        """Since when every vehicle in the mission has arrived (those that left waiting to come back)."""
        self._left_with: dict[str, tuple[list[PathEntry], Task]] = {}
        """The path and task each vehicle that left had (the last time it left)."""
        self._rng = random.Random(spec.seed)
        self._lifelong_task: asyncio.Task | None = None
        self.bystanders: dict[str, tuple[float, float, float]] = {}
        """Where the fleet's vehicles outside the mission stand (lifelong missions: not a free spot;
        a held vehicle does not rejoin through one: `rejoin.py`)."""
        self._frame_t = 0.0
        self.delay = 0.0
        """How far the plan's clock stands behind the wall clock (s): the largest its vehicles'
        states tell (`VehicleState.delay`)."""

    def plan_time(self) -> float:
        """The plan's time now (s since the start on the plan's clock)."""
        assert self.t0 is not None
        return time.time() - self.t0 - self.delay

    async def prepare(self) -> str | None:
        """Each vehicle is what its gateway says (`Telemetry`): its capabilities (from the radios
        file: a stock Crazyflie's task is planned on flight edges only, whatever the scenario
        assumed) and its battery (issue 16: the charge used, read from its resting voltage, and the
        voltage go into eq. 4-6 through `Task.charge_used_ah` and `Task.voltage`). Waits up to
        `CAPABILITIES_WAIT_S` for every vehicle's telemetry (a silent one keeps its task's), then up
        to `MissionTiming.link_wait_s` for the link of each vehicle heard of to be up: before it is,
        its gateway knows neither its battery nor its state, and the mission is refused."""
        seen: dict[str, Telemetry] = {}
        self.subscribe(self.keys.all_vehicles("telemetry"), Telemetry, lambda tel, _k: seen.__setitem__(tel.vid, tel))
        if self.spec.lifelong_s > 0 or self.spec.on_fault == "replan":
            self.subscribe(self.keys.mocap_frame, PoseFrame, self._on_frame)
        start = time.monotonic()
        while not set(self.tasks) <= set(seen) and time.monotonic() < start + CAPABILITIES_WAIT_S:
            await asyncio.sleep(0.05)

        def linkless() -> list[str]:
            return sorted(v for v in self.tasks if v in seen and not seen[v].link_ok)

        if linkless() and self.print_progress:
            print(f"waiting up to {self.timing.link_wait_s:.0f} s for the radio links of {', '.join(linkless())}",
                  flush=True)
        while linkless() and time.monotonic() < start + self.timing.link_wait_s:
            await asyncio.sleep(0.1)
        if down := linkless():
            return "no radio link to " + ", ".join(f"{v} (gateway {seen[v].gateway})" for v in down) + \
                f" after {self.timing.link_wait_s:.0f} s: vehicle switched off, out of range or still connecting"
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
        return None

    def _on_frame(self, frame: PoseFrame, _key: str) -> None:
        if frame.t < self._frame_t + BYSTANDERS_EVERY_S:
            return
        self._frame_t = frame.t
        for p in frame.poses:
            if p.vid not in self.tasks:
                self.bystanders[p.vid] = (p.x, p.y, p.z)

    def plan_request(self) -> PlanRequest:
        s = self.spec
        return PlanRequest(map=s.map, tasks=self.tasks, planner=s.planner, mu=s.mu, time_limit=s.time_limit,
                           mission=s.mission)

    def planner_wait_s(self) -> float:
        return self.spec.time_limit + self.timing.planner_timeout_s

    def accept(self, reply: PlanReply) -> str | None:
        if reply.plan is None:
            return "planning failed: the planner's reply carries no plan"
        aloft = sorted(v for v, t in reply.plan.tasks.items() if self._in_air(reply.plan, t.goal))
        if aloft and not self.spec.hover:
            return f"{', '.join(aloft)}: a goal in the air needs a hover mission (--hover)"
        self.plan = self.first_plan = plan = reply.plan
        self.voltage = plan.model.voltage
        for vid, path in plan.paths.items():
            self.reports[vid].planned_s = path[-1].t
        self.sep = sep = SeparationMonitor(*plan.model.body())  # physical bodies, not the planning envelope
        self.subscribe(self.keys.sim_truths, SimTruthFrame, lambda f, _k: sep.update_frame(f))
        self._plans = self.publishers(lambda vid: self.keys.vehicle(vid, "plan"), VehiclePlan,
                                      congestion_control=zenoh.CongestionControl.BLOCK)
        self._abort_pub = self.publisher(self.keys.mission(self.mission, "abort"), MissionAbort)
        self.serve(self.keys.mission(self.mission, "add"), TaskAdd, TaskAddReply, self.add_task)
        return None

    def hand_out(self, t0: float) -> None:
        """Every vehicle's plan (again every `RESEND_S`: made once per plan and start time, a
        32-vehicle city934 mission spent a tenth of its process's time remaking them)."""
        assert self.plan is not None and self._plans is not None
        if self._handed is None or self._handed[0] is not self.plan or self._handed[1] != t0:
            self._handed = (self.plan, t0, vehicle_plans(self.plan, self.mission, t0, self._back))
        self._plans.put_all(self._handed[2])

    def sample(self) -> None:
        if self.spec.lifelong_s > 0 and self._lifelong_task is None and self.t0 is not None:
            self._lifelong_task = asyncio.get_running_loop().create_task(self._lifelong())
        now = time.time()
        due = sorted(v for v, c in self._rejoin.items() if c.due(self.states.get(v), now))
        if due and not self.fault and (self._replanning is None or self._replanning.done()):
            for vid in due:
                self._rejoin[vid].tries += 1
                self._rejoin[vid].last_try = now
            self._replanning = asyncio.get_running_loop().create_task(self._bring_back(due))

    async def _bring_back(self, vids: list[str]) -> None:
        """Bring the held vehicles `vids` back into the plan (`rejoin.py`); those the planner names
        as not able to yet (`PlanReply.refused`, or the one it could not place) are left out and
        the others are tried again, unless another fault's replan is waiting (it goes first) or the
        planner named none (its time ran out: the next try)."""
        faults = self._fault_replans
        while (vids := [v for v in vids if v in self._rejoin]) and self.plan is not None and self.t0 is not None:
            answer = await self._ask_replan(self.plan, [], {}, rejoin=vids)
            if self._fault_replans != faults:
                return
            if any(v not in self._rejoin for v in vids):
                continue  # one left for good meanwhile (an emergency landing): the others again
            if isinstance(answer, str):
                blocked, self._blocked = self._blocked, []
                refused, self._refused = self._refused or dict.fromkeys(blocked, answer), {}
                out = [v for v in vids if v in refused]
                for v in out or vids:
                    if self._rejoin[v].tries == 1:
                        self.events.append(f"{v} not back yet: {refused.get(v, answer)}")
                if not out:
                    return
                vids = [v for v in vids if v not in out]
                continue
            reply, at, took = answer
            if (error := self._apply_replan(reply, at, took, [], {}, back=vids)) is not None:
                self.events.append(f"{', '.join(vids)} could not rejoin: {error}")
                return
            for vid in vids:
                self._rejoined[vid] = self._rejoined.get(vid, 0) + 1
                self.left.pop(vid, None)
                self.reports[vid].arrived = False
                held_s = time.time() - self._rejoin.pop(vid).since
                self.events.append(f"{vid} rejoined the mission after {held_s:.1f} s held (switch at {at:.1f} s)")
            self.sweeps = [s for s in self.sweeps if s.vid not in vids]
            return

    def on_fault(self, vid: str, kind: str, text: str, node: str, rejoinable: bool = False,
                 acted: bool = False, at: Point | None = None) -> bool:
        if kind == "link_lost" and not acted:
            return True  # the gateway's word (`LinkHealth`): the executor reports what it does (a hold, a landing)
        if vid in self.left:
            if rejoinable and kind == "tracking_hold":
                self._may_rejoin(vid)
            elif node or kind in GONE_KINDS:
                self._rejoin.pop(vid, None)
            if text not in self.left[vid]:
                self.left[vid] += f"; {text}"
            if node and kind in REPLAN_KINDS and self.t0 is not None:  # it now lands there: plan around that too
                self.sweeps += self._sweeps(vid, node, kind, at)
                where = f" ({at[0]:.2f}, {at[1]:.2f})" if at is not None else ""
                self.events.append(f"{vid} ({kind}) lands at {node}{where}: replanning the others")
                self._queue_replan()
            return True
        if (self.spec.on_fault != "replan" or kind not in REPLAN_KINDS or self.plan is None or self.t0 is None
                or self.first_plan is None or vid not in self.first_plan.paths or self.states.get(vid) is None):
            return False
        self.left[vid] = text
        if vid in self.plan.paths:
            self._left_with[vid] = (self.plan.paths[vid], self.plan.tasks[vid])
        if rejoinable and kind == "tracking_hold":
            self._may_rejoin(vid)
        self.sweeps += self._sweeps(vid, node, kind, at)
        self.events.append(f"{vid} left the mission ({kind}): replanning the others")
        self._queue_replan()
        return True

    def _may_rejoin(self, vid: str) -> None:
        """`vid` was held for another's sake or left behind by a fault that may clear: the mission
        may bring it back (`rejoin.py`), unless it came back `spec.rejoins` times already."""
        if vid in self._left_with and vid not in self._rejoin and self._rejoined.get(vid, 0) < self.spec.rejoins:
            self._rejoin[vid] = Candidate(*self._left_with[vid], time.time())

    def _queue_replan(self) -> None:
        """Replan the others around the vehicles that left, after the replans already queued."""
        self._fault_replans += 1
        self._replanning = asyncio.get_running_loop().create_task(self._replan(self._replanning, self._fault_replans))

    def _sweeps(self, vid: str, node: str, kind: str, at: Point | None) -> list[Sweep]:
        """Where `vid` may be from its latest state on (`sweeps.left_vehicle`); where its fault
        landing goes, if its event said: `at` (`VehicleEvent.at`; the only word of a spot that is no
        node of the graph), else `node`'s position."""
        assert self.plan is not None and self.t0 is not None
        state = self.states[vid]
        nodes = self.plan.graph.nodes
        ground = ground_height(self.plan)
        return left_vehicle(vid, kind, (state.x, state.y, state.z), self.plan_time(), ground,
                            at if at is not None else nodes[node].pos if node in nodes else None, plan_end(self.plan))

    async def _replan(self, previous: asyncio.Task | None, ticket: int) -> None:
        """After `previous`, plan the remaining vehicles on around those that left and hand the new
        plans out, unless a later fault's replan (`ticket` is this one's number) is queued: that one
        plans around every vehicle that left by its start, this one's included. (Faults come in
        bursts: in a 32-vehicle soak, 18 holds in a few seconds queued 18 replans of half a second
        each, one after another, the last handed out ten seconds late, while the planner took 30-47 %
        of a core from the control loops.) A vehicle the planner could not place (it drives or flies
        into the space a vehicle that left closed) is stopped where it is, alone (on the ground for
        good, in the air held hovering), and leaves too, with every other the planner named as
        placed by no order (`PlanReply.unplaceable`), and the others are planned again, as long as
        each failed replan names a vehicle still to stop (a jam behind a car stopped on a road
        stops car after car: an 80-vehicle soak's mission ended on the fourth in a row when three
        were the most); any other failure is the mission's fault (it ends, landing everyone),
        unless a later fault's replan was queued meanwhile: that one plans around more (the
        vehicle this one could not place has often left by then: held in the same burst)."""
        if previous is not None:
            await asyncio.gather(previous, return_exceptions=True)
        if ticket < self._fault_replans:
            self.replans_skipped += 1
            return
        error = await self._plan_on(None)
        while error and self._stop_blocked(error):  # (each time one more left: at most once a vehicle)
            error = await self._plan_on(None)
        if error and ticket < self._fault_replans:
            self.events.append(f"replanning failed ({error}); the replan of a later fault tries again")
        elif error:
            self.fault = self.fault or f"{', '.join(self.left)} left the mission; {error}"

    def _stop_blocked(self, error: str) -> bool:
        """Stop the vehicles the last replan could not place where they are (module doc of
        `_replan`): every one it named at once (`PlanReply.unplaceable`); whether it stopped any."""
        blocked, self._blocked = self._blocked, []
        stopped = [vid for vid in blocked if self._stop_where_it_is(vid, error)]  # (each one, not any())
        return bool(stopped)

    def _stop_where_it_is(self, vid: str, error: str) -> bool:
        """Stop `vid`, which a replan could not place, where it is: on the ground for good; in the
        air held hovering, for the mission's sake (`MissionAbort.hold`): it may come back
        (`rejoin.py`). Whether it did. (An 80-vehicle soak's replan could not place a vehicle
        flying into the column of one held hovering, its next node 27 cm from it, and the mission
        ended for all 80.)"""
        state = self.states.get(vid)
        if (not vid or state is None or state.mode not in GROUND_MODES | AIR_MODES or self.plan is None
                or self.t0 is None or vid not in self.plan.paths or vid in self.left or self._abort_pub is None):
            return False
        aloft = state.mode in AIR_MODES
        reason = f"{vid}: {'held' if aloft else 'stopped'} where it is, no plan around the vehicles that left ({error})"
        self._abort_pub.put(MissionAbort(mission=self.mission, reason=reason, vehicles=[vid], hold=aloft))
        self.left[vid] = reason
        if aloft:
            self._left_with[vid] = (self.plan.paths[vid], self.plan.tasks[vid])
        ground = ground_height(self.plan)
        self.sweeps += left_vehicle(vid, "tracking_hold", (state.x, state.y, state.z), self.plan_time(),
                                    ground, None, plan_end(self.plan))
        self.events.append(reason)
        return True

    async def _plan_on(self, previous: asyncio.Task | None, goals: dict[str, str] | None = None) -> str | None:
        """After `previous` (replans run one at a time): plan the running mission on from
        `REPLAN_LEAD_S` ahead (`Replan`: around the vehicles that left, with new `goals`) and hand
        the new plans out; why it could not, or None."""
        if previous is not None:
            await asyncio.gather(previous, return_exceptions=True)
        if self.plan is None or self.t0 is None:
            return "the mission has not started"
        left = [v for v in self.left if v in self.plan.paths]  # those that left since the last replan
        answer = await self._ask_replan(self.plan, left, goals or {})
        if isinstance(answer, str):
            return answer
        return self._apply_replan(*answer, left, goals or {})

    async def _ask_replan(self, plan: Plan, left: list[str], goals: dict[str, str],
                          rejoin: Sequence[str] = ()) -> tuple[PlanReply, float, float] | str:
        """The planner's replan of `plan` (its reply, the switch time and how long it took), asked
        again from later when it does not come before its switch time or its time limit ran out
        (`REPLAN_TIME_LIMITS_S`); or why there is none. The held vehicles `rejoin` come back
        (`rejoin.py`)."""
        late = ""
        for k, limit in enumerate(REPLAN_TIME_LIMITS_S):  # a planner too slow this time is asked again, from later
            lead = REPLAN_LEAD_S * (k + 1)
            at = self.plan_time() + lead
            base, sweeps = self._with_rejoining(plan, rejoin, at)
            req = PlanRequest(map=self.spec.map, tasks={}, planner="sipp" if rejoin else self.spec.replanner,
                              mu=self.spec.mu, time_limit=limit, reply_within=lead,
                              replan=Replan(base=base, at=at, left=left, sweeps=sweeps,
                                            goals={**self._stranded_goals(left), **goals}, strand=True,
                                            rejoin=list(rejoin)))
            started = time.perf_counter()
            try:
                reply = await query(self.session, self.keys.planner_plan, req, PlanReply, timeout=lead)
            except QueryTimeout as exc:
                late = f"the planner did not replan: {exc}"
                continue
            except QueryError as exc:
                return f"the planner did not replan: {exc}"
            except RuntimeError:  # the mission ended (its session closed) while this replan waited
                return "the mission ended"
            took = time.perf_counter() - started
            if not reply.ok and reply.timed_out and k + 1 < len(REPLAN_TIME_LIMITS_S):
                late = f"the planner ran out of its {limit:.1f} s ({reply.error})"
                self.events.append(f"replan: {late}; asked again with more time")
                continue
            if not reply.ok or reply.plan is None:
                return self._replan_failed(reply)
            if self.plan_time() <= at:
                return reply, at, took
            late = f"the replan came too late ({took:.2f} s)"
        return f"{late} ({len(REPLAN_TIME_LIMITS_S)} times)"

    def _stranded_goals(self, left: Sequence[str]) -> dict[str, str]:
        """The goals a replan had left out of reach (`stranded`), asked for again by every replan
        after it, of the vehicles still in the mission: what closed one (a vehicle held on the way,
        which came back since, a body that left) may be gone. (An 80-vehicle soak's replan around
        two held vehicles left cf26 short of its spot; both came back 2-4 s later, every vehicle
        arrived, and the mission failed for cf26's goal.) Given up again, it stays stranded."""
        return {v: g for v, g in self.stranded.items() if v not in left and v not in self.left}

    def _replan_failed(self, reply: PlanReply) -> str:
        """Note whom a failed replan names (the vehicles it could not place, those it could not bring
        back yet); why it failed."""
        self._blocked = [v for v in dict.fromkeys((reply.failed_vehicle, *reply.unplaceable)) if v]
        self._refused = dict(reply.refused)
        return f"replanning failed: {reply.error}"

    def _with_rejoining(self, plan: Plan, rejoin: Sequence[str], at: float) -> tuple[Plan, list[Sweep]]:
        """`plan` with the held vehicles `rejoin` back in it (their paths shifted so that each is
        where it stands at `at`: `rejoin.shifted_path`), and the sweeps of the others and of the
        bystanders where they stand (the body it stopped for may be one)."""
        if not rejoin:
            return plan, self.sweeps
        assert self.t0 is not None
        paths, tasks = dict(plan.paths), dict(plan.tasks)
        for vid in rejoin:
            c, s = self._rejoin[vid], self.states[vid]
            progress = progress_at(plan, c.path, (s.x, s.y, s.z), self.plan_time() + 1.0)
            paths[vid], tasks[vid] = shifted_path(c.path, progress, at), c.task
        ground = ground_height(plan)
        t = self.plan_time()
        end = plan_end(plan)
        standing = [w for vid, p in self.bystanders.items()
                    for w in left_vehicle(vid, "tracking_hold", p, t, ground, None, end)]
        return (msgspec.structs.replace(plan, paths=paths, tasks=tasks),
                [s for s in self.sweeps if s.vid not in rejoin] + standing)

    def _apply_replan(self, reply: PlanReply, at: float, took: float, left: list[str],
                      goals: dict[str, str], back: Sequence[str] = ()) -> str | None:
        """Take the planner's replan (`_ask_replan`): the vehicles it strands, the new goals, the
        plans handed out (`back`: the held vehicles it brings back); why not, if it left a new goal
        out of reach."""
        assert self.plan is not None and self.t0 is not None and reply.plan is not None
        before = {v: t.goal for v, t in self.plan.tasks.items()}
        wanted = {v: goals.get(v, self.stranded.get(v, g)) for v, g in before.items()}
        short = {v: t.goal for v, t in reply.plan.tasks.items() if t.goal != wanted.get(v, t.goal)}
        if refused := sorted(set(short) & set(goals)):
            return f"{', '.join(f'{wanted[v]!r}' for v in refused)} out of reach"
        self.replans.append(took)
        self.plan, self._back = reply.plan, frozenset(back)
        for vid in [v for v in self.stranded if v in reply.plan.tasks and v not in short and v not in goals]:
            self.reports[vid].arrived = False
            self.events.append(f"{vid}: {self.stranded.pop(vid)!r} in reach again: it goes on to it")
        for vid, node in short.items():
            self.stranded.setdefault(vid, wanted[vid])
            self.reports[vid].arrived = False
            if node != before.get(vid):
                self.events.append(f"{vid}: {wanted[vid]!r} out of reach now: it stops at {node!r}")
        for vid, path in self.plan.paths.items():
            self.reports[vid].planned_s = path[-1].t
        for vid in goals:
            self.reports[vid].arrived = False
            self.stranded.pop(vid, None)
        self.hand_out(self.t0)
        why = (f"around {', '.join(self.left)}" if left else f"for {', '.join(goals)}" if goals
               else f"with {', '.join(back)} back" if back else "again")
        self.events.append(f"replanned {len(self.plan.paths)} vehicles {why} in {took:.2f} s (switch at {at:.1f} s, "
                           f"{reply.planner})")
        return None

    async def add_task(self, req: TaskAdd) -> TaskAddReply:
        """`mission/<id>/add`: a new goal for one of the mission's vehicles, planned against the
        others' paths (it continues from its goal, or from its path if it is still on its way)."""
        plan = self.plan
        if plan is None or self.t0 is None:
            return TaskAddReply(ok=False, error=f"mission {self.mission} has not started")
        if req.vid not in plan.paths:
            why = f"left the mission ({self.left[req.vid]})" if req.vid in self.left else "is not in the mission"
            return TaskAddReply(ok=False, error=f"{req.vid} {why}")
        if req.goal not in plan.graph.nodes:
            return TaskAddReply(ok=False, error=f"no node {req.goal!r} on map {self.spec.map!r}")
        if self._in_air(plan, req.goal) and not self.spec.hover:
            return TaskAddReply(ok=False, error=f"{req.goal} is an air node: only a hover mission (--hover) ends a task there")
        taken = {t.goal: v for v, t in plan.tasks.items() if v != req.vid}
        taken |= {g: v for v, g in self.stranded.items() if v != req.vid}  # (asked for again by every replan)
        if req.goal in taken:
            return TaskAddReply(ok=False, error=f"{req.goal} is the goal of {taken[req.goal]}")
        if req.vid in self._pending:
            return TaskAddReply(ok=False, error=f"{req.vid}: a new goal is being planned already")
        self._pending.add(req.vid)
        try:
            previous = self._replanning
            task = self._replanning = asyncio.get_running_loop().create_task(
                self._plan_on(previous, {req.vid: req.goal}))
            error = await task
        finally:
            self._pending.discard(req.vid)
        if error:
            return TaskAddReply(ok=False, error=f"{req.vid} -> {req.goal}: {error}")
        self.tasks_added += 1
        return TaskAddReply(ok=True, arrival_s=self.reports[req.vid].planned_s)

    async def _lifelong(self) -> None:
        """Give every vehicle that arrived a random free parking spot as its next goal, for
        `spec.lifelong_s` (issue 16: lifelong operation)."""
        assert self.t0 is not None
        while time.time() - self.t0 < self.spec.lifelong_s:
            await asyncio.sleep(0.5)
            plan = self.plan
            if plan is None or self.fault:
                return
            for vid, r in self.reports.items():
                if r.arrived and vid in plan.paths and vid not in self._pending:
                    goals = {t.goal for t in plan.tasks.values()}
                    down = [(s.x, s.y) for v, s in self.states.items() if v in self.left]  # where they rest
                    free = sorted(n for n, node in plan.graph.nodes.items()
                                  if node.kind == "parking" and n not in goals
                                  and all(math.dist(node.pos[:2], p) > LEFT_CLEARANCE for p in down))
                    free = [n for n in free if self._clear_of_bystanders(plan, n)]
                    if free:
                        reply = await self.add_task(TaskAdd(vid=vid, goal=self._rng.choice(free)))
                        if not reply.ok:
                            self.events.append(f"lifelong: {reply.error}")
                        break  # one at a time: the plan changed

    def _clear_of_bystanders(self, plan: Plan, node: str) -> bool:
        return all(math.dist(plan.graph.nodes[node].pos[:2], p[:2]) > BYSTANDER_CLEARANCE
                   for p in self.bystanders.values())

    @staticmethod
    def _in_air(plan: Plan, node: str) -> bool:
        return node in plan.graph.nodes and plan.graph.nodes[node].kind == "air"

    def end_reason(self, now: float) -> str | None:
        if self.t0 is not None and now - self.t0 < self.spec.lifelong_s:
            return None
        if self._pending:
            return None
        others_in = all(r.arrived for v, r in self.reports.items() if v not in self.left)
        self._all_in = (self._all_in or now) if others_in else None
        if (self.left or self.stranded) and others_in:
            if any(c.pending(now, self._all_in) for c in self._rejoin.values()):
                return None  # (bounded: `Candidate.pending`)
            short = "".join(f"; {v} stopped short of {g!r}" for v, g in self.stranded.items())
            return f"every other vehicle arrived; left: {'; '.join(self.left.values()) or 'none'}{short}"
        if all(r.arrived for r in self.reports.values()):
            return ARRIVED
        plan = self.plan
        if plan is not None and any(self._in_air(plan, t.goal) for v, t in plan.tasks.items() if v not in self.left):
            return None  # a hover mission: open until told where to land
        assert self.t0 is not None
        latest = max(r.planned_s for v, r in self.reports.items() if v not in self.left)
        if now > self.t0 + min(self.delay, latest) + latest + self.spec.slack_s:  # (waits: at most the plan's length)
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
                                    self.elapsed(), self.first_plan, self.events,
                                    self.plan if self.replans else None, list(self.replans),
                                    self.tasks_done, self.tasks_added, self.replans_skipped, self.delay)
        if sep is not None:
            self.result.min_gap, self.result.min_pair = sep.min_gap, sep.min_pair
        return self.result

    def on_state(self, state: VehicleState) -> None:
        r = self.reports[state.vid]
        r.mode, r.step, r.steps, r.owner = state.mode, state.step, state.steps, state.owner
        if state.mission != self.mission or self.t0 is None:
            return
        self.delay = max(self.delay, state.delay)
        r.energy_j = state.charge_used_ah * 3600.0 * self.voltage  # eq. 4-5 backwards
        r.max_tracking_error = max(r.max_tracking_error, state.tracking_error)
        if state.mode in AIRBORNE_MODES or state.mode in ("driving",):
            where = "air" if state.mode in AIRBORNE_MODES else "ground"
            r.sq_error[where] += state.tracking_error**2
            r.samples[where] += 1
        if state.arrived and not r.arrived and state.t - state.delay >= self.t0 + r.planned_s - ARRIVAL_SLACK_S:
            r.arrived, r.arrival_s = True, state.t - self.t0
            self.tasks_done += state.vid not in self.stranded

    def progress_line(self, now: float) -> str:
        t = now - (self.t0 or now)
        parts = [f"{r.vid}:{r.mode[:4]} {r.step}/{r.steps}{'*' if r.arrived else ''}" for r in self.reports.values()]
        return f"t={t:6.1f}s  " + "  ".join(parts)
