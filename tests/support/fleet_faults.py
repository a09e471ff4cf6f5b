"""Harness of the fault tests (tests/test_faults_*.py): a mission on a local fleet (in-process router,
every service a process, simulated Crazyflies), watched as any other process would see it, with
faults injected through the simulators' fault keys (`sim/fault/<vid>`, docs/reliability.md)."""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import defaultdict
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass, field

import zenoh

from common.bus.keys import Keys
from common.bus.messages import (
    MissionAbort,
    ServiceStats,
    SimFault,
    SimTruth,
    Telemetry,
    VehicleEvent,
    VehicleState,
)
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import ZenohConfig, open_session
from common.domain.planfile import Task
from common.domain.vehicle_model import VehicleModel
from services.mission.demo import LocalFleet
from services.mission.runner import MissionResult, MissionRunner, MissionSpec
from services.mission.separation import SeparationMonitor

TOWN_TASKS = {
    "cf1": Task(start="WP10", goal="EP8"),  # flies west -> east through the corridor
    "cf2": Task(start="EP7", goal="WP9"),   # flies east -> west
    "cf3": Task(start="WP7", goal="WP3"),   # drives in the west (15 s)
}
"""16 s plans on the town map: both flyers airborne from about 4 s to 12 s of the mission."""
STATS_SERVICES = ("executor", "gateway", "sim", "mocap")
NO_RECORDER = ("telemetry",)
"""Services a flight test that judges the control path leaves out of compose.yaml's fleet: the
recorder is tested by the live view, the examples and its own tests, and would only share the
2-core machine with the loops being judged."""
AT_NODE_M = 0.08
"""m (3D, ground truth) from a node that counts as being on it: the executor's own arrival radius
(5 cm, on its estimate) plus its estimate's error from the truth (motion-capture noise, a few cm)."""
SAFE_TOUCHDOWN = 0.7
"""m/s: the hardest touchdown of a landing under position control (about 0.5 m/s: the motors stop
2 cm up); a fall from cruise height is 2.8 m/s."""


async def until(predicate: Callable[[], bool], timeout: float, what: str | Callable[[], str]) -> None:
    """Wait for `predicate`; on timeout fail naming `what` (a callable says what is still missing)."""
    try:
        async with asyncio.timeout(timeout):
            while not predicate():
                await asyncio.sleep(0.02)
    except TimeoutError:
        raise AssertionError(f"timed out after {timeout} s waiting for {what() if callable(what) else what}") from None


@dataclass
class Watch:
    """Ground truth, states, telemetry and events of every vehicle, each stamped on arrival."""

    keys: Keys
    truth: dict[str, list[SimTruth]] = field(default_factory=lambda: defaultdict(list))
    states: dict[str, list[VehicleState]] = field(default_factory=lambda: defaultdict(list))
    telemetry: dict[str, list[Telemetry]] = field(default_factory=lambda: defaultdict(list))
    events: list[tuple[float, VehicleEvent]] = field(default_factory=list)
    stats: dict[str, ServiceStats] = field(default_factory=dict)
    """Latest `stats/<service>/<instance>` of each service, by service name (one instance each here)."""
    separation: SeparationMonitor = field(default_factory=lambda: SeparationMonitor(*VehicleModel().body()))
    """The bodies' separation in ground truth over everything watched (sampled on every truth),
    including after the mission ended, while its vehicles settled."""
    _faults: dict[str, Publisher[SimFault]] = field(default_factory=dict)
    _session: zenoh.Session | None = None

    def open(self, config: ZenohConfig) -> None:
        """Subscribe (from the event loop)."""
        s = self._session = open_session(config)
        subscribe(s, self.keys.all_sim_truth, SimTruth, self._on_truth, maxlen=4096)
        subscribe(s, self.keys.all_vehicles("state"), VehicleState, lambda m, _k: self.states[m.vid].append(m))
        subscribe(s, self.keys.all_vehicles("telemetry"), Telemetry, lambda m, _k: self.telemetry[m.vid].append(m))
        subscribe(s, self.keys.all_vehicles("event"), VehicleEvent, lambda m, _k: self.events.append((time.time(), m)))
        for service in STATS_SERVICES:  # one per service: the router's access control grants them so
            subscribe(s, self.keys.all_stats(service), ServiceStats, lambda m, _k: self.stats.__setitem__(m.service, m))

    def _on_truth(self, truth: SimTruth, _key: str) -> None:
        self.truth[truth.vid].append(truth)
        self.separation.update(truth)

    def close(self) -> None:
        if self._session is not None:
            self._session.close()

    @property
    def contacts(self) -> list[tuple[float, str, str, float]]:
        """(t, vid, vid, gap) of every sample in which two bodies intersected, in ground truth."""
        return self.separation.contacts

    def inject(self, fault: SimFault) -> float:
        """Publish `fault`; the time it was published."""
        assert self._session is not None
        pub = self._faults.get(fault.vid)
        if pub is None:
            pub = self._faults[fault.vid] = Publisher(self._session, self.keys.sim_fault(fault.vid), SimFault)
        pub.put(fault)
        return time.time()

    def abort(self, abort: MissionAbort) -> float:
        """Publish `abort` (as the operator or a mission would); the time it was published."""
        assert self._session is not None
        Publisher(self._session, self.keys.mission(abort.mission, "abort"), MissionAbort).put(abort)
        return time.time()  # (the publisher goes with the session)

    def mode(self, vid: str) -> str:
        return self.states[vid][-1].mode if self.states[vid] else ""

    def kinds(self, vid: str, since: float = 0.0) -> list[str]:
        return [e.kind for t, e in self.events if e.vid == vid and t >= since]

    def first(self, vid: str, kind: str, since: float = 0.0) -> float | None:
        """Arrival time of the first `kind` event of `vid` from `since` on."""
        return next((t for t, e in self.events if e.vid == vid and e.kind == kind and t >= since), None)

    def truth_between(self, vid: str, t0: float, t1: float = math.inf) -> list[SimTruth]:
        return [s for s in self.truth[vid] if t0 <= s.t <= t1]

    def hardest_touchdown(self, vid: str) -> float:
        """The simulator's fastest touchdown of `vid` (m/s; above about 1 m/s it fell)."""
        return self.stats["sim"].figures[f"touchdown_mps:{vid}"]

    def locked(self, vid: str) -> bool:
        """Whether the simulated firmware of `vid` reported its supervisor Locked (reboot required)
        and no reboot followed."""
        kinds = [k for k in self.kinds(vid) if k in ("sim_locked", "sim_reboot")]
        return bool(kinds) and kinds[-1] == "sim_locked"

    def at_rest_on_ground(self, vid: str) -> bool:
        return _at_rest(self.truth[vid][-1])

    def rest_since(self, vid: str) -> float | None:
        """The time (ground truth's clock) from which `vid` has been at rest on the ground; None if
        it is not at rest now."""
        samples = self.truth[vid]
        if not samples or not _at_rest(samples[-1]):
            return None
        since = samples[-1].t
        for s in reversed(samples):
            if not _at_rest(s):
                break
            since = s.t
        return since

    def last_touchdown(self) -> float:
        """The time (ground truth's clock) of the last vehicle's last touchdown: its first sample on
        the ground after one in the air (0 if none flew; its last sample if one is still up)."""
        last = 0.0
        for samples in self.truth.values():
            up = next((k for k in range(len(samples) - 1, -1, -1) if samples[k].airborne), None)
            if up is not None:
                last = max(last, samples[min(up + 1, len(samples) - 1)].t)
        return last

    def distance_to(self, vid: str, pos: tuple[float, float, float]) -> float:
        """m from where `vid` is in ground truth (its last truth) to `pos`."""
        s = self.truth[vid][-1]
        return math.dist((s.x, s.y, s.z), pos)

    def at_rest_on(self, vid: str, pos: tuple[float, float, float], tolerance: float = AT_NODE_M) -> bool:
        """Whether `vid` rests on the ground within `tolerance` m of `pos`, in ground truth."""
        return bool(self.truth[vid]) and self.at_rest_on_ground(vid) and self.distance_to(vid, pos) < tolerance

    def landed_safely(self, vid: str, touchdown: float = SAFE_TOUCHDOWN) -> str:
        """Why `vid` did not come down safely in ground truth ('' if it did): at rest on the ground,
        motors off, no touchdown harder than `touchdown` m/s, its supervisor not left locked."""
        if not self.truth[vid]:
            return f"{vid}: no ground truth"
        if not self.at_rest_on_ground(vid):
            return f"{vid}: not at rest on the ground: {self.truth[vid][-1]}"
        if self.hardest_touchdown(vid) >= touchdown:
            return f"{vid}: touched down at {self.hardest_touchdown(vid):.2f} m/s (bound {touchdown})"
        if self.locked(vid):
            return f"{vid}: the supervisor locked and was not rebooted"
        return ""

    def separation_line(self) -> str:
        sep = self.separation
        gap = "none closer than 1 m" if sep.min_gap == math.inf else f"{100 * sep.min_gap:.1f} cm {sep.min_pair}"
        return f"ground truth: closest bodies {gap}, contacts {len(sep.contacts)}"


def _at_rest(s: SimTruth) -> bool:
    """On the ground, motors off."""
    return not s.airborne and not s.motors and s.z < 0.01


Scenario = Callable[[Watch, MissionRunner], Awaitable[None]]

SETTLE_S = 3.0
"""s after a mission's end for its vehicles to come to rest: a landing's last stop can be lost on
the radio, and the gateway repeats it when the next status reply still shows the motors running."""

SUPERVISOR_WATCH_S = 4.0
"""s watched after a safety landing came to rest: the firmware's supervisor locks a vehicle whose
setpoints stop while it still counts as flying (its motors above idle within 1.5 s, then the 2 s
commander watchdog: up to 3.6 s after the motors stopped), so a lock would show here."""


async def settle(watch: Watch, vids: Iterable[str], timeout: float) -> None:
    """Wait until every one of `vids` is at rest on the ground or `timeout` passed (the tests'
    assertions then say which is not)."""
    with contextlib.suppress(AssertionError):
        await until(lambda: all(watch.truth[v] and watch.at_rest_on_ground(v) for v in vids), timeout, "rest")


def fly(fleet: LocalFleet, spec: MissionSpec, scenario: Scenario) -> tuple[MissionResult, Watch]:
    """Run the mission of `spec` on `fleet` while `scenario(watch, runner)` injects and checks;
    return the mission's result and everything watched."""
    watch = Watch(fleet.keys)
    runner = MissionRunner(spec, fleet.client_config(), fleet.keys, progress=False)

    async def main() -> None:
        watch.open(fleet.client_config())
        try:
            mission = asyncio.create_task(runner.run())
            await scenario(watch, runner)
            assert await mission == 0
            await settle(watch, runner.spec.tasks, SETTLE_S)
            landed = [watch.rest_since(v) for v in runner.spec.tasks if watch.first(v, "emergency_landing")]
            if landed:
                rested = max(landed) if None not in landed else time.time()
                await asyncio.sleep(max(rested + SUPERVISOR_WATCH_S - time.time(), 0.0))
            # the simulator's figures (touchdowns, motors cut in the air) from after the last touchdown
            touchdown = watch.last_touchdown()
            await until(lambda: "sim" in watch.stats and watch.stats["sim"].t > touchdown, 5.0, "the sim's stats")
        finally:
            watch.close()

    asyncio.run(main())
    assert runner.result is not None, "the mission did not run"
    print(runner.result.summary())
    return runner.result, watch


def airborne(watch: Watch, vid: str, z: float = 0.3) -> Callable[[], bool]:
    return lambda: bool(watch.truth[vid]) and watch.truth[vid][-1].z > z


async def cruising(watch: Watch, vid: str) -> None:
    """Wait until `vid` flies at cruise height, then 1 s more (in cruise, the setpoint the firmware
    keeps through a silence is about the hover's)."""
    await until(lambda: watch.mode(vid) == "flying", 60, f"{vid} flying")
    await until(airborne(watch, vid), 5, f"{vid} at cruise height")
    await asyncio.sleep(1.0)


def assert_the_others_arrived(result: MissionResult, watch: Watch, faulted: str) -> None:
    """Issue 16's outcome of one vehicle's fault, judged in ground truth: the mission replanned the
    others around `faulted`, every other vehicle is at its goal, `faulted` came down softly and
    rests on the ground, no supervisor is left locked and no bodies touched."""
    assert faulted in result.reason and "every other vehicle arrived" in result.reason, result.reason
    assert result.replans, result.events
    assert result.plan is not None
    assert watch.landed_safely(faulted) == "", watch.landed_safely(faulted)
    for vid in result.vehicles:
        if vid == faulted:
            continue
        assert not watch.locked(vid), f"{vid}: the supervisor locked and was not rebooted"
        goal = result.plan.graph.nodes[result.plan.paths[vid][-1].node].pos
        assert watch.distance_to(vid, goal) < 0.05, (vid, watch.truth[vid][-1], goal)
        assert result.vehicles[vid].arrived, vid
    assert result.contacts == 0 and not watch.contacts, (watch.separation_line(), watch.contacts[:5])
