"""The fleet carries on when one vehicle leaves its plan for a reason other than a fault of its own
hardware (issue 16): held by the tracking guard after a gust, or stopped alone by the mission; the
planner plans the others on around it, they switch without stopping and arrive; no contact. Judged
in ground truth (`sim/truth`). The hardware faults (low battery, lost link, lost body) are flown
in tests/test_faults_battery.py, test_faults_radio.py and test_faults_mocap.py, with the same
outcome required."""

from __future__ import annotations

import math

import pytest

from common.bus.messages import MissionAbort, SimFault
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from tests.support.fleet_faults import NO_RECORDER, TOWN_TASKS, Watch, cruising, fly, until

pytestmark = pytest.mark.flight

GUST = SimFault(vid="cf1", kind="gust", duration_s=0.5, gust=(7.0, 0.0))
"""7 m/s^2 along +x for 0.5 s: pushes a cruising vehicle past three times town's 3 cm margin, the
guard's burst, which it holds at once (5 m/s^2 pushed it 9.3-9.7 cm, just past the burst; short of
it, the guard pauses the mission instead, `tests/test_proximity_pause.py`)."""


@pytest.mark.timeout(240)
def test_a_vehicle_held_by_wind_and_one_stopped_alone_leave_the_others_flying_on(tmp_path) -> None:
    """Two more ways out of a mission, in one flight. cf1, pushed off its plan by a gust in cruise,
    is held hovering by the tracking guard (issue 15) and the others are replanned around its
    column; then cf3, driving, is stopped alone (`MissionAbort.vehicles`: what the mission sends
    when a replan cannot place a driving vehicle) and stays where it stopped. cf2 flies on to its
    goal, no contact. The gust pushed cf1 along its way, not off it: held on it, it is brought
    back once it stands still and arrives too (`VehicleController._on_its_way`)."""
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20, slack_s=3.0)
    marks: dict[str, float] = {}

    async def scenario(watch: Watch, runner: MissionRunner) -> None:
        await cruising(watch, "cf1")
        watch.inject(GUST)
        await until(lambda: watch.first("cf1", "tracking_hold") is not None, 5, "cf1 held by the guard")
        await until(lambda: bool(runner.replans), 5, "the replan around cf1")
        assert watch.mode("cf3") == "driving", watch.mode("cf3")
        marks["abort"] = watch.abort(MissionAbort(mission=spec.mission, reason="test: cf3 alone", vehicles=["cf3"]))

    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="heldalone", without=NO_RECORDER) as fleet:
        result, watch = fly(fleet, spec, scenario)

    assert result.plan is not None
    goals = {vid: result.plan.graph.nodes[task.goal].pos for vid, task in TOWN_TASKS.items()}
    stopped = [s for s in watch.truth["cf3"] if s.t > marks["abort"] + 0.5]
    assert stopped and max(math.dist((s.x, s.y), (stopped[0].x, stopped[0].y)) for s in stopped) < 0.01
    assert watch.distance_to("cf3", goals["cf3"]) > 0.1 and not result.vehicles["cf3"].arrived  # short of its goal
    assert result.vehicles["cf2"].arrived and watch.distance_to("cf2", goals["cf2"]) < 0.05
    assert watch.at_rest_on_ground("cf1") and watch.hardest_touchdown("cf1") < 0.7
    held = [e for _, e in watch.events if e.vid == "cf1" and e.kind == "tracking_hold"]
    assert held and held[0].rejoinable and "late on it" in held[0].detail, held
    assert any(e.startswith("cf1 rejoined") for e in result.events), result.events
    assert result.vehicles["cf1"].arrived and watch.distance_to("cf1", goals["cf1"]) < 0.05, result.summary()
    assert result.contacts == 0 and not watch.contacts, watch.separation_line()
    # latency from the capture and from the frame's arrival at the bridge: every sample of the first
    # is one of the second plus the simulated capture system's own latency (6 ms, docs/mocap.md)
    ex, gw = watch.stats["executor"].figures, watch.stats["gateway"].figures
    assert ex["pose_to_cmd_p50_ms"] >= ex["frame_to_cmd_p50_ms"] + 5.9, ex
    assert gw["pose_to_radio_p99_ms"] >= gw["frame_to_radio_p99_ms"] + 5.9, gw
    print(f"cf1 held, replanned in {', '.join(f'{1e3 * t:.0f} ms' for t in result.replans)}; {result.events}")
