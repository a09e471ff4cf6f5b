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
    held: `FIRST`, and `BURST` right after the replan around it has gone to the planner."""

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
            await asyncio.sleep(0.05)  # its replan has asked the planner
            for vid in BURST:
                assert self.on_fault(vid, "tracking_hold", f"{vid}: held", "")
            assert self._replanning is not None
            await self._replanning
        finally:
            self.stop()


@pytest.mark.timeout(60)
def test_a_burst_of_holds_during_a_replan_is_replanned_once_after_it(zenoh_router: str) -> None:
    cfg = ZenohConfig.client(zenoh_router)
    runner = Burst(MissionSpec(map="town", tasks=TASKS, time_limit=20), cfg, KEYS, progress=False)

    async def main() -> None:
        planner = PlannerService("planner", "p1", cfg, KEYS)
        serving = asyncio.create_task(planner.run())
        try:
            await asyncio.sleep(0.5)
            assert await runner.run() == 0
        finally:
            planner.stop()
            await serving

    asyncio.run(main())
    assert not runner.fault, runner.fault
    assert runner.plan is not None
    assert set(runner.plan.paths) == set(TASKS) - {FIRST, *BURST}, sorted(runner.plan.paths)
    # the replan under way, then one for the three (not three: each a planner's time, one after another)
    assert len(runner.replans) == 2 and runner.replans_skipped == 2, (runner.replans, runner.events)
