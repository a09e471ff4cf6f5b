"""What every mission does, whatever it flies: ask the planner, hand the plans out, start every
executor at a common time, watch, and end with a result. `MissionRunner` (paper 000: flying cars on
a graph) and `TeamMission` (paper 002: a ground-air team) are its two variants; they say what to
ask for, how to hand the answer out, when every vehicle has it and when the mission is over.

The skeleton, one short-lived service (`alive/mission/<id>`):

1. fail fast when no executor or no planner is alive;
2. `prepare` (a flying-car mission waits for each vehicle's radio link and learns its capabilities
   and battery from its gateway), then query
   `planner/plan` (the planner also publishes the plans it makes for a mission);
3. hand the plans out and wait until the executors of every vehicle report them loaded;
4. publish `MissionStart(t0)` `start_lead_s` ahead; plans and start are re-sent every `RESEND_S`
   while the mission runs (zenoh keeps no history: late joiners and take-overs need them);
5. every `TICK_S` ask the variant whether the mission is over; a fault ends it too, unless the
   variant handles it (`on_fault`: a flying-car mission plans the others on around the vehicle) or
   the mission keeps going on faults: a fault event (`FAULT_EVENTS`; a gateway's stale-command
   landing only if the commands do not come back: `stale_commands.py`), a vehicle in emergency
   landing, or no state from a vehicle for `contact_timeout_s` (its executor or the router is gone);
6. on failure or SIGINT/SIGTERM publish `MissionAbort` and wait (up to `LAND_WAIT_S`) until every
   vehicle has come to rest.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Generic, TypeVar

import msgspec

from common.bus.messages import (
    MissionAbort,
    MissionStart,
    PlanReply,
    PlanRequest,
    VehicleEvent,
    VehicleState,
    VehicleStates,
)
from common.bus.pubsub import SERVICE_START_S, QueryError, QueryTimeout, query
from common.bus.service import Service
from services.mission.stale_commands import StaleCommands

log = logging.getLogger(__name__)

R = TypeVar("R")

FAULT_EVENTS = frozenset({"emergency_landing", "low_battery", "link_lost", "crash", "stale_cmd_landing",
                          "controller_failed", "action_failed", "tracking_hold", "aborted"})
"""Events that end a mission (unless it keeps going). A motion-capture dropout (`mocap_lost`) is not
one by itself: the executor predicts through short dropouts and reports what it does about long
ones (an emergency landing, or holding on the ground)."""
AT_REST_MODES = frozenset({"done", "parked", "holding", "failed", "aborted"})
"""Modes of a vehicle that has come to rest after an abort (flying cars and team robots)."""
TICK_S = 0.1
"""How often the mission looks at its vehicles."""
RESEND_S = 1.0
"""Plans and the start are re-sent this often."""
RETRY_S = 0.5
"""Before the start (the plans until they are loaded) and after an abort (the abort until every
vehicle rests), what is not yet acknowledged is re-sent this often."""
PROGRESS_S = 2.0
"""How often a progress line is printed."""
LAND_WAIT_S = 10.0
"""After an abort, how long to wait for every vehicle to come to rest."""


@dataclass(frozen=True)
class MissionTiming:
    """Timeouts shared by every mission: the executors' `ready_timeout_s` to report the plans
    loaded, the planner's answer beyond the planning time limit, the start's lead, silence, and
    `link_wait_s` for the gateways' links to come up (a gateway still connecting: cflib's
    connection is hundreds of round trips)."""

    start_lead_s: float = 2.0
    ready_timeout_s: float = 20.0
    planner_timeout_s: float = 10.0
    contact_timeout_s: float = 2.0
    abort_on_fault: bool = True
    link_wait_s: float = 30.0


class MissionClient(Service, Generic[R]):
    """The skeleton of a mission; subclasses implement the hooks below and build a result `R`."""

    def __init__(self, mission: str, vehicles: Iterable[str], timing: MissionTiming, *args,
                 progress: bool = True, **kwargs) -> None:
        super().__init__("mission", mission, *args, **kwargs)
        self.mission = mission
        self.vehicles = list(vehicles)
        self.timing = timing
        self.print_progress = progress
        self.result: R | None = None
        self.states: dict[str, VehicleState] = {}
        """The latest state of each of the mission's vehicles (of any mission: their executors' view)."""
        self.events: list[str] = []
        self.fault: str | None = None
        self.heard: dict[str, float] = {}
        """vid -> arrival time of its latest state."""
        self.t0: float | None = None
        self.started = 0.0
        self.stale = StaleCommands()
        """Vehicles their gateways took over for stale commands, a fault only if it lasts."""

    # ---- hooks ------------------------------------------------------------------------------------
    async def prepare(self) -> str | None:
        """Before the plan request: learn what the plan needs from the live fleet; why the mission
        cannot start, if it cannot."""
        return None

    def plan_request(self) -> PlanRequest:
        """What to ask the planner for (with this mission's id, so that it publishes the plans)."""
        raise NotImplementedError

    def planner_wait_s(self) -> float:
        """How long the planner may take to answer."""
        raise NotImplementedError

    def accept(self, reply: PlanReply) -> str | None:
        """Take a successful reply; why it cannot be flown, or None. Subscribe to what the variant watches."""
        raise NotImplementedError

    def hand_out(self, t0: float) -> None:
        """Publish every vehicle's plan (t0 = 0 until the start time is known)."""
        raise NotImplementedError

    def loaded(self, vid: str) -> bool:
        """The executor of `vid` reports this mission's plan loaded."""
        state = self.states.get(vid)
        return state is not None and state.mission == self.mission

    def end_reason(self, now: float) -> str | None:
        """Why the mission is over now (success or not), or None while it goes on."""
        raise NotImplementedError

    def succeeded(self, reason: str) -> bool:
        """Whether the mission, over for `reason`, achieved what it was for."""
        raise NotImplementedError

    def conclude(self, ok: bool, reason: str) -> R:
        """The result of a mission that ended (`ok` so far) for `reason`."""
        raise NotImplementedError

    def progress_line(self, now: float) -> str:
        return ""

    def on_fault(self, vid: str, kind: str, text: str, node: str, rejoinable: bool = False,
                 acted: bool = False, at: tuple[float, float, float] | None = None) -> bool:
        """A fault of one vehicle (`kind`: its event, `node`: where its executor lands it, if it
        said, and `at` its position; `rejoinable`: held so that it may come back,
        `VehicleEvent.rejoinable`; `acted`: its executor's report of what it does,
        `VehicleEvent.acted`); whether the variant handles it (the mission goes on) instead of
        ending the mission."""
        return False

    def on_state(self, state: VehicleState) -> None:
        """A state of one of the mission's vehicles (already kept in `states`)."""

    def sample(self) -> None:
        """Called every tick while the mission runs."""

    async def before_result(self) -> None:
        """Called once the mission is over, before `conclude` (e.g. to let ground truth catch up)."""

    # ---- the skeleton -----------------------------------------------------------------------------
    async def main(self) -> None:
        self.started = time.time()
        try:
            self.result = await self._run()
        except asyncio.CancelledError:
            self.result = self.conclude(False, "interrupted")
            raise

    async def _run(self) -> R:
        if not (await self.watch_alive("executor")).instances:
            return self.conclude(False, "no executor is alive: start executors (fleet executor / fleet up)")
        if not (await self.watch_alive("planner")).instances:
            return self.conclude(False, "no planner is alive: start one (fleet planner / fleet up)")
        error = await self.prepare()
        if error:
            return self.conclude(False, error)
        wait = self.planner_wait_s()
        try:
            request = msgspec.structs.replace(self.plan_request(), reply_within=wait)
            reply = await query(self.session, self.keys.planner_plan, request, PlanReply, timeout=wait,
                                find_s=SERVICE_START_S)
        except QueryTimeout:
            return self.conclude(False, f"the planner did not answer within {wait:.0f} s")
        except QueryError as exc:
            return self.conclude(False, f"the planner is unreachable or failed: {exc}")
        if not reply.ok:
            return self.conclude(False, f"planning failed: {reply.error}")
        error = self.accept(reply)
        if error:
            return self.conclude(False, error)
        k = self.keys
        self.subscribe(k.all_executor_states, VehicleStates, self._on_states)
        self.subscribe(k.all_vehicles("event"), VehicleEvent, self._on_event)
        start_pub = self.publisher(k.mission(self.mission, "start"), MissionStart)
        abort_pub = self.publisher(k.mission(self.mission, "abort"), MissionAbort)
        if not await self._until(lambda: all(self.loaded(v) for v in self.vehicles), self.timing.ready_timeout_s,
                                 lambda: self.hand_out(0.0)):
            missing = sorted(v for v in self.vehicles if not self.loaded(v))
            return self.conclude(False, f"executors did not take the plans of {', '.join(missing)}")
        self.t0 = time.time() + self.timing.start_lead_s
        start = MissionStart(mission=self.mission, t0=self.t0, vehicles=self.vehicles)
        reason = await self._watch(start, start_pub, abort_pub)
        ok = self.succeeded(reason)
        if not ok:
            abort = MissionAbort(mission=self.mission, reason=reason)
            abort_pub.put(abort)
            await self._until(lambda: all(s.mode in AT_REST_MODES for s in self.states.values()), LAND_WAIT_S,
                              lambda: abort_pub.put(abort))
        await self.before_result()
        return self.conclude(ok, reason)

    async def _watch(self, start: MissionStart, start_pub, abort_pub) -> str:
        """Run the mission until it is over; the reason."""
        last_sent = last_print = -float("inf")
        try:
            while True:
                now = time.time()
                if now - last_sent >= RESEND_S:
                    last_sent = now
                    self.hand_out(start.t0)
                    start_pub.put(start)
                await asyncio.sleep(TICK_S)
                self.sample()
                now = time.time()
                if self.print_progress and now - last_print >= PROGRESS_S:
                    last_print = now
                    print(self.progress_line(now), flush=True)
                reason = self.end_reason(now)
                if reason is not None:
                    return reason
                self._check_contact(now)
                self._check_stale(now)
                if self.fault and self.timing.abort_on_fault:
                    return f"aborted on fault: {self.fault}"
        except asyncio.CancelledError:
            abort_pub.put(MissionAbort(mission=self.mission, reason="aborted on request"))
            raise

    async def _until(self, done: Callable[[], bool], timeout: float, again: Callable[[], None]) -> bool:
        """Call `again` every half second until `done()` (checked every tick) or `timeout`; whether it
        got done."""
        deadline = time.monotonic() + timeout
        last_again = -math.inf
        while time.monotonic() < deadline:
            if done():
                return True
            if time.monotonic() - last_again >= RETRY_S:
                last_again = time.monotonic()
                again()
            await asyncio.sleep(TICK_S)
        return done()

    def _on_states(self, batch: VehicleStates, _key: str) -> None:
        for state in batch.states:
            self._on_state(state)

    def _on_state(self, state: VehicleState) -> None:
        if state.vid not in self.vehicles:
            return
        self.states[state.vid] = state
        self.heard[state.vid] = time.time()
        if state.mission == self.mission and state.mode == "emergency_landing":  # its event may be lost
            text = f"{state.vid}: in emergency landing"
            if not self.on_fault(state.vid, "emergency_landing", text, ""):
                self.fault = self.fault or text
        self.on_state(state)

    def _check_contact(self, now: float) -> None:
        """A vehicle not heard from for `contact_timeout_s` is a fault (its owner or the router is gone)."""
        for vid in self.vehicles:
            silent = now - self.heard.get(vid, now)
            if silent > self.timing.contact_timeout_s:
                self.fault = self.fault or f"{vid}: lost contact (no state for {silent:.1f} s)"

    def _check_stale(self, now: float) -> None:
        """A vehicle whose commands did not come back within the grace after its gateway took it
        over is a fault (`stale_commands.py`)."""
        for event in self.stale.overdue(now):
            self._fault(event, f"{event.vid}: {event.kind}: no command came back within {self.stale.grace_s:.1f} s")

    def _on_event(self, event: VehicleEvent, _key: str) -> None:
        if event.vid not in self.vehicles:
            return
        text = f"{event.vid}: {event.kind} {event.detail}".strip()
        self.events.append(text)
        log.warning("vehicle event: %s", text)
        now = time.time()
        if event.kind == "stale_cmd_landing":  # a fault only if the commands do not come back
            self.stale.took_over(event, now)
        elif event.kind == "cmd_resumed" and (away := self.stale.resumed(event.vid, now)) is not None:
            self.events.append(f"{event.vid}: its commands came back after {away:.2f} s: it flies on")
        elif event.kind == "landed" and (took_over := self.stale.landed(event.vid)) is not None:
            self._fault(took_over, f"{event.vid}: {took_over.kind}: landed by its gateway, no command came back")
        elif event.kind in FAULT_EVENTS:
            self._fault(event, text)

    def _fault(self, event: VehicleEvent, text: str) -> None:
        """A fault of one vehicle: the variant's to handle (`on_fault`), or the mission's."""
        if not self.on_fault(event.vid, event.kind, text, event.node, event.rejoinable, event.acted, event.at):
            self.fault = self.fault or text

    def elapsed(self) -> float:
        return time.time() - self.started
