"""Battery below its reserve mid-flight (issues 8 and 16), injected into the simulated battery in
cruise: the voltage sags under the flight current, the executor sees it (telemetry vbat < 3.3 V for
1 s), lands the vehicle at the nearest node where its plan takes off or lands and tells everyone (a
"low_battery" VehicleEvent naming that node); the mission replans the others around where it comes
down and every one of them arrives. Judged in ground truth, no contact."""

from __future__ import annotations

import math

import pytest

from common.bus.messages import SimFault
from common.bus.vehicle_plans import vehicle_plans
from common.domain.vehicle_model import VehicleModel
from services.executor.faults import landing_nodes
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from tests.support.fleet_faults import (
    NO_RECORDER,
    TOWN_TASKS,
    Watch,
    assert_the_others_arrived,
    cruising,
    fly,
)

pytestmark = pytest.mark.flight

MODEL = VehicleModel()
NEARLY_EMPTY_AH = MODEL.capacity_ah - 0.5 * MODEL.reserve_ah
"""Half the reserve left (5 % of the capacity): about 3.1 V in flight."""


@pytest.mark.timeout(180)
def test_low_battery_mid_flight_lands_at_the_nearest_safe_node_and_the_others_fly_on(tmp_path) -> None:
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)
    marks: dict[str, float] = {}

    async def scenario(watch: Watch, runner: MissionRunner) -> None:
        await cruising(watch, "cf1")
        marks["drained"] = watch.inject(SimFault(vid="cf1", kind="battery", charge_used_ah=NEARLY_EMPTY_AH))

    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="batteryfault", without=NO_RECORDER) as fleet:
        result, watch = fly(fleet, spec, scenario)

    drained = marks["drained"]
    told = [(t, e) for t, e in watch.events if e.vid == "cf1" and e.kind == "low_battery"]
    assert told, watch.kinds("cf1")
    t_told, event = told[0]
    assert 1.0 <= t_told - drained < 3.0  # 1 s under 3.3 V, telemetry at 5 Hz
    assert min(tel.vbat for tel in watch.telemetry["cf1"] if tel.t > drained) < 3.3
    assert not result.ok and "cf1: low_battery" in result.reason, result.reason
    assert_the_others_arrived(result, watch, "cf1")
    # it landed where it said: where its plan takes off or lands, nearest to where it was when told
    assert result.plan is not None
    candidates = landing_nodes(vehicle_plans(result.plan, result.mission)["cf1"].steps)
    at = min(watch.states["cf1"], key=lambda s: abs(s.t - t_told))
    nearest = min(candidates, key=lambda s: math.dist(s.pos[:2], (at.x, at.y))).node
    assert event.node == nearest, (event.node, nearest)
    # the world says it came down there: at rest on that node, motors off, softly
    gx, gy, gz = result.plan.graph.nodes[event.node].pos
    assert watch.at_rest_on("cf1", (gx, gy, gz), 0.05), (event.node, watch.truth["cf1"][-1])
    assert watch.landed_safely("cf1") == ""
    print(f"replanned in {', '.join(f'{1e3 * t:.0f} ms' for t in result.replans)}; low battery reported {t_told - drained:.2f} s after the drain; landed at {event.node}, "
          f"{100 * watch.distance_to('cf1', (gx, gy, gz)):.1f} cm from it in ground truth, "
          f"touchdown {watch.hardest_touchdown('cf1'):.2f} m/s; {watch.separation_line()}")
