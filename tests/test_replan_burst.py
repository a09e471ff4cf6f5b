"""Faults in a burst are replanned once (issue 15): a mission whose vehicles are held one after
another while a replan is under way plans the others on once more after it, around every vehicle
that left, instead of once per fault. A real planner over zenoh; the mission's own replanning
(`MissionRunner.on_fault`), driven with the states its executors would have reported."""

from __future__ import annotations

import asyncio
import time

import pytest

from common.bus.keys import Keys
from common.bus.messages import PlanReply, VehicleState
from common.bus.pubsub import query
from common.bus.session import ZenohConfig
from common.domain.scenario import read_scenario
from services.mission.runner import MissionRunner, MissionSpec
from services.planner.service import PlannerService

KEYS = Keys("replanburst")
TASKS = read_scenario("maps/scenarios/town_8.yaml").tasks
FIRST, BURST = "cf7", ("cf1", "cf4", "cf8")
"""Held on the ground at their start spots: one, then three more while the others are replanned around it."""


class Burst(MissionRunner):
    """A started mission (its plan accepted, every vehicle parked at its start) whose vehicles are
    held: `FIRST`, and `BURST` while the replan around it asks the planner."""

    def __init__(self, router: str) -> None:
        super().__init__(MissionSpec(map="town", tasks=TASKS, time_limit=20), ZenohConfig.client(router), KEYS,
                         progress=False)
        self.burst = list(BURST)
        self.asked = 0
        """Replans asked of the planner."""

    async def _ask_replan(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        """The burst: while the first replan (around `FIRST`) asks the planner."""
        self.asked += 1
        while self.burst:
            vid = self.burst.pop(0)
            assert self.on_fault(vid, "tracking_hold", f"{vid}: held", "")
        return await super()._ask_replan(*args, **kwargs)

    async def main(self) -> None:
        try:
            reply = await query(self.session, self.keys.planner_plan, self.plan_request(), PlanReply, timeout=30)
            assert self.accept(reply) is None, reply.error
            assert self.plan is not None
            self.t0 = time.time() - 0.5
            for vid, path in self.plan.paths.items():
                x, y, z = self.plan.graph.nodes[path[0].node].pos
                self.states[vid] = VehicleState(vid=vid, t=time.time(), owner="e1", mode="parked", x=x, y=y, z=z,
                                                yaw=0.0, mission=self.mission)
            assert self.on_fault(FIRST, "tracking_hold", f"{FIRST}: held", "")
            while self._replanning is not None and not self._replanning.done():  # (the burst queues more)
                await self._replanning
            await self._replanning
        finally:
            self.stop()


def fly_burst(router: str, runner: Burst) -> None:
    """Run `runner` against a planner on `router`: no fault of the mission's, and the last plan
    leaves out every vehicle held."""

    async def main() -> None:
        cfg = ZenohConfig.client(router)
        planner = PlannerService("planner", "p1", cfg, KEYS)
        serving = asyncio.create_task(planner.run())
        try:
            await asyncio.sleep(0.5)
            assert await runner.run() == 0
        finally:
            planner.stop()
            await serving

    asyncio.run(main())
    assert not runner.fault, (runner.fault, runner.events)
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
