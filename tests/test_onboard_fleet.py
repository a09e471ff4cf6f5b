"""Onboard control mode end to end (issue 17): `fleet demo`'s fleet (planner, executor, gateways,
simulated Crazyflies and motion capture, as processes over zenoh) with every vehicle in onboard
mode flies a town mission: every vehicle arrives, no two bodies touch in ground truth, the gateways
report the mode, the simulated firmware never received an attitude setpoint and its estimators
fused the streamed poses (the simulator's stats count both), and the touchdowns are gentle."""

from __future__ import annotations

import asyncio
import time

import pytest

from common.bus.messages import ServiceStats, Telemetry
from common.bus.pubsub import subscribe
from common.bus.session import open_session
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from tests.support.fleet_faults import NO_RECORDER, SAFE_TOUCHDOWN, TOWN_TASKS

pytestmark = pytest.mark.flight


@pytest.mark.timeout(240)
def test_onboard_mode_flies_a_town_mission_without_contact(tmp_path) -> None:
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)
    controls: dict[str, str] = {}
    stats: list[ServiceStats] = []
    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=1, fleet="onboard", control="onboard", without=NO_RECORDER) as fleet:
        runner = MissionRunner(spec, fleet.client_config(), fleet.keys, progress=False)

        async def fly() -> None:
            session = open_session(fleet.client_config())
            subs = [subscribe(session, fleet.keys.all_vehicles("telemetry"), Telemetry,
                              lambda tel, _k: controls.__setitem__(tel.vid, tel.control)),
                    subscribe(session, fleet.keys.all_stats("sim"), ServiceStats, lambda s, _k: stats.append(s))]
            try:
                await runner.run()
                deadline = time.monotonic() + 5.0
                while not stats and time.monotonic() < deadline:
                    await asyncio.sleep(0.1)
            finally:
                for sub in subs:
                    sub.close()
                session.close()

        asyncio.run(fly())
    result = runner.result
    assert result is not None
    print(result.summary())
    assert result.ok and result.contacts == 0, result.summary()
    assert result.vehicles["cf1"].samples["air"] > 100 and result.vehicles["cf2"].samples["air"] > 100  # they flew
    assert controls == dict.fromkeys(TOWN_TASKS, "onboard")
    figures = stats[-1].figures
    assert figures["attitude_setpoints"] == 0  # RPYT packets the simulated firmware received
    assert figures["ext_poses_fused"] > 1000  # by the vehicles' Kalman estimators
    assert figures["touchdown_max_mps"] <= SAFE_TOUCHDOWN
