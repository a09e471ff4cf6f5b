"""End to end over real zenoh and processes (issue 6): a 3-vehicle town mission flown by two
executor processes, one killed mid-flight; every vehicle still arrives without contact, the killed
executor's vehicles pass to the other within a second and the gateways obey the new owner."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import time
from pathlib import Path

import pytest

from common.deploy.radios import LinkModel
from common.domain.planfile import Task
from common.domain.scenario import read_scenario
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from tests.support.fleet_faults import NO_RECORDER, SETTLE_S, TOWN_TASKS, Watch, settle
from tests.support.service_logs import service_warnings

pytestmark = pytest.mark.flight

REPO = Path(__file__).resolve().parents[1]


def _pid_of(run_dir, instance: str) -> int:
    procs = json.loads((run_dir / "up.json").read_text())
    return next(p["pid"] for p in procs if p["instance"] == instance)


@pytest.mark.timeout(240)
def test_executor_killed_mid_flight_its_vehicles_still_arrive(tmp_path) -> None:
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)
    killed: dict[str, object] = {}
    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="e2e", without=NO_RECORDER) as fleet:
        runner = MissionRunner(spec, fleet.client_config(), fleet.keys, progress=False)

        async def kill_when_flying() -> None:
            while True:
                flying = [s for s in runner.states.values() if s.mode == "flying" and s.mission == spec.mission]
                if flying:
                    victim = flying[0]
                    killed.update(vid=victim.vid, owner=victim.owner, t=time.time())
                    os.kill(_pid_of(fleet.run_dir, victim.owner), signal.SIGKILL)
                    return
                await asyncio.sleep(0.05)

        watch = Watch(fleet.keys)  # ground truth

        async def scenario() -> None:
            watch.open(fleet.client_config())
            try:
                mission = asyncio.create_task(runner.run())
                await asyncio.wait_for(kill_when_flying(), timeout=60)
                # the vehicle passes to the surviving executor: at once when the router sees the
                # connection close (0.17-0.23 s measured), else when the 0.8 s lease expires (seen
                # once in CI: over 1.5 s), plus the 0.1 s grace and the new owner's first state
                while runner.states[killed["vid"]].owner == killed["owner"]:
                    assert time.time() - killed["t"] < 2.5, "no take-over within 2.5 s" + service_warnings(fleet.run_dir)
                    await asyncio.sleep(0.02)
                killed["handover_s"] = time.time() - killed["t"]
                assert await mission == 0
                await settle(watch, spec.tasks, SETTLE_S)
            finally:
                watch.close()

        asyncio.run(scenario())
    result = runner.result
    assert result is not None, "mission did not run"
    print(result.summary(), f"\nhand-over after {killed['handover_s']:.2f} s")
    assert result.ok, result.summary()
    assert result.contacts == 0
    assert all(r.arrived for r in result.vehicles.values())
    assert result.vehicles[killed["vid"]].owner not in ("", killed["owner"])
    # the world agrees: no contact, and every vehicle, those handed over too, rests on its goal
    assert not watch.contacts, (watch.separation_line(), watch.contacts[:5])
    assert result.plan is not None
    for vid, task in spec.tasks.items():
        goal = result.plan.graph.nodes[task.goal].pos
        assert watch.at_rest_on(vid, goal), (vid, task.goal, watch.truth[vid][-1] if watch.truth[vid] else None)
    print(f"{watch.separation_line()}; ground-truth goal errors (m):",
          {vid: round(watch.distance_to(vid, result.plan.graph.nodes[t.goal].pos), 3) for vid, t in spec.tasks.items()})


@pytest.mark.timeout(240)
def test_ten_percent_packet_loss_keeps_tracking_within_bounds(tmp_path) -> None:
    """Issue 5: with 10 % of radio packets lost, tracking stays within issue 4's bounds (RMS 3 cm on
    the ground, 5 cm in the air), measured by the executors against their references."""
    tasks = {k: TOWN_TASKS[k] for k in ("cf1", "cf3")}  # a flyer and a driver
    spec = MissionSpec(map="town", tasks=tasks, planner="sipp", time_limit=20)
    with local_fleet("town", tasks, tmp_path / "run", executors=1, fleet="lossy",
                     link=LinkModel(loss=0.10, seed=3), without=NO_RECORDER) as fleet:
        runner = MissionRunner(spec, fleet.client_config(), fleet.keys, progress=False)
        asyncio.run(runner.run())
    result = runner.result
    assert result is not None
    print(result.summary())
    assert result.ok, result.summary()
    for r in result.vehicles.values():
        assert r.rms_error("ground") <= 0.03, r
        assert r.rms_error("air") <= 0.05, r
    assert result.vehicles["cf1"].samples["air"] > 100  # it flew


@pytest.mark.timeout(240)
def test_stock_crazyflies_fly_a_fly_only_mission(tmp_path) -> None:
    """Issue 14: stock firmware, no wheel app, no STATUS replies: the mission learns each vehicle's
    capabilities from its gateway, the planner keeps them in the air, every vehicle arrives."""
    scenario = read_scenario(REPO / "maps" / "scenarios" / "town_fly.yaml")
    tasks = {vid: Task(start=t.start, goal=t.goal) for vid, t in scenario.tasks.items()}  # the scenario says nothing
    spec = MissionSpec(map="town", tasks=tasks, planner="sipp", time_limit=20)
    with local_fleet("town", dict(scenario.tasks), tmp_path / "run", executors=1, fleet="stock", without=NO_RECORDER) as fleet:
        runner = MissionRunner(spec, fleet.client_config(), fleet.keys, progress=False)
        asyncio.run(runner.run())
    result = runner.result
    assert result is not None
    print(result.summary())
    assert result.ok and result.contacts == 0, result.summary()
    assert result.plan is not None and all(t.capabilities == "fly" for t in result.plan.tasks.values())
    kinds = {k for _u, _v, k in result.plan.graph.edges}
    assert "drive" in kinds  # the map has roads; the vehicles did not use them:
    edge = {(u, v): k for u, v, k in result.plan.graph.edges}
    for path in result.plan.paths.values():
        assert all(edge[(a.node, b.node)] != "drive" for a, b in zip(path, path[1:], strict=False) if a.node != b.node)
