"""The executor service (paper 000 §VI-C, Fig. 4: trajectory generator, state machine, driving and
flying controllers): one asyncio process running one control loop over the vehicles it owns.

Ownership is rendezvous hashing over the live executors, seen through liveliness tokens
(`takeover.py`): every executor computes the same assignment, so when one dies its vehicles pass
to the others as soon as its token disappears (under 1 s), and the gateways obey the new owner. A
vehicle taken over mid-mission resumes from the last state its previous owner published.

Inputs: `vehicle/*/plan`, `mocap/frame` (every vehicle's pose of one motion-capture frame),
`vehicle/*/telemetry`, `vehicle/*/state` (for take-over), `mission/*/start`, `mission/*/abort`,
`mission/*/delay` (the other executors' plan clocks).

The control cycle is triggered by a frame's arrival (DESIGN.md, "Hot path"): it fuses the frame's
poses of the owned vehicles, holds each owned vehicle that heads into another body the frames show
(the proximity stop, `proximity.py`), ticks every controller and sends the commands as one `CmdBatch` per
gateway (`gateway/<instance>/cmd`; a vehicle's gateway is the one its telemetry comes from,
`vehicle/<vid>/cmd` until that is known). Each mission's plan runs on a clock that waits for the
vehicles that lag their references (`common/flight/plan_clock.py`): before the ticks, every running
mission's clock moves on at the pace its vehicles here allow, and one that waits is told to the
other executors (`mission/<id>/delay`). Without frames (motion capture lost) a cycle runs every
`FRAME_WAIT` periods anyway, so that stale poses are noticed and fault landings are flown. Outputs
for owned vehicles besides the commands: `vehicle/<vid>/state` at the state rate,
`vehicle/<vid>/event` on faults (team plans of ground-air teams, paper 002:
`services/executor/team_robots.py`); `stats/executor/<instance>`: counters, late cycles (a command
sent more than a period after its frame's capture), pose-to-command latency, cycle cost, the poses
its estimators rejected as outliers and their restarts (of the vehicles it owns now).

Losing the router (docs/bus.md) makes every remote token vanish at once: that is not the death of
the other executors, so ownership stands still until the router is back and the others have had
time to reconnect (`ROUTER_SETTLE_S`). Meanwhile no command reaches a vehicle, so the gateways land
the flying ones and stop the others (stale commands): the executor aborts the missions of the
vehicles it owns rather than resume a plan whose timing is gone when the router returns.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from common.bus.args import keys_from_args, run_service, zconfig_from_args
from common.bus.liveliness import AliveSet
from common.bus.messages import (
    Cmd,
    CmdBatch,
    FramePose,
    MissionAbort,
    MissionStart,
    PlanDelay,
    PlanStep,
    Pose,
    PoseFrame,
    Telemetry,
    VehicleEvent,
    VehiclePlan,
    VehicleState,
    VehicleStates,
)
from common.bus.pubsub import Subscription
from common.bus.service import Service
from common.bus.stats import percentile_figures, publish_stats
from common.domain.mapfile import MapSpec, load_map
from common.errors import InputError
from common.flight.estimator import EstimatorParams, KalmanBank, PoseEstimator, fuse_poses
from common.flight.modes import Mode
from common.flight.plan_clock import ClockParams, PlanClock, latency_pace
from services.executor.faults import ASIDE, STRAIGHT_DOWN, FaultParams
from services.executor.plan_clearance import nearest, on_its_way
from services.executor.proximity import Bodies, Closing, ProximityParams, standing
from services.executor.takeover import VehicleOwnership
from services.executor.team_robots import TeamExecutor
from services.executor.trajectory import Trajectory
from services.executor.vehicle_controller import MOVING, OWN_TRACKING, ControlParams, VehicleController

log = logging.getLogger(__name__)

FAULT_MODES = {"emergency_landing": "emergency_landing", "holding": "holding"}

ROUTER_SETTLE_S = 2.0
"""After the router comes back, clients reconnect one by one (zenoh retries every 1 to 4 s):
ownership waits this long for the other executors' tokens before it moves any vehicle."""
TAKEOVER_GRACE_S = 0.1
"""A change of the live executors is applied this much later: a router shutting down drops its
clients one by one, so a peer's token may vanish a few ms before this process loses the router
too. Well inside the gateways' 0.2 s before a silent vehicle's command is stale."""
DELAY_EVERY_S = 1.0
"""s between two `PlanDelay`s of a running mission whose clock stands behind while no vehicle here
slows it (for an executor that missed the messages of the wait: a take-over, a reconnection)."""
ROUTER_CHECK_TICKS = 10
"""Control ticks between two looks at the router link (a look costs about a microsecond)."""
BODIES_FRESH_S = 2.0
"""s: a vehicle seen in a frame this recent is where a fault landing of another may not come down."""
STATE_FRESH_S = 0.25
"""s: another executor's vehicle whose state is older counts as not keeping to its plan (its
executor may have stalled) for the proximity stop's judging on the plans (five state periods)."""
ON_PLAN_MODES = MOVING | {Mode.PARKED, Mode.DONE}
"""The modes of a vehicle that keeps to its plan, when not held and not in a fault landing."""
REACT_WINDOW = 200
"""Cycles (2 s at 100 Hz) over which the proximity stop's reaction is measured (`LoopStats.recent_latency`)."""
FRAME_WAIT = 1.5
"""Control periods a cycle waits for a motion-capture frame before it runs without one."""


class LoopStats:
    """Cycle lateness (how long after its frame reached the mocap bridge, or after its due time
    without one, a cycle started), cycle cost and pose-to-command latency (the commands' publication
    - the capture time of the newest frame fused; and - the frame's arrival at the bridge: this
    software's part, without the capture system's own latency), last N of each; counts and the
    worst latency since the start. A cycle is missed (late) when its commands went out more than a
    period after its frame reached the bridge."""

    def __init__(self, n: int = 2000) -> None:
        self.late: deque[float] = deque(maxlen=n)
        self.cost: deque[float] = deque(maxlen=n)
        self.latency: deque[float] = deque(maxlen=10 * n)
        self.software: deque[float] = deque(maxlen=10 * n)
        self.ticks = 0
        self.missed = 0
        self.worst_latency = 0.0
        self.slowed = 0
        """Cycles in which the loop's latency slowed a running mission's clock (`latency_pace`)."""
        self.loop_pace = 1.0
        """The pace the loop's latency allowed at the last cycle."""
        self._react = 0.0
        self._react_at = 0

    def add(self, late: float, cost: float, period: float) -> None:
        self.ticks += 1
        self.late.append(late)
        self.cost.append(cost)
        if late + cost > period:
            self.missed += 1

    def add_latency(self, seconds: float, software: float) -> None:
        """From the capture, and from the frame's arrival at the bridge, to the commands' publication (s)."""
        self.latency.append(seconds)
        self.software.append(software)
        self.worst_latency = max(self.worst_latency, seconds)

    def recent_latency(self, n: int = REACT_WINDOW) -> float:
        """The p99 of the last `n` pose-to-command latencies (s; 0 before any), recomputed every
        `n` cycles: how late this executor's commands are now (the proximity stop's reaction)."""
        if self.ticks >= self._react_at:
            self._react_at = self.ticks + n
            recent = list(itertools.islice(reversed(self.latency), n))
            self._react = float(np.percentile(recent, 99)) if recent else 0.0
        return self._react

    def percentiles(self) -> dict[str, float]:
        return {**percentile_figures("late", self.late), **percentile_figures("cost", self.cost),
                **percentile_figures("pose_to_cmd", self.latency), **percentile_figures("frame_to_cmd", self.software)}

    def figures(self) -> dict[str, float]:
        """Counts, percentiles and the worst latency, for `stats/executor/<instance>`."""
        return {"ticks": self.ticks, "missed": self.missed, "pose_to_cmd_max_ms": 1e3 * self.worst_latency,
                "slowed_cycles": self.slowed, "loop_pace": self.loop_pace, **self.percentiles()}


class ExecutorService(Service):
    def __init__(self, instance: str, *args, rate_hz: float = 100.0, state_hz: float = 20.0,
                 control: ControlParams | None = None, proximity: ProximityParams | None = None,
                 **kwargs) -> None:
        super().__init__("executor", instance, *args, **kwargs)
        self.control = control or ControlParams()
        self.team = TeamExecutor(self, self.publish_states)
        self.period = 1.0 / rate_hz
        self.state_every = max(1, round(rate_hz / state_hz))
        self.plans: dict[str, VehiclePlan] = {}
        self.starts: dict[str, float] = {}
        self.aborts: dict[str, str] = {}
        self.ownership = VehicleOwnership(self.instance, lambda vid: vid in self.controllers, self._take,
                                          lambda vid: self.controllers.pop(vid, None))
        self.last_seen: dict[str, tuple[PoseFrame, FramePose]] = {}
        """The latest pose of every vehicle, owned or not (with its frame): a take-over starts from it."""
        self.bodies = Bodies(proximity or ProximityParams())
        """Every vehicle's position and velocity in the frames: the proximity stop's view."""
        self._landings: dict[str, tuple[float, tuple[float, float, float]]] = {}
        """Other executors' fault landings: vid -> (when heard, where it comes down)."""
        self._unstopped: dict[str, float] = {}
        """Other executors' vehicles in a fault or an emergency landing, which no proximity stop
        stops (`_going_on`): vid -> when heard."""
        self._heard: dict[str, VehicleState] = {}
        """Other executors' vehicles' latest states, for the proximity stop's report (`_standing`)."""
        self._spared: set[tuple[str, str]] = set()
        """(mover, other) pairs a proximity stop was spared for (`_plans_keep_apart`), told once."""
        self._ways: dict[str, tuple[VehiclePlan, Trajectory]] = {}
        """Other executors' vehicles' references, as their executors make them of their plans
        (`_plans_keep_apart`), each made when first asked for."""
        self.gateway_of: dict[str, str] = {}
        """Each vehicle's gateway, from its telemetry: where its commands go."""
        self._maps: dict[str, MapSpec | None] = {}
        """The plans' maps by name (None: not readable here), for fault landings off the graph."""
        self.controllers: dict[str, VehicleController] = {}
        self.bank = KalmanBank(EstimatorParams())
        """Every owned vehicle's pose filter, for fusing a frame in one step."""
        self.stats = LoopStats()
        self._last_mode: dict[str, Mode] = {}
        self._told_held: dict[str, int] = {}
        """Each vehicle's last hold reported (`VehicleController.holds`)."""
        self._told_aside: dict[str, tuple[float, float, float] | None] = {}
        """Each vehicle's emergency descent's spot beside a body last reported (`emergency_aside`)."""
        self._told_landing: dict[str, PlanStep | None] = {}
        """Where each vehicle's landing was heading at its last report (`VehicleController.landing_step`)."""
        self._told_aborted: list[str] = []
        """Vehicles whose mission this executor aborted while the router was lost: told once it is
        back, and again `ROUTER_SETTLE_S` later (clients reconnect one by one: a mission that came
        back after the first was never told, and waited for its time limit)."""
        self._executors: AliveSet | None = None
        self._router_lost_at: float | None = None
        self._router_back_at: float | None = None
        self._failed: set[tuple[str, str]] = set()  # (vid, mission) whose controller raised
        self.clocks: dict[str, PlanClock] = {}
        """Each mission's plan clock as this executor keeps it (`common/flight/plan_clock.py`)."""
        self._delay_sent: dict[str, tuple[float, float]] = {}  # mission -> (when, pace) of the last `PlanDelay`

    # ---- wiring ---------------------------------------------------------------------------------
    async def main(self) -> None:
        k = self.keys
        self.subscribe(k.all_vehicles("plan"), VehiclePlan, self._on_plan)
        frames = self.subscribe(k.mocap_frame, PoseFrame, maxlen=64)  # pulled by the control loop
        self.subscribe(k.all_vehicles("telemetry"), Telemetry, self._on_telemetry, maxlen=1024)
        self.subscribe(k.all_executor_states, VehicleStates, self._on_states, maxlen=1024)
        self.subscribe(k.all_vehicles("event"), VehicleEvent, self._on_event, maxlen=1024)
        self.subscribe(k.all_missions("start"), MissionStart, self._on_start)
        self.subscribe(k.all_missions("abort"), MissionAbort, self._on_abort)
        self.subscribe(k.all_missions("delay"), PlanDelay, self._on_delay, maxlen=1024)
        self._delay = self.publishers(lambda mission: k.mission(mission, "delay"), PlanDelay)
        self._cmd = self.publishers(lambda vid: k.vehicle(vid, "cmd"), Cmd)
        self._batch = self.publishers(k.gateway_cmd, CmdBatch)
        self._state = self.publishers(lambda vid: k.vehicle(vid, "state"), VehicleState)
        self._states = self.publisher(k.executor_states(self.instance), VehicleStates)
        self._event = self.publishers(lambda vid: k.vehicle(vid, "event"), VehicleEvent)
        self.team.open()
        loop = asyncio.get_running_loop()
        self._executors = await self.watch_alive(
            "executor", lambda _i, _a, _live: loop.call_later(TAKEOVER_GRACE_S, self._on_executors))
        self._reassign(self._executors.instances)
        self.spawn(publish_stats(self, self._figures), name="stats")
        await self._control_loop(frames)

    def _figures(self) -> dict[str, float]:
        estimators = [ctl.estimator for ctl in self.controllers.values()]
        return {"vehicles": len(self.controllers), **self.stats.figures(),
                "poses_rejected": sum(e.rejected for e in estimators),
                "estimator_restarts": sum(e.restarts for e in estimators)}

    # ---- ownership ------------------------------------------------------------------------------
    def _on_executors(self) -> None:
        """The live executors changed `TAKEOVER_GRACE_S` ago: re-apply ownership, unless the router
        is lost or just back (then `_check_router` does once the others have reconnected)."""
        if self._router_lost_at is None and self.session.info.routers_zid():
            assert self._executors is not None
            self._reassign(self._executors.instances)

    def _check_router(self, now: float) -> None:
        """Notice the loss of the router (abort the owned vehicles' missions) and its return
        (re-apply ownership once the other executors have had `ROUTER_SETTLE_S` to reconnect)."""
        if not self.session.info.routers_zid():
            self._router_back_at = None
            if self._router_lost_at is None:
                self._router_lost_at = now
                log.error("%s: lost the router: aborting the running missions (the gateways land or stop "
                          "the vehicles); ownership stands still until it is back", self.instance)
                for vid, ctl in self.controllers.items():
                    if ctl.t0 is not None:  # started (or due to start): its timing is gone
                        self.aborts.setdefault(self.plans[vid].mission, "the executor lost its router")
                        ctl.abort("the executor lost its router")
                        self._told_aborted.append(vid)
            return
        if self._router_lost_at is None:
            return
        if self._router_back_at is None:
            self._router_back_at = now
            log.warning("%s: the router is back after %.1f s", self.instance, now - self._router_lost_at)
            self._tell_aborted(now)
        elif now - self._router_back_at >= ROUTER_SETTLE_S:
            self._router_lost_at = self._router_back_at = None
            self._tell_aborted(now)  # again: the mission's own session may have reconnected only since
            self._told_aborted.clear()
            assert self._executors is not None
            self._reassign(self._executors.instances)

    def _tell_aborted(self, now: float) -> None:
        """The missions must know whose vehicles this executor aborted: nobody flies their plans on."""
        for vid in self._told_aborted:
            self._tell(VehicleEvent(vid=vid, t=now, kind="aborted",
                                    detail="the executor lost its router: mission aborted"))

    def _reassign(self, live: frozenset[str]) -> None:
        """Take the vehicles that hash to us, release the others (rendezvous hashing)."""
        self.ownership.reassign(live, self.plans)
        self.team.reassign(self.ownership.live)

    def _take(self, vid: str) -> None:
        plan = self.plans[vid]
        if (vid, plan.mission) in self._failed:
            return
        ctl = VehicleController(vid, plan.model, owner=self.instance, params=self.control, bank=self.bank,
                                bodies=lambda: self._bodies_besides(vid), ground=self._map(plan.map),
                                tracking_pause=self.tracking_pause(), count=self.counters.inc)
        ctl.load(plan)
        t0 = plan.t0 or self.starts.get(plan.mission)
        if t0:
            ctl.start(t0)
        prev = self.ownership.resume_from(vid, plan.mission)
        if prev is not None:
            seen = self.last_seen.get(vid)
            ctl.take_over(prev, time.time(), seen[0].pose(seen[1]) if seen else None)
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
        if ctl is not None and known is not None and known.mission == plan.mission and ctl.t0 is not None:
            if ctl.replan(plan, time.time()):  # the running mission planned on (issue 16)
                self.plans[plan.vid] = plan
            return
        if ctl is not None:
            if ctl.load(plan):  # refused while airborne: the old plan stays until it has landed
                self.plans[plan.vid] = plan
                t0 = plan.t0 or self.starts.get(plan.mission)
                if t0:
                    ctl.start(t0)
            return
        self.plans[plan.vid] = plan
        self.ownership.claim(plan.vid)

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
        if not abort.vehicles:  # the whole mission: a plan of it that comes later is aborted too
            self.aborts[abort.mission] = abort.reason
        if abort.hold:  # (only `vehicles`: held for the mission's sake, `VehicleController.stop_short`)
            for vid in abort.vehicles:
                ctl = self.controllers.get(vid)
                if (ctl is not None and self.plans[vid].mission == abort.mission
                        and not ctl.stop_short(abort.reason)):  # (it may not be held: the guard is off)
                    ctl.abort(abort.reason)
            return
        self.team.on_abort(abort)
        for vid, ctl in self.controllers.items():
            if self.plans[vid].mission == abort.mission and (not abort.vehicles or vid in abort.vehicles):
                ctl.abort(abort.reason)

    def _on_delay(self, msg: PlanDelay, _key: str) -> None:
        if msg.source != self.instance:
            self._clock(msg.mission).hear(msg.source, msg.delay, msg.pace, msg.t)

    def _clock(self, mission: str) -> PlanClock:
        clock = self.clocks.get(mission)
        if clock is None:
            clock = self.clocks[mission] = PlanClock(self.control.clock)
        return clock

    def _fuse(self, frames: list[PoseFrame]) -> None:
        """Take a cycle's `frames` (oldest first): every body's position for the proximity stop,
        every vehicle's newest pose remembered, and that pose of each owned vehicle fused, all at
        once. Only the newest: a cycle that found several frames waiting runs late (a starved
        process), and fusing each of them made every late cycle costlier than an on-time one
        (an executor of 80 under a profiler fused 1.9 frames a cycle, 30 % of its loop's time); a
        pose a hundredth of a second older adds next to nothing to the estimate."""
        fresh: dict[str, tuple[PoseFrame, FramePose]] = {}
        for frame in frames:
            self.bodies.update(frame)
            for p in frame.poses:
                fresh[p.vid] = (frame, p)
        self.last_seen.update(fresh)
        controllers = self.controllers
        estimators: list[PoseEstimator] = []
        poses: list[Pose] = []
        for vid, (frame, p) in fresh.items():
            ctl = controllers.get(vid)
            if ctl is not None:
                estimators.append(ctl.estimator)
                poses.append(frame.pose(p))
        fuse_poses(estimators, poses)

    def _map(self, name: str) -> Callable[[], MapSpec | None]:
        """The map a plan names, as it is known (`safe_landing_steps` keeps a landing off the graph out
        of its no-fly zones and obstacles): read once, off the event loop (city934 takes 80 ms, a
        stall a take-over in flight must not have); None until read, and for good, with a warning,
        if it cannot be read here (a map file only the planner's machine has): such landings then
        go by the plan's airspace alone."""
        if name not in self._maps:
            self._maps[name] = None
            threading.Thread(target=self._read_map, args=(name,), name=f"map {name}", daemon=True).start()
        return lambda: self._maps[name]

    def _read_map(self, name: str) -> None:
        try:
            self._maps[name] = load_map(name)
        except InputError as exc:
            log.warning("%s: cannot read the plans' map here (%s): a fault landing off the graph will not "
                        "know its no-fly zones and obstacles", self.instance, exc)

    def _bodies_besides(self, vid: str) -> list[tuple[float, float, float]]:
        """Where every vehicle but `vid` is (its pose in a frame of the last `BODIES_FRESH_S`), and
        where the fault landings of this executor and, by their states, of the others are heading:
        what a fault landing of `vid` keeps off."""
        now = time.time()
        seen = [(p.x, p.y, p.z) for other, (frame, p) in self.last_seen.items()
                if other != vid and now - frame.t < BODIES_FRESH_S]
        mine = [ctl.landing_step for other, ctl in self.controllers.items() if other != vid]
        theirs = [at for other, (t, at) in self._landings.items() if other != vid and now - t < BODIES_FRESH_S]
        return seen + [step.pos for step in mine if step is not None] + theirs

    def _on_telemetry(self, tel: Telemetry, _key: str) -> None:
        if tel.gateway:
            self.gateway_of[tel.vid] = tel.gateway
        ctl = self.controllers.get(tel.vid)
        if ctl is not None:
            ctl.on_telemetry(tel, time.time())

    def _on_states(self, batch: VehicleStates, _key: str) -> None:
        for state in batch.states:
            self._on_state(state)

    def _on_state(self, state: VehicleState) -> None:
        self.team.on_state(state)
        self.ownership.on_state(state)
        if state.owner != self.instance:  # another executor's fault landing, announced
            self._heard[state.vid] = state
            if state.landing is not None or state.mode == Mode.EMERGENCY_LANDING:
                self._unstopped[state.vid] = time.time()
            else:
                self._unstopped.pop(state.vid, None)
            if state.landing is not None:
                self._landings[state.vid] = (time.time(), state.landing)
                for ctl in self.controllers.values():
                    ctl.landing_wanted_by(state.vid, state.landing)
            else:
                self._landings.pop(state.vid, None)

    def publish_states(self, states: list[VehicleState], now: float) -> None:
        """Each state on its vehicle's key (tools) and all of them as one `VehicleStates` (the
        fleet's services)."""
        for state in states:
            self._state.put(state.vid, state)
        if states:
            self._states.put(VehicleStates(owner=self.instance, t=now, states=states))

    def _on_event(self, event: VehicleEvent, _key: str) -> None:
        """Another executor's vehicle's event: the fleet's reflex to it (`_reflex`). An owned
        vehicle's was run when it was told (`_tell`)."""
        if event.vid not in self.controllers:
            self._reflex(event, time.time())

    def _tell(self, event: VehicleEvent) -> None:
        """An owned vehicle's event, to everyone; the fleet's reflex to it runs here at once for this
        executor's other vehicles, not when the event comes back through the router: on a starved
        machine that took 0.25 s (an 80-vehicle soak: cf74 yielded to cf12, held by the same
        executor, that late, and ran into it)."""
        self._event.put(event.vid, event)
        self._reflex(event, event.t)

    def _reflex(self, event: VehicleEvent, now: float) -> None:
        """The fleet's reflex to a vehicle held by the tracking guard or coming down in an emergency
        landing (`VehicleController.yield_to`): every owned vehicle whose plan goes where it is held,
        or under it, holds too (at its next tick: this cycle's, if it has not ticked yet), and is
        reported in turn."""
        if event.kind not in ("tracking_hold", "emergency_landing") or (seen := self.last_seen.get(event.vid)) is None:
            return
        frame, pose = seen
        pos, unseen_s = (pose.x, pose.y, pose.z), event.t - frame.t  # (held on a stale pose: unseen a while)
        for vid, ctl in self.controllers.items():
            if vid != event.vid:
                ctl.yield_to(event.vid, pos, now, unseen_s, descending=event.kind == "emergency_landing")

    # ---- the loop -------------------------------------------------------------------------------
    async def _control_loop(self, frames: Subscription[PoseFrame]) -> None:
        """One cycle per motion-capture frame (module docstring): fuse the frames that arrived,
        tick every controller, send one batch per gateway. A cycle that runs late (a starved
        process) still fuses the newest pose of every body that reached the process before it
        judges staleness (`_fuse`)."""
        wait = FRAME_WAIT * self.period
        due = time.monotonic() + wait
        n = 0
        while True:
            await frames.wait(due - time.monotonic())
            start = time.monotonic()
            now = time.time()
            drained = [frame for frame, _key in frames.drain()]
            newest = drained[-1] if drained else None
            if newest is not None:
                self._fuse(drained)
                self.bodies.settle(newest.t)
            self._end_pauses(now)
            self._stop_short(now)
            self._keep_apart(now)
            if n % ROUTER_CHECK_TICKS == 0:
                self._check_router(now)
            arrived = (newest.arrived or newest.t) if newest is not None else 0.0
            self._run_clocks(now)
            self._cycle(now, n, newest.t if newest is not None else 0.0, arrived)
            n += 1
            end = time.monotonic()
            late = now - arrived if newest is not None else start - due
            self.stats.add(max(late, 0.0), end - start, self.period)
            if newest is not None:
                sent = time.time()
                self.stats.add_latency(sent - newest.t, sent - arrived)
            due = end + wait

    def _stop_short(self, now: float) -> None:
        """The proximity stop (`services/executor/proximity.py`): every owned vehicle moving on its
        plan that heads into another body holds (at the tick that follows; on a fault landing's
        flight to its node: hovers and chooses its node again, `VehicleController.stop_short`),
        judged every cycle, a new frame or not (`Bodies.reaction`). The guard's switch
        (`FaultParams.guard`) turns it off too."""
        if not self.control.faults.guard:
            return
        movers: list[str] = []
        velocities: list[tuple[float, float, float, float, float, float]] = []
        radius = height = 0.0
        rows = self.bodies.rows
        for vid, ctl in self.controllers.items():
            motion = ctl.motion()
            if motion is not None and vid in rows:
                movers.append(vid)
                velocities.append(motion)
                r, h = ctl.model.body()
                radius, height = max(radius, r), max(height, h)
        if not movers:
            return
        react = self.bodies.reaction(now, self.stats.recent_latency(), self.period)
        v_self = np.array(velocities).reshape(len(movers), 2, 3)
        for closing in self.bodies.closing(movers, v_self, radius, height, now, react,
                                           lambda: self._going_on(now), self._bend):
            if self._plans_keep_apart(closing, radius, height, now):
                self.counters.inc("proximity_kept_apart_by_plans")
                continue
            ctl = self.controllers[closing.mover]
            why = f"{closing.why()}; {self._standing(closing.mover, now)}; {self._standing(closing.other, now)}"
            if self._may_pause(closing.mover, closing.other, now):
                new = ctl.paused is None
                if ctl.pause(why, closing.other, now):
                    if new:
                        self.counters.inc("proximity_paused")
                    continue
            ctl.stop_short(why)

    def tracking_pause(self) -> tuple[float, float] | None:
        """(settle s, longest s) of a pause for a vehicle's own tracking
        (`VehicleController._pause_for_tracking`, `ProximityParams.pause_tracking`), with the plan's
        clock that stands for it (`ClockParams.enabled`) and the guard (`FaultParams.guard`); None:
        the guard holds at once."""
        p = self.bodies.params
        if not (p.pause_tracking and self.control.clock.enabled and self.control.faults.guard):
            return None
        return p.pause_settle_s, p.pause_max_s

    def _may_pause(self, mover: str, other: str, now: float) -> bool:
        """Whether `mover` may pause for `other` rather than be held (`ProximityParams.pause`, with
        `trust_plans`: a pause ends when the plans are judged to keep the two apart; and with the
        plan's clock, `ClockParams.enabled`: on the wall clock the plans would run on without the
        mover): both keep to their plans of one mission (`_keeping_to_plan`)."""
        clock = self.controllers[mover].plan_clock(now)
        p = self.bodies.params
        return (p.pause and p.trust_plans and self.control.clock.enabled and clock is not None
                and self._keeping_to_plan(other, clock[0], now) is not None)

    def _end_pauses(self, now: float) -> None:
        """Every owned vehicle stopped by its pause (`VehicleController.pause`) at least
        `pause_settle_s` ago goes back onto its plan's place (the others have come to theirs
        meanwhile), and goes on once its plan and the other vehicle's keep them apart from where
        they stand, both going on at full pace (`_gap_on_plans`, over the look-ahead of a closing
        at the two vehicles' fastest); one paused for `pause_max_s` (the pauses it continues
        counted), or whose other vehicle keeps to its plan no more (held, landing after a fault:
        the clock standing brings it back to no place of its plan), is held instead, as it would
        have been without the pause."""
        p = self.bodies.params
        for vid, ctl in self.controllers.items():
            pause = ctl.paused
            if pause is None or pause.other == OWN_TRACKING:  # (that one its controller ends: `_judge_tracking_pause`)
                continue
            if now - pause.stopped < p.pause_settle_s:
                continue
            clock = ctl.plan_clock(now)
            gone = clock is None or self._keeping_to_plan(pause.other, clock[0], now) is None
            if gone or now - pause.since >= p.pause_max_s:
                self.counters.inc("proximity_pause_held")
                ctl.stop_short(f"{pause.why}; paused {now - pause.since:.1f} s, "  # (held at its next tick: the pause ends)
                               + (f"{pause.other} keeping to no plan now" if gone else "the plans not keeping the two apart"))
                continue
            ctl.back_onto_plan()
            m = ctl.model
            react = self.bodies.reaction(now, self.stats.recent_latency(), self.period)
            radius, height = m.body()
            if self._gap_on_plans(vid, pause.other, react, 2.0 * max(m.speed.drive, m.speed.fly), now, 1.0,
                                  radius, height) > p.near_gap:
                self.counters.inc("proximity_pause_ended")
                ctl.go_on(now)

    def _plans_keep_apart(self, closing: Closing, radius: float, height: float, now: float) -> bool:
        """Whether the mover and the other body of `closing` both keep to their plans of one mission
        and these keep them apart until the mover could have stopped (`plan_clearance.py`): the
        mover goes on. Off with `ProximityParams.trust_plans`."""
        p = self.bodies.params
        if not p.trust_plans:
            return False
        gap = self._gap_on_plans(closing.mover, closing.other, closing.react, closing.speed, now, None, radius, height)
        if gap > p.near_gap and (closing.mover, closing.other) not in self._spared:
            self._spared.add((closing.mover, closing.other))
            log.info("%s: goes on past %s, both keeping to plans that keep them %.1f cm apart", closing.mover,
                     closing.other, 100 * gap)
        return gap > p.near_gap

    def _gap_on_plans(self, mover: str, other: str, react: float, speed: float, now: float, pace: float | None,
                      radius: float, height: float) -> float:
        """How near (m, `plan_clearance.nearest`) the bodies of `mover` (owned) and `other` come going
        on along their plans of one mission (`on_its_way`; at `pace`, or their clock's) until a
        closing at `speed` (at least; m/s) could have been stopped after `react` s; -inf when
        either keeps to no plan of that mission (`_keeping_to_plan`)."""
        p = self.bodies.params
        ctl = self.controllers[mover]
        clock = ctl.plan_clock(now)
        if clock is None or ctl.trajectory is None or mover not in self.bodies.rows or other not in self.bodies.rows:
            return -math.inf
        mission, rel, own_pace = clock
        way = self._keeping_to_plan(other, mission, now)
        if way is None:
            return -math.inf
        rows = [self.bodies.rows[mover], self.bodies.rows[other]]
        pos, vel = self.bodies.pos[rows], self.bodies.vel[rows]
        speed = max(float(np.sqrt(np.einsum("bx,bx->b", vel, vel)).sum()), speed)
        taus = np.linspace(0.0, react + float(self.bodies.stop_time(speed)), 2 * p.samples + 1)
        pace = own_pace if pace is None else pace
        ways = [on_its_way(w, pos[k], vel[k], rel, pace, taus, ctl.model.margin, p.velocity_s, react, p.hold_s)
                for k, w in enumerate((ctl.trajectory, way))]
        return nearest(*ways, radius, height)

    def _keeping_to_plan(self, vid: str, mission: str, now: float) -> Trajectory | None:
        """`vid`'s reference if it keeps to its plan in `mission`: an owned vehicle by its controller
        (`VehicleController.plan_clock`), another by its state of the last `STATE_FRESH_S`
        (in a mode of its plan, not held, no fault landing); None otherwise."""
        ctl = self.controllers.get(vid)
        if ctl is not None:
            clock = ctl.plan_clock(now)
            return ctl.trajectory if clock is not None and clock[0] == mission else None
        state, plan = self._heard.get(vid), self.plans.get(vid)
        if (state is None or plan is None or plan.mission != mission or state.mission != mission
                or now - state.t > STATE_FRESH_S or state.held or state.landing is not None
                or not state.pose_ok or state.mode not in ON_PLAN_MODES):
            return None
        known = self._ways.get(vid)
        if known is None or known[0] is not plan:
            try:
                way = Trajectory(plan.steps, self.control.trajectory)
            except ValueError:  # (a plan its own executor cannot follow either)
                return None
            known = self._ways[vid] = (plan, way)
        return known[1]

    def _keep_apart(self, now: float) -> None:
        """Every owned vehicle held hovering keeps `ProximityParams.standoff` from the other bodies:
        its hover's point moves away from those nearer (`Bodies.push_apart`), at most
        `standoff_speed` a second, up to `standoff_reach` from where it began to hover
        (`VehicleController.keep_apart`). Off with the guard (`FaultParams.guard`)."""
        if not self.control.faults.guard:
            return
        p = self.bodies.params
        step = p.standoff_speed * self.period
        for vid, ctl in self.controllers.items():
            at = ctl.held_hover()
            if at is None:
                continue
            radius, height = ctl.model.body()
            push = self.bodies.push_apart(vid, at, radius, height, now)
            if push is not None:
                scale = min(1.0, step / max(math.hypot(*push), 1e-12))
                ctl.keep_apart(scale * push[0], scale * push[1], p.standoff_reach)

    def _standing(self, vid: str, now: float) -> str:
        """How `vid` stands (`standing`): an owned vehicle by its last tick, another by its state heard."""
        ctl = self.controllers.get(vid)
        return standing(vid, ctl.state() if ctl is not None and ctl.ticked else self._heard.get(vid), now)

    def _bend(self, vid: str, taus: np.ndarray) -> np.ndarray:
        """How `vid`'s plan bends over the proximity stop's look-ahead (`VehicleController.bend`)."""
        return self.controllers[vid].bend(taus)

    def _going_on(self, now: float) -> set[str]:
        """The vehicles whose approach counts in the proximity stop, since nothing stops them: in a
        fault landing (its descent goes on) or an emergency landing, this executor's and, by their
        states of the last `BODIES_FRESH_S`, the others'."""
        mine = {vid for vid, ctl in self.controllers.items()
                if ctl.mode == Mode.EMERGENCY_LANDING or ctl.landing_step is not None}
        return mine | {vid for vid, t in self._unstopped.items() if now - t < BODIES_FRESH_S}

    def _run_clocks(self, now: float) -> None:
        """Move every running mission's plan clock on at the pace its vehicles here allowed at
        their last tick (the slowest) and this loop's latency allows (`latency_pace`), tell the
        others when it waits, and give each controller its mission's delay and pace (the slowest
        heard, too)."""
        paces: dict[str, float] = {}
        running: set[str] = set()  # missions with a vehicle here not done yet
        started = [(ctl, self.plans[vid].mission) for vid, ctl in self.controllers.items() if ctl.t0 is not None]
        for ctl, mission in started:
            paces[mission] = min(paces.get(mission, 1.0), ctl.clock_pace)
            if ctl.mode != Mode.DONE:
                running.add(mission)
        loop = self.stats.loop_pace = latency_pace(self.stats.recent_latency(), self.control.clock)
        if loop < 1.0 and running:
            self.stats.slowed += 1
            paces.update({m: min(paces[m], loop) for m in running})
        for mission, pace in paces.items():
            clock = self._clock(mission)
            delay = clock.wait(now, pace)
            sent, sent_pace = self._delay_sent.get(mission, (-float("inf"), 1.0))
            if (pace < 1.0 or clock.waited > 0.0 or sent_pace < 1.0
                    or (delay > 0.0 and mission in running and now - sent >= DELAY_EVERY_S)):
                self._delay_sent[mission] = (now, pace)
                self._delay.put(mission, PlanDelay(mission=mission, source=self.instance, delay=delay, pace=pace, t=now))
        timing = {m: (self.clocks[m].behind(now), min(pace, self.clocks[m].heard_pace(now))) for m, pace in paces.items()}
        for ctl, mission in started:
            ctl.delay, ctl.pace = timing[mission]

    def _cycle(self, now: float, n: int, pose_t: float, pose_arrived: float) -> None:
        """Tick every owned controller; commands out as one batch per gateway. Each vehicle's
        state goes out one cycle in `state_every`, the vehicles' turns spread over the cycles
        (all in one cycle, 80 vehicles' states made that cycle about 1 ms longer than the others:
        8-17 us a put), and the cycle's states go out together too (`publish_states`)."""
        batches: dict[str, list[Cmd]] = {}
        states: list[VehicleState] = []
        for k, (vid, ctl) in enumerate(list(self.controllers.items())):
            try:
                cmd = ctl.tick(now)
            except Exception as exc:  # one vehicle's bug must not take the others down
                self._give_up(vid, exc, now)
                continue
            gateway = self.gateway_of.get(vid)
            if gateway is None:
                self._cmd.put(vid, cmd)
            else:
                batches.setdefault(gateway, []).append(cmd)
            if (n + k) % self.state_every == 0:
                states.append(ctl.state())
            self._report_mode(vid, ctl, now)
        self.publish_states(states, now)
        sent = time.time()
        for gateway, cmds in batches.items():
            self._batch.put(gateway, CmdBatch(owner=self.instance, t=sent, cmds=cmds, pose_t=pose_t,
                                                   pose_arrived=pose_arrived))

    def _give_up(self, vid: str, exc: Exception, now: float) -> None:
        """Stop commanding `vid` for the rest of its mission (its gateway lands or stops it when
        its command goes stale) and tell everyone."""
        mission = self.plans[vid].mission
        log.exception("%s: the controller of %s failed; the vehicle is left to its gateway's safety "
                      "landing for the rest of mission %s", self.instance, vid, mission, exc_info=exc)
        self.counters.inc(f"controller_failed:{vid}")
        self._failed.add((vid, mission))
        del self.controllers[vid]
        self._tell(VehicleEvent(vid=vid, t=now, kind="controller_failed", detail=f"{type(exc).__name__}: {exc}"))

    def _report_mode(self, vid: str, ctl: VehicleController, now: float) -> None:
        """Tell everyone (`vehicle/<vid>/event`) when a vehicle enters a fault mode, or leaves its
        plan for a battery or link fault: "low_battery" / "link_lost", with the node it lands at and
        where that is (none: it lands where it is, stopped, or hovers to choose its node again: nowhere clear to
        land, or its flight there stopped short of a body); and when an emergency descent, its poses
        back, comes down beside a body in its column instead of where it is (node `ASIDE`, `at` the spot):
        the mission plans the others around that too."""
        prev, mode = self._last_mode.get(vid), ctl.mode
        self._last_mode[vid] = mode
        if ctl.held and self._told_held.get(vid) != ctl.holds and mode in (Mode.HOVERING, Mode.HOLDING):
            self._told_held[vid] = ctl.holds  # (also held while already holding: `_left_behind`)
            self._tell(VehicleEvent(vid=vid, t=now, kind="tracking_hold", detail=ctl.held,
                                    rejoinable=ctl.rejoinable, acted=True))
            return
        if prev != mode or (mode == Mode.LANDING and self._landing_moved(vid, ctl)):  # (or chosen again)
            self._report_change(vid, ctl, prev, mode, now)
        if mode == Mode.EMERGENCY_LANDING and (aside := ctl.emergency_aside) is not self._told_aside.get(vid):
            self._told_aside[vid] = aside
            if aside is not None:
                self._tell(VehicleEvent(
                    vid=vid, t=now, kind="emergency_landing", node=ASIDE, acted=True, at=aside,
                    detail=f"poses back: landing beside a body in its column at ({aside[0]:.2f}, {aside[1]:.2f})"))

    def _landing_moved(self, vid: str, ctl: VehicleController) -> bool:
        """Whether a vehicle landing heads for another node or spot than its last report said (a
        planned landing that a fault let go on and a body below sent elsewhere: `_planned_landing_blocked`)."""
        step = ctl.landing_step
        told = self._told_landing.get(vid)
        return step is not None and (told is None or (step.node, step.pos) != (told.node, told.pos))

    def _report_change(self, vid: str, ctl: VehicleController, prev: Mode | None, mode: Mode, now: float) -> None:
        """The event of a vehicle's change of mode from `prev` to `mode`, or of where it lands, if it is
        a fault's (`_report_mode`)."""
        if mode == Mode.LANDING:
            self._told_landing[vid] = ctl.landing_step
        kind, detail, node, at = FAULT_MODES.get(mode), f"from {prev}", "", None
        leaves_plan = (mode == Mode.LANDING or (mode == Mode.DONE and prev != Mode.LANDING)
                       or (mode == Mode.HOVERING and not ctl.held))  # (a fault landing with nowhere clear)
        if kind is None and leaves_plan:
            if ctl.faults.low_battery(ctl.charge_used_ah, now):
                kind = "low_battery"
            elif ctl.faults.link_lost(now):
                kind = "link_lost"
            step = ctl.landing_step
            node = step.node if step is not None else ""
            at = step.pos if step is not None and node != STRAIGHT_DOWN else None  # (down from where it is)
            where = ("landing straight down" if node == STRAIGHT_DOWN
                     else f"landing beside it at ({at[0]:.2f}, {at[1]:.2f})" if node == ASIDE and at is not None
                     else f"landing at {node}" if node
                     else "landing here" if mode == Mode.LANDING
                     else f"hovering here, {ctl.landing_wait}" if mode == Mode.HOVERING else "stopped here")
            detail = f"from {prev}: {where}"
        if kind is not None:
            self._tell(VehicleEvent(vid=vid, t=now, kind=kind, detail=detail, node=node, acted=True, at=at))


def cmd_executor(args: argparse.Namespace) -> int:
    control = ControlParams(faults=FaultParams(guard=args.tracking_guard),
                            clock=ClockParams(enabled=args.plan_clock))
    svc = ExecutorService(args.instance, zconfig_from_args(args), keys_from_args(args),
                          rate_hz=args.rate, state_hz=args.state_rate, control=control,
                          proximity=ProximityParams(pause_tracking=args.tracking_pause))
    return run_service(svc)
