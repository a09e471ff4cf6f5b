"""Motion-capture dropouts mid-flight (issues 8 and 16), injected at the simulated motion capture:
0.3 s is bridged by the executor's prediction (the vehicle flies its plan on and arrives), 2 s makes
it land (a blind, level emergency descent) and the mission replans the others around it: every one
of them arrives; 1 s in a take-off lands it in the take-off's column and the mission brings it
back. Judged in ground truth, no contact. A bridge that falls behind drops late frames rather than
queue them."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

import pytest
import zenoh

from common.bus.messages import MocapBody, MocapFrame, SimFault
from common.bus.pubsub import Publisher
from common.bus.session import ZenohConfig
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from services.mocap_bridge.bridge import MocapBridge
from services.mocap_bridge.config import MocapConfig
from tests.support.fleet_faults import (
    NO_RECORDER,
    TOWN_TASKS,
    Watch,
    airborne,
    assert_the_others_arrived,
    cruising,
    fly,
    until,
)

SHORT, LONG = 0.3, 2.0


@pytest.mark.flight
@pytest.mark.timeout(180)
def test_a_short_dropout_is_flown_through_a_long_one_lands_the_vehicle_and_the_others_fly_on(tmp_path) -> None:
    """cf2 loses its body for 0.3 s in cruise and flies on to its goal; then cf1 for 2 s: it lands,
    cf2 and cf3 are replanned around it and arrive."""
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)
    marks: dict[str, float] = {}

    async def scenario(watch: Watch, runner: MissionRunner) -> None:
        await until(lambda: watch.mode("cf1") == "flying" and watch.mode("cf2") == "flying", 60, "both flying")
        await cruising(watch, "cf2")
        marks["short"] = watch.inject(SimFault(vid="cf2", kind="mocap_dropout", duration_s=SHORT))
        await cruising(watch, "cf1")
        await asyncio.sleep(max(0.0, marks["short"] + SHORT + 0.5 - time.time()))
        assert watch.mode("cf1") == "flying", "cf1 must still be flying for the long dropout"
        marks["long"] = watch.inject(SimFault(vid="cf1", kind="mocap_dropout", duration_s=LONG))

    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="mocapfault", without=NO_RECORDER) as fleet:
        result, watch = fly(fleet, spec, scenario)

    short, long = marks["short"], marks["long"]
    # the short dropout happened (the bridge reported the body lost) and was flown through
    assert "mocap_lost" in watch.kinds("cf2", since=short)
    cf2 = [s for s in watch.states["cf2"] if short <= s.t < long]
    assert {s.mode for s in cf2} <= {"flying", "landing"}, {s.mode for s in cf2}
    assert all(s.pose_ok for s in cf2), "the prediction must bridge 0.3 s"
    assert max(s.tracking_error for s in cf2) < 0.05
    assert min(s.z for s in watch.truth_between("cf2", short, long)) > 0.3
    assert watch.first("cf2", "emergency_landing") is None
    # the long one made cf1 land, blind, soon after the prediction went stale; the others flew on
    landed_at = watch.first("cf1", "emergency_landing")
    assert landed_at is not None and landed_at - long < 1.0, watch.kinds("cf1")
    assert "cf1: " in result.reason and "emergency" in result.reason, result.reason
    assert watch.landed_safely("cf1", touchdown=0.6) == ""  # in ground truth: at rest, motors off, softly
    assert_the_others_arrived(result, watch, "cf1")
    print(f"cf2 through {SHORT} s: worst tracking error {max(s.tracking_error for s in cf2):.3f} m; "
          f"cf1 emergency landing {landed_at - long:.2f} s into {LONG} s, touchdown {watch.hardest_touchdown('cf1'):.2f} m/s; "
          f"replanned in {', '.join(f'{1e3 * t:.0f} ms' for t in result.replans)}; {watch.separation_line()}")


@pytest.mark.flight
@pytest.mark.timeout(180)
def test_a_dropout_in_a_take_off_lands_the_vehicle_on_its_spot_and_the_mission_brings_it_back(tmp_path) -> None:
    """cf1 loses its body for 1 s half-way up its take-off (a motion-capture stall): it comes down
    blind in its take-off's column, is held there once seen again, and the mission brings it back
    into the plan: it takes off again and arrives, as do the others; no contact in ground truth."""
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)
    marks: dict[str, float] = {}

    async def scenario(watch: Watch, runner: MissionRunner) -> None:
        await until(lambda: watch.mode("cf1") == "taking_off" and airborne(watch, "cf1", 0.15)(), 60,
                    "cf1 half-way up its take-off")
        marks["lost"] = watch.inject(SimFault(vid="cf1", kind="mocap_dropout", duration_s=1.0))

    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="takeoffdrop", without=NO_RECORDER) as fleet:
        result, watch = fly(fleet, spec, scenario)

    lost = marks["lost"]
    landed_at, held_at = watch.first("cf1", "emergency_landing", lost), watch.first("cf1", "tracking_hold", lost)
    assert landed_at is not None and held_at is not None and landed_at < held_at, watch.kinds("cf1", lost)
    assert any(e.startswith("cf1 rejoined") for e in result.events), result.events
    assert result.ok, result.summary()
    assert result.plan is not None
    for vid in result.vehicles:
        goal = result.plan.graph.nodes[result.plan.paths[vid][-1].node].pos
        assert watch.distance_to(vid, goal) < 0.05 and result.vehicles[vid].arrived, (vid, watch.truth[vid][-1], goal)
        assert watch.landed_safely(vid) == "", watch.landed_safely(vid)
    assert result.contacts == 0 and not watch.contacts, (watch.separation_line(), watch.contacts[:5])
    print(f"cf1 came down {landed_at - lost:.2f} s into the dropout, held {held_at - lost:.2f} s after it; "
          f"{watch.separation_line()}")


def test_late_frames_are_dropped_not_queued(zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    """A bridge that falls behind drops frames older than `max_age_s` (counted) instead of
    publishing a backlog of late poses; a frame delivered 0.15 s late (a loaded machine) is kept."""
    cfg = ZenohConfig.client(zenoh_router)
    bridge = MocapBridge(MocapConfig(), cfg)
    session = zsession()
    frames = Publisher(session, bridge.keys.sim_mocap, MocapFrame)

    async def main() -> None:
        task = asyncio.create_task(bridge.run())
        await until(lambda: frames.matched, 5.0, "the bridge's subscription")
        for age in (1.0, 0.5, 0.15, 0.0):
            frames.put(MocapFrame(t=time.time() - age, bodies=[MocapBody("cf1", 0.0, 0.0, 0.0, 0.0)]))
        await until(lambda: bridge.published.get("cf1") == 2, 2.0, "the late and the fresh pose")
        bridge.stop()
        assert await task == 0

    asyncio.run(main())
    assert bridge.counters["late_frames"] == 2
