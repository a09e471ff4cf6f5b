"""A mission run by the fleet's own mission runner (`fleet mission run` / `fleet mission team`,
started as a process like any client) and watched over the bus: its plans, start, abort, every
vehicle's state and events become `MissionEvent`s; its exit and summary become a `MissionResult`."""

from __future__ import annotations

import asyncio
import re
import signal
import time
from collections.abc import AsyncIterator, Callable, Sequence

from common.bus.messages import MissionAbort, MissionStart, VehicleEvent, VehiclePlan, VehicleState
from common.bus.pubsub import Publisher, Subscription, subscribe
from services.api._types import EventKind, MissionEvent, MissionResult, VehicleOutcome

_SUMMARY = re.compile(r"^(?:team )?mission (\S+): (OK|FAILED) \((.*)\) in [\d.]+ s$")
AT_REST_MODES = frozenset({"done", "parked", "holding", "failed", "aborted"})
"""Modes of a vehicle that has come to rest (flying cars and team robots)."""
LAND_WAIT_S = 15.0
"""After an abort, how long `Mission.abort` waits for every vehicle to come to rest."""


class Mission:
    """A running mission, `id` its id (for `add_task`): `events()` iterates over what happens (from
    its beginning), `wait()` returns its result, `abort()` lands every vehicle. Made by
    `AsyncFleet.start_mission`."""

    def __init__(self, fleet_session, keys, mission: str, vehicles: Sequence[str], argv: list[str],
                 env: dict[str, str], on_event: Callable[[MissionEvent], None] | None = None) -> None:
        self.id = mission
        self.vehicles = list(vehicles)
        self.plans: dict[str, VehiclePlan] = {}
        """Each vehicle's latest plan as the mission handed it out."""
        self._argv, self._env = argv, env
        self._on_event = on_event
        self._events: list[MissionEvent] = []
        self._changed = asyncio.Event()
        self._states: dict[str, VehicleState] = {}
        self._outcome: dict[str, dict] = {v: {"arrival_s": None, "max_err": 0.0} for v in vehicles}
        self._notes: list[str] = []
        self._output: list[str] = []
        self._t0: float | None = None
        self._delay = 0.0  # how far its plan's clock stands behind the wall clock (`VehicleState.delay`)
        self._started = time.time()
        self._result: MissionResult | None = None
        self._proc: asyncio.subprocess.Process | None = None
        k, s = keys, fleet_session
        self._subs: list[Subscription] = [
            subscribe(s, k.mission(mission, "start"), MissionStart, self._on_start),
            subscribe(s, k.mission(mission, "abort"), MissionAbort, self._on_abort),
            subscribe(s, k.all_vehicles("plan"), VehiclePlan, self._on_plan),
            subscribe(s, k.all_vehicles("event"), VehicleEvent, self._on_vehicle_event),
        ]
        self._abort_pub: Publisher[MissionAbort] = Publisher(s, k.mission(mission, "abort"), MissionAbort)
        self._task: asyncio.Task[None] | None = None

    # ---- running ------------------------------------------------------------------------------
    async def _launch(self) -> None:
        self._proc = await asyncio.create_subprocess_exec(
            *self._argv, env=self._env, stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.STDOUT)
        self._task = asyncio.get_running_loop().create_task(self._supervise(), name=f"mission {self.id}")

    async def _supervise(self) -> None:
        assert self._proc is not None and self._proc.stdout is not None
        async for raw in self._proc.stdout:
            self._output.append(raw.decode(errors="replace").rstrip("\n"))
        code = await self._proc.wait()
        for sub in self._subs:
            sub.close()
        self._abort_pub.close()
        self._result = self._conclude(code)
        self._emit("ended", detail=self._result.reason)

    def _conclude(self, code: int) -> MissionResult:
        ok, reason, summary = False, "", []
        for i, line in enumerate(self._output):
            match = _SUMMARY.match(line)
            if match and match.group(1) == self.id:
                ok, reason, summary = match.group(2) == "OK", match.group(3), self._output[i:]
        if not reason:
            tail = [line for line in self._output if line.strip()]
            reason = tail[-1] if tail else f"the mission runner exited with code {code}"
        outcomes = {}
        for vid in self.vehicles:
            state, noted = self._states.get(vid), self._outcome[vid]
            plan = self.plans.get(vid)
            voltage = plan.model.voltage if plan is not None else 0.0
            outcomes[vid] = VehicleOutcome(
                vid=vid, arrived=noted["arrival_s"] is not None, arrival_s=noted["arrival_s"],
                energy_j=state.charge_used_ah * 3600.0 * voltage if state is not None else 0.0,
                max_tracking_error=noted["max_err"], mode=state.mode if state is not None else "?",
                position=(state.x, state.y, state.z) if state is not None else (0.0, 0.0, 0.0))
        return MissionResult(mission=self.id, ok=ok and code == 0, reason=reason,
                             duration_s=time.time() - self._started, vehicles=outcomes, events=list(self._notes),
                             summary="\n".join(summary))

    # ---- what the bus says -------------------------------------------------------------------
    def _emit(self, kind: EventKind, **fields) -> None:
        event = MissionEvent(kind=kind, mission=self.id, t=time.time(), **fields)
        self._events.append(event)
        changed, self._changed = self._changed, asyncio.Event()
        changed.set()
        if self._on_event is not None:
            self._on_event(event)

    def _on_start(self, start: MissionStart, _key: str) -> None:
        if self._t0 is None:
            self._t0 = start.t0
            self._emit("started", detail=f"t0 {start.t0:.2f}")

    def _on_abort(self, abort: MissionAbort, _key: str) -> None:
        if abort.vehicles:  # stopped or held alone (a replan could not place them): the others go on
            for vid in abort.vehicles:
                if vid in self._outcome and self._result is None:
                    self._notes.append(abort.reason)
                    self._emit("vehicle_event", vid=vid, detail=abort.reason)
            return
        if not any(e.kind == "aborted" for e in self._events):
            self._emit("aborted", detail=abort.reason)

    def _on_plan(self, plan: VehiclePlan, _key: str) -> None:
        if plan.mission != self.id or plan.vid not in self._outcome:
            return
        before = self.plans.get(plan.vid)
        if before is None or before.steps != plan.steps:  # plans are re-sent every second: a new one is news
            self.plans[plan.vid] = plan
            self._emit("planned", vid=plan.vid, steps=len(plan.steps))

    def _on_vehicle_event(self, event: VehicleEvent, _key: str) -> None:
        if event.vid in self._outcome and self._result is None:
            text = f"{event.vid}: {event.kind} {event.detail}".strip()
            self._notes.append(text)
            self._emit("vehicle_event", vid=event.vid, detail=text)

    def _on_fleet_state(self, state: VehicleState) -> None:
        """A state of any vehicle (the fleet hands every one to its running missions)."""
        if state.vid not in self._outcome or state.mission != self.id:
            return
        before = self._states.get(state.vid)
        self._states[state.vid] = state
        if self._result is not None:  # over: kept only for `abort`'s wait until every vehicle rests
            return
        noted = self._outcome[state.vid]
        self._delay = max(self._delay, state.delay)
        if self._t0 is not None:
            noted["max_err"] = max(noted["max_err"], state.tracking_error)
        fields = {"vid": state.vid, "mode": state.mode, "step": state.step, "steps": state.steps}
        if before is None or before.mode != state.mode:
            self._emit("mode", **fields)
        if before is not None and before.step != state.step:
            self._emit("progress", **fields)
        if state.arrived and not (before is not None and before.arrived) and self._t0 is not None:
            noted["arrival_s"] = state.t - self._t0  # the latest arrival (a lifelong mission's vehicles arrive again)
            self._emit("arrived", **fields)

    # ---- the user's side ---------------------------------------------------------------------
    @property
    def done(self) -> bool:
        """Whether the mission is over."""
        return self._result is not None

    async def events(self) -> AsyncIterator[MissionEvent]:
        """Every event of the mission from its beginning, then live ones, until it has ended."""
        i = 0
        while True:
            changed = self._changed
            while i < len(self._events):
                yield self._events[i]
                i += 1
            if self._result is not None:
                return
            await changed.wait()

    async def wait(self) -> MissionResult:
        """Wait until the mission is over; its result (whether or not it succeeded)."""
        assert self._task is not None
        await asyncio.shield(self._task)
        assert self._result is not None
        return self._result

    async def plan_of(self, vid: str, timeout: float) -> VehiclePlan | None:
        """`vid`'s plan once the mission hands it out (None if the mission ended or `timeout` passed first)."""
        deadline = time.monotonic() + timeout
        while vid not in self.plans and self._result is None and time.monotonic() < deadline:
            changed = self._changed
            with_timeout = max(0.0, deadline - time.monotonic())
            try:
                await asyncio.wait_for(changed.wait(), with_timeout)
            except TimeoutError:
                break
        return self.plans.get(vid)

    async def abort(self, reason: str = "aborted through the API") -> MissionResult:
        """Abort: every vehicle lands at the nearest safe point or stops; returns the result."""
        if self._result is None:
            self._abort_pub.put(MissionAbort(mission=self.id, reason=reason))
            if self._proc is not None and self._proc.returncode is None:
                self._proc.send_signal(signal.SIGINT)
        result = await self.wait()
        deadline = time.monotonic() + LAND_WAIT_S
        while time.monotonic() < deadline and any(self._latest(v) not in AT_REST_MODES for v in self.vehicles):
            await asyncio.sleep(0.2)
        return result

    def _latest(self, vid: str) -> str:
        state = self._states.get(vid)
        return state.mode if state is not None else "parked"
