"""The simulated team over zenoh (`fleet sim team`, paper 002 §IV-E): actions run once in the
world with the drone's sensing, repeats are answered with their status, ground truth for both."""

from __future__ import annotations

import asyncio
import time

import pytest

from common.bus.keys import Keys
from common.bus.messages import ActionStatus, SimTruth, TeamAction
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import ZenohConfig, open_session
from common.domain import team_plan as tp
from common.team.maps import load_env
from common.team.sensing import Sensing
from common.team.team_model import TeamModel
from services.sim.team.service import TeamSimService
from services.sim.team.world import TeamWorld

KEYS = Keys("collab-sim-test")
CLIMB = tp.Step(tp.Altitude(2.0), (1.25, 1.25, 2.0), 1.0)
# the UGV's markers are 5 m away, beyond the camera's 2.5 m: GOTOLANDMARK_DYN is not available
FAR_DYN = tp.Step(tp.GoToLandmarkDyn((0.5, 0.5, 1.2), (1.25, 6.25, 2.0)), (1.25, 6.25, 2.0), 1.0)


@pytest.mark.timeout(30)
def test_actions_run_once_with_sensing_and_repeats_get_their_status(zenoh_router: str) -> None:
    async def body():
        zc = ZenohConfig.client(zenoh_router)
        world = TeamWorld(Sensing(load_env("demo-room"), TeamModel()), (1.25, 1.25, 1.0), (5.75, 1.25, 0.0))
        sim = TeamSimService("sim", zc, KEYS, world, {"drone": "d1", "ugv": "u1"}, time_scale=10.0)
        task = asyncio.create_task(sim.run())
        client = open_session(zc)
        got: list[ActionStatus] = []
        truth: dict[str, SimTruth] = {}
        subs = [subscribe(client, KEYS.all_vehicles("action_status"), ActionStatus, lambda m, _k: got.append(m)),
                subscribe(client, KEYS.all_sim_truth, SimTruth, lambda m, _k: truth.__setitem__(m.vid, m))]
        action = Publisher(client, KEYS.vehicle("d1", "action"), TeamAction)

        async def send(index: int, step: tp.Step, until: str) -> ActionStatus:
            action.put(TeamAction(vid="d1", owner="test", mission="m1", index=index, step=step, t=time.time()))
            for _ in range(200):
                found = [s for s in got if s.index == index and s.status == until]
                if found:
                    return found[-1]
                await asyncio.sleep(0.02)
            raise AssertionError(f"no {until} for step {index}: {got}")

        try:
            await asyncio.sleep(0.3)
            done = await send(0, CLIMB, "done")
            assert done.pose == (1.25, 1.25, 2.0) and [s.status for s in got if s.index == 0] == ["started", "done"]
            again = await send(0, CLIMB, "done")
            assert again.t == done.t  # answered, not run again
            failed = await send(1, FAR_DYN, "failed")
            assert "GoToLandmarkDyn not available" in failed.detail and failed.pose == (1.25, 1.25, 2.0)
            assert world.xyz("drone") == (1.25, 1.25, 2.0)
            await asyncio.sleep(0.3)
            assert truth["d1"].z == 2.0 and truth["d1"].airborne
            assert (truth["u1"].x, truth["u1"].y, truth["u1"].z) == (5.75, 1.25, 0.0)
        finally:
            for s in subs:
                s.close()
            action.close()
            client.close()
            sim.stop()
            assert await task == 0

    asyncio.run(body())
