"""Faults in a burst are replanned once (issue 15): a mission whose vehicles are held one after
another while a replan is under way plans the others on once more after it, around every vehicle
that left, instead of once per fault; a fault while a held vehicle is being brought back
(`Replan.rejoin`) is replanned first. A real planner over zenoh; the mission's own replanning
(`MissionRunner.on_fault`), driven with the states its executors would have reported."""

from __future__ import annotations

import asyncio
import time

import msgspec
import pytest

from common.bus.keys import Keys
from common.bus.messages import MissionAbort, PlanReply, VehicleState
from common.bus.pubsub import query, subscribe
from common.bus.session import ZenohConfig
from common.domain.scenario import read_scenario
from services.executor.faults import ASIDE
from services.mission import runner as mission_runner
from services.mission.runner import MissionRunner, MissionSpec
from services.planner.service import PlannerService
from services.planner.sipp import search as sipp_search

KEYS = Keys("replanburst")
TASKS = read_scenario("maps/scenarios/town_8.yaml").tasks
FIRST, BURST = "cf7", ("cf1", "cf4", "cf8")
"""Held on the ground at their start spots: one, then three more while the others are replanned around it."""


class Burst(MissionRunner):
    """A started mission (its plan accepted, every vehicle parked at its start) whose vehicles are
    held: `FIRST`, and `BURST` while the replan around it asks the planner."""

    held_during: tuple[str, ...] = BURST
    """The vehicles held while the first replan asks the planner (none: a scenario without the burst)."""

    def __init__(self, router: str) -> None:
        super().__init__(MissionSpec(map="town", tasks=TASKS, time_limit=20), ZenohConfig.client(router), KEYS,
                         progress=False)
        self.burst = list(self.held_during)
        self.asked = 0
        """Replans asked of the planner."""

    async def _ask_replan(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        """The burst: while the first replan (around `FIRST`) asks the planner."""
        self.asked += 1
        while self.burst:
            vid = self.burst.pop(0)
            assert self.on_fault(vid, "tracking_hold", f"{vid}: held", "")
        return await super()._ask_replan(*args, **kwargs)

    async def start_parked(self, holding: str = "") -> None:
        """The mission's plan accepted and started half a second ago, every vehicle at its start
        spot, parked (`holding`: that one holding)."""
        reply = await query(self.session, self.keys.planner_plan, self.plan_request(), PlanReply, timeout=30)
        assert self.accept(reply) is None, reply.error
        assert self.plan is not None
        self.t0 = time.time() - 0.5
        for vid, path in self.plan.paths.items():
            x, y, z = self.plan.graph.nodes[path[0].node].pos
            self.states[vid] = VehicleState(vid=vid, t=time.time(), owner="e1", mode="holding" if vid == holding else "parked",
                                            x=x, y=y, z=z, yaw=0.0, mission=self.mission)

    async def main(self) -> None:
        try:
            await self.start_parked()
            assert self.on_fault(FIRST, "tracking_hold", f"{FIRST}: held", "")
            while self._replanning is not None and not self._replanning.done():  # (the burst queues more)
                await self._replanning
            await self._replanning
        finally:
            self.stop()


def with_planner(router: str, runner: Burst) -> None:
    """Run `runner` against a planner on `router`; no fault of the mission's."""

    async def main() -> None:
        planner = PlannerService("planner", "p1", ZenohConfig.client(router), KEYS)
        serving = asyncio.create_task(planner.run())
        try:
            await asyncio.sleep(0.5)
            assert await runner.run() == 0
        finally:
            planner.stop()
            await serving

    asyncio.run(main())
    assert not runner.fault, (runner.fault, runner.events)


def fly_burst(router: str, runner: Burst) -> None:
    """Run `runner` against a planner on `router`: the last plan leaves out every vehicle held."""
    with_planner(router, runner)
    assert runner.plan is not None
    assert set(runner.plan.paths) == set(TASKS) - {FIRST, *BURST}, sorted(runner.plan.paths)


@pytest.mark.timeout(60)
def test_a_burst_of_holds_during_a_replan_is_replanned_once_after_it(zenoh_router: str) -> None:
    """The burst comes while the replan around FIRST asks the planner, with the held vehicles'
    sweeps in its request: it cannot place them (they are held where they stand), which is no
    fault of the mission's since the next replan, queued behind it, plans around all four; the
    two between are left out."""
    runner = Burst(zenoh_router)
    fly_burst(zenoh_router, runner)
    assert runner.asked == 2 and runner.replans_skipped == 2, (runner.asked, runner.events)
    assert any("the replan of a later fault tries again" in e for e in runner.events), runner.events


class OneHold(Burst):
    """`FIRST` held at its start spot, nothing else: the replan around it."""

    held_during = ()

    async def main(self) -> None:
        try:
            await self.start_parked(holding=FIRST)
            assert self.on_fault(FIRST, "tracking_hold", f"{FIRST}: held", "")
            await self._replanning
        finally:
            self.stop()


@pytest.mark.timeout(60)
def test_a_replan_that_ran_out_of_its_time_is_asked_again_with_more(zenoh_router: str, monkeypatch) -> None:
    """A loaded machine's planner gets a share of a core: a replan whose time limit ended it with
    more to try (an 80-vehicle soak's mission aborted so) is asked for again, from later, with more
    time (`REPLAN_TIME_LIMITS_S`), and the mission goes on. Here the first try gets next to no time
    (its search looks at the clock at every expansion)."""
    monkeypatch.setattr(mission_runner, "REPLAN_TIME_LIMITS_S", (1e-6, 0.6))  # (a limit must be positive)
    monkeypatch.setattr(sipp_search, "DEADLINE_EVERY", 1)
    runner = OneHold(zenoh_router)
    with_planner(zenoh_router, runner)
    assert runner.plan is not None and set(runner.plan.paths) == set(TASKS) - {FIRST}, runner.events
    assert [e for e in runner.events if "the planner ran out of its 0.0 s" in e], runner.events


class RejoinDuringFault(Burst):
    """`FIRST` held for another's sake at its start spot; while the replan that would bring it back
    asks the planner, `BURST[0]` is held for its own tracking."""

    held_during = ()

    def __init__(self, router: str) -> None:
        super().__init__(router)
        self.fault_during: str | None = BURST[0]

    async def _ask_replan(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        if kwargs.get("rejoin") and self.fault_during:
            vid, self.fault_during = self.fault_during, None
            assert self.on_fault(vid, "tracking_hold", f"{vid}: held", "")
        return await super()._ask_replan(*args, **kwargs)

    async def main(self) -> None:
        try:
            await self.start_parked(holding=FIRST)
            assert self.on_fault(FIRST, "tracking_hold", f"{FIRST}: stops short of cf9", "", rejoinable=True)
            await self._replanning
            for attempt in range(2):  # the first is overtaken by the fault, the second brings it back
                self._rejoin[FIRST].since = self._rejoin[FIRST].last_try = time.time() - 5.0  # due
                self.sample()
                while self._replanning is not None and not self._replanning.done():
                    await self._replanning
                assert FIRST in self.left if attempt == 0 else FIRST not in self.left, (attempt, self.events)
        finally:
            self.stop()


@pytest.mark.timeout(60)
def test_a_fault_during_a_held_vehicles_return_is_replanned_first(zenoh_router: str) -> None:
    """A vehicle's fault while the replan that brings a held one back asks the planner: that
    replan's answer is dropped and the fault's replan goes first (the others planned around the
    new hold); the next try brings the held vehicle back, its plan saying so."""
    runner = RejoinDuringFault(zenoh_router)
    with_planner(zenoh_router, runner)
    assert runner.plan is not None and FIRST in runner.plan.paths and BURST[0] not in runner.plan.paths
    assert runner._back == {FIRST}, runner._back
    assert any(e.startswith(f"{FIRST} rejoined the mission") for e in runner.events), runner.events
    around = [e for e in runner.events if e.startswith("replanned") and f"around {FIRST}, {BURST[0]}" in e]
    assert around, runner.events  # the fault's replan, around both, before the return


class LinkWords(Burst):
    """`FIRST`'s link lost, in two words: its gateway's (`LinkHealth`: no log block for a second),
    then its executor's report of what it does about it (`VehicleEvent.acted`)."""

    held_during = ()

    async def main(self) -> None:
        try:
            await self.start_parked()
            assert self.on_fault(FIRST, "link_lost", f"{FIRST}: link_lost no log block for 1.00 s", "")
            assert FIRST not in self.left and self._replanning is None  # the gateway's word: left to the executor
            assert self.on_fault(FIRST, "link_lost", f"{FIRST}: link_lost from driving: stopped here", "", acted=True)
            assert FIRST in self.left and self._replanning is not None
            await self._replanning
        finally:
            self.stop()


@pytest.mark.timeout(60)
def test_a_gateways_link_lost_is_left_to_the_executor_whose_report_takes_the_vehicle_out(zenoh_router: str) -> None:
    runner = LinkWords(zenoh_router)
    with_planner(zenoh_router, runner)
    assert runner.plan is not None and FIRST not in runner.plan.paths


class LandsAside(Burst):
    """`FIRST`, hovering half a metre above its start, lands beside where it is on a low battery:
    its executor's event names no node of the graph (`ASIDE`) but where it comes down (`at`)."""

    held_during = ()
    spot: tuple[float, float, float] = (0.0, 0.0, 0.0)
    hover: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mode = "landing"

    async def tell_faults(self) -> None:
        """What `FIRST`'s executor tells the mission."""
        assert self.on_fault(FIRST, "low_battery", f"{FIRST}: low_battery from hovering: landing beside it",
                             ASIDE, acted=True, at=self.spot)

    async def main(self) -> None:
        try:
            await self.start_parked()
            state = self.states[FIRST]
            self.hover, self.spot = (state.x, state.y, 0.5), (state.x + 0.3, state.y, 0.0)
            self.states[FIRST] = msgspec.structs.replace(state, mode=self.mode, z=0.5)
            await self.tell_faults()
            await self._replanning
        finally:
            self.stop()


class EmergencyAside(LandsAside):
    """`FIRST`, hovering half a metre above its start, goes into an emergency landing (the others
    are replanned around its descent straight down); its poses back, its executor says it comes
    down beside a body in its column (`ASIDE`, `at`): the others are replanned around that too."""

    mode = "emergency_landing"

    async def tell_faults(self) -> None:
        assert self.on_fault(FIRST, "emergency_landing", f"{FIRST}: emergency_landing from flying", "", acted=True)
        await self._replanning
        assert not any(s.rest and s.p0 == self.spot for s in self.sweeps)
        assert self.on_fault(FIRST, "emergency_landing", f"{FIRST}: emergency_landing poses back: landing beside "
                             "a body in its column", ASIDE, acted=True, at=self.spot)


@pytest.mark.timeout(60)
@pytest.mark.parametrize("runner_type", [LandsAside, EmergencyAside])
def test_a_fault_landing_beside_the_vehicle_is_planned_around_where_it_comes_down(
        zenoh_router: str, runner_type: type[LandsAside]) -> None:
    runner = runner_type(zenoh_router)
    with_planner(zenoh_router, runner)
    mine = [s for s in runner.sweeps if s.vid == FIRST]
    above = (runner.spot[0], runner.spot[1], runner.hover[2])
    assert any(s.p0 == runner.hover and s.p1 == above for s in mine), mine  # level to above the spot
    assert any(s.rest and s.p0 == runner.spot for s in mine), mine  # then resting on it


class PlacesNoneInTheAir(Burst):
    """`FIRST` held at its start spot; the replan around it cannot place `ALOFT`, in flight half a
    metre above its start, nor `PARKED` (the planner's answer stood in for: an 80-vehicle soak's
    replan could not place a vehicle flying into the column of one held hovering, and the mission
    ended for all 80). The mission holds `ALOFT` where it is instead (`MissionAbort.hold`, heard on
    the bus), stops `PARKED` where it is, both at once (`PlanReply.unplaceable`), and plans the
    others on around all three."""

    held_during = ()
    ALOFT, PARKED = "cf4", "cf2"
    heard: list[MissionAbort]

    async def _ask_replan(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        self.asked += 1
        if self.asked == 1:
            return self._replan_failed(PlanReply(ok=False, error=f"no plan (could not place {self.ALOFT})",
                                                 failed_vehicle=self.ALOFT, unplaceable=[self.ALOFT, self.PARKED]))
        return await MissionRunner._ask_replan(self, *args, **kwargs)

    async def main(self) -> None:
        self.heard = []
        aborts = subscribe(self.session, self.keys.mission(self.mission, "abort"), MissionAbort,
                           lambda msg, _key: self.heard.append(msg))
        try:
            await self.start_parked(holding=FIRST)
            state = self.states[self.ALOFT]
            self.states[self.ALOFT] = msgspec.structs.replace(state, mode="flying", z=0.5)
            assert self.on_fault(FIRST, "tracking_hold", f"{FIRST}: held", "")
            await self._replanning
            await asyncio.sleep(0.3)
        finally:
            aborts.close()
            self.stop()


@pytest.mark.timeout(60)
def test_the_vehicles_a_replan_cannot_place_are_held_or_stopped_where_they_are_at_once_and_the_others_go_on(
        zenoh_router: str) -> None:
    runner = PlacesNoneInTheAir(zenoh_router)
    with_planner(zenoh_router, runner)
    aloft, parked = runner.ALOFT, runner.PARKED
    assert runner.asked == 2 and runner.plan is not None
    assert set(runner.plan.paths) == set(TASKS) - {FIRST, aloft, parked}, sorted(runner.plan.paths)
    assert [(m.vehicles, m.hold) for m in runner.heard] == [([aloft], True), ([parked], False)], runner.heard
    assert runner.left[aloft].startswith(f"{aloft}: held where it is, no plan around the vehicles that left")
    assert runner.left[parked].startswith(f"{parked}: stopped where it is, no plan around the vehicles that left")
    assert parked not in runner._left_with
    assert aloft in runner._left_with  # (it may come back: `rejoin.py`)
    state = runner.states[aloft]
    spot, column = [s for s in runner.sweeps if s.vid == aloft]  # where it hovers, and its column once the plan ended
    assert spot.rest and spot.p0 == spot.p1 == (state.x, state.y, 0.5), spot
    assert column.rest and column.p0 == (state.x, state.y, 0.5) and column.t0 > spot.t0, column


class StopsCarAfterCar(Burst):
    """`FIRST` held; the replans around it cannot place `JAM`'s cars, one a replan (the planner's
    answers stood in for: a car stopped on a road claims the switch node of the car behind it, and
    so on down the road; a 10-minute 80-vehicle soak's mission ended on the fourth when three stops
    were the most). Each is stopped where it is and the others are planned again, until a replan
    places them."""

    held_during = ()
    JAM = ("cf2", "cf3", "cf5", "cf6")

    async def _ask_replan(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        self.asked += 1
        if self.asked <= len(self.JAM):
            car = self.JAM[self.asked - 1]
            return self._replan_failed(PlanReply(ok=False, error=f"no plan (could not place {car})",
                                                 failed_vehicle=car, unplaceable=[car]))
        return await MissionRunner._ask_replan(self, *args, **kwargs)


@pytest.mark.timeout(60)
def test_a_jam_of_cars_a_replan_cannot_place_one_after_another_is_stopped_car_after_car(zenoh_router: str) -> None:
    runner = StopsCarAfterCar(zenoh_router)
    with_planner(zenoh_router, runner)
    assert runner.asked == len(runner.JAM) + 1 and runner.plan is not None and not runner.fault, runner.fault
    assert set(runner.plan.paths) == set(TASKS) - {FIRST, *runner.JAM}, sorted(runner.plan.paths)
    assert all(runner.left[car].startswith(f"{car}: stopped where it is") for car in runner.JAM), runner.left
