"""Radio link loss (issues 8 and 16), injected into the simulated radio (every packet to and from one vehicle
lost for a while):

- at the gateway, with a stand-in executor hovering two vehicles: the simulated firmware levels the
  attitude 0.5 s into the silence and cuts the motors at 2 s (the vehicle falls and its supervisor
  locks: that is what a Crazyflie does); the gateway reports `link_lost` 1 s after the last log
  block (event and telemetry), `link_up` and `vehicle_locked` when the link is back, and reboots
  it (`rebooted`); the other vehicle flies on;
- in a mission, a 1.5 s loss while driving: the vehicle stops, is held as its plan moves on, and
  comes back into the mission once its link is back (`Replan.rejoin`); then a 1.5 s loss while
  cruising: levelled, no cut; the link is reported lost, the executor lands the vehicle at its
  nearest safe node once the link is back and the mission replans the others around it: every one
  of them arrives (ground truth, no contact);
- a vehicle that sank to the ground while its link was lost (the firmware kept a thrust below the
  hover) still gets a landing from its executor (it used to raise and take the executor down).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest
import zenoh

from common.bus.messages import PlanStep, SimFault
from common.bus.session import ZenohConfig
from common.bus.vehicle_plans import vehicle_plans
from common.deploy.radios import simulated_radios
from common.domain.vehicle_model import VehicleModel
from services.executor.faults import landing_nodes, safe_landing_steps
from services.executor.trajectory import Trajectory
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from services.radio_gateway.gateway import RadioGateway
from services.sim.crazyflie.service import SimService
from tests.support.fleet_faults import (
    NO_RECORDER,
    SAFE_TOUCHDOWN,
    TOWN_TASKS,
    Watch,
    assert_the_others_arrived,
    cruising,
    fly,
    until,
)
from tests.support.loadgen import LoadCommander, running


@pytest.mark.timeout(60)
def test_firmware_levels_at_half_a_second_cuts_at_two_and_the_gateway_reports_the_loss(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    cfg = ZenohConfig.client(zenoh_router)
    spec = simulated_radios({"cf0": (0.0, 0.0, 0.0), "cf1": (0.4, 0.0, 0.0)}, per_radio=2)
    sim, gw = SimService(spec, cfg), RadioGateway("r0", spec, cfg)
    cmd = LoadCommander("e1", cfg, flyers=["cf0", "cf1"])
    watch = Watch(sim.keys)

    async def main() -> dict[str, float]:
        watch.open(cfg)
        async with running(sim, gw, cmd):
            await until(lambda: all(v in sim.vehicles and sim.vehicles[v].car.z > 0.4 for v in ("cf0", "cf1")),
                        8.0, "both hovering")
            await until(lambda: "link_up" in watch.kinds("cf0"), 2.0, "cf0's link up")
            t = watch.inject(SimFault(vid="cf0", kind="radio_blackout", duration_s=2.5))
            kinds = ("sim_watchdog_level", "link_lost", "sim_watchdog_cut", "link_up", "vehicle_locked", "rebooted")
            await until(lambda: set(kinds) <= set(watch.kinds("cf0")), 6.0,
                        lambda: f"events {', '.join(k for k in kinds if k not in watch.kinds('cf0'))} of cf0 "
                                f"(has {[(round(at - t, 2), e.kind) for at, e in watch.events if e.vid == 'cf0']})")
            lost = [tel for tel in watch.telemetry["cf0"] if tel.t > t and not tel.link_ok]
            assert lost and all(tel.link_quality == 0.0 for tel in lost)
            await until(lambda: "link_up" in watch.kinds("cf0", since=watch.first("cf0", "rebooted", since=t)), 8.0,
                        lambda: f"cf0 reconnected after its reboot ({[(round(at - t, 2), e.kind, e.detail) for at, e in watch.events if e.vid == 'cf0' and at > t]})")
            return {kind: watch.first("cf0", kind, since=t) - t for kind in kinds}

    try:
        after = asyncio.run(main())
    finally:
        watch.close()
    print("s after the link went:", {k: round(v, 2) for k, v in after.items()})
    assert 0.45 <= after["sim_watchdog_level"] < 0.8
    assert 0.9 <= after["link_lost"] < 1.5  # 1 s after the last log block (10 Hz)
    assert 1.95 <= after["sim_watchdog_cut"] < 2.3  # the watchdog's timeout: free fall, then Locked
    assert 2.5 <= after["link_up"] < 3.5 and 2.5 <= after["vehicle_locked"] < 3.5  # back in range, locked
    assert after["rebooted"] < 5.0  # the gateway reboots it through the radio
    cf0, cf1 = sim.vehicles["cf0"], sim.vehicles["cf1"]
    assert cf0.watchdog_levels == 1 and cf0.watchdog_cuts == 1 and cf0.hardest_touchdown > 1.0  # it fell
    assert cf0.firmware.running and not cf0.firmware.supervisor.locked  # rebooted, flyable again
    assert cf1.watchdog_levels == 0 and cf1.car.z > 0.4 and "link_lost" not in watch.kinds("cf1")
    assert cf0.blacked_out > 0
    assert watch.truth["cf0"] and not watch.contacts, watch.separation_line()  # cf0 fell beside cf1, not onto it


@pytest.mark.flight
@pytest.mark.timeout(180)
def test_a_link_lost_mid_flight_lands_the_vehicle_and_one_lost_while_driving_comes_back(tmp_path) -> None:
    """Two losses of 1.5 s in one mission. cf3, driving: it stops, its plan moves on, it is held and
    the others are replanned around it; once its link is back and it stands still the mission
    brings it back (`Replan.rejoin`): its executor waits for its new reference, drives on and
    arrives. cf1, cruising: levelled by its firmware, not cut; its executor lands it at its
    nearest safe node once the link is back and the others are replanned around it. Every other
    vehicle arrives, no contact (ground truth). On the wall clock (`fleet executor --no-plan-clock`):
    the plan's clock would wait for cf3 stopped this briefly (`tests/test_plan_clock.py`), and this
    is the way back for a vehicle held by a fault that the clock does not absorb (one that kept it
    waiting 5 s)."""
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)
    marks: dict[str, float] = {}

    async def scenario(watch: Watch, runner: MissionRunner) -> None:
        await until(lambda: watch.mode("cf3") == "driving", 60, "cf3 driving")
        await asyncio.sleep(2.0)
        marks["drive_cut"] = watch.inject(SimFault(vid="cf3", kind="radio_blackout", duration_s=1.5))
        await cruising(watch, "cf1")
        marks["cut"] = watch.inject(SimFault(vid="cf1", kind="radio_blackout", duration_s=1.5))  # under the 2 s cut

    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="radiofault", without=NO_RECORDER,
                     extra_args={"executor": ["--no-plan-clock"]}) as fleet:
        result, watch = fly(fleet, spec, scenario)

    drive_cut = marks["drive_cut"]
    print("cf3 events after its cut:", [(round(t - drive_cut, 2), e.kind, e.detail) for t, e in watch.events
                                        if e.vid == "cf3" and t > drive_cut])
    held = [e for _, e in watch.events if e.vid == "cf3" and e.kind == "tracking_hold"]
    assert held and held[0].rejoinable and held[0].detail.startswith("its plan moved on"), held
    assert any(e.startswith("cf3 rejoined the mission") for e in result.events), result.events
    assert "cf3" not in result.reason, result.reason  # back in the mission: it arrived (below)
    cut = marks["cut"]
    kinds = watch.kinds("cf1", since=cut)
    print("cf1 events after the cut:", [(round(t - cut, 2), e.kind, e.detail) for t, e in watch.events if e.vid == "cf1" and t > cut])
    assert {"sim_watchdog_level", "link_lost", "link_up"} <= set(kinds)
    assert "sim_watchdog_cut" not in kinds and "vehicle_locked" not in kinds  # back in range before 2 s
    assert any(not tel.link_ok for tel in watch.telemetry["cf1"] if tel.t > cut)
    assert_the_others_arrived(result, watch, "cf1")
    # the executor's event names where it lands cf1: a node where cf1's plan takes off or lands ...
    told = [e for _, e in watch.events if e.vid == "cf1" and e.kind == "link_lost" and e.node]
    assert told, [(e.kind, e.detail) for _, e in watch.events if e.vid == "cf1"]
    node = told[0].node
    assert result.plan is not None
    ground = {s.node for s in landing_nodes(vehicle_plans(result.plan, result.mission)["cf1"].steps)}
    assert node in ground, (node, ground)
    # ... and the world says it came down there: at rest on that node, motors off
    pos = result.plan.graph.nodes[node].pos
    assert watch.at_rest_on("cf1", pos), (node, pos, watch.truth["cf1"][-1], round(watch.distance_to("cf1", pos), 3))
    assert watch.landed_safely("cf1") == ""
    for vid in TOWN_TASKS:
        assert watch.hardest_touchdown(vid) < SAFE_TOUCHDOWN, (vid, watch.hardest_touchdown(vid))
    print(f"replanned in {', '.join(f'{1e3 * t:.0f} ms' for t in result.replans)}; cf1 landed at {node} (its event's), {100 * watch.distance_to('cf1', pos):.1f} cm from it in ground "
          f"truth, touchdown {watch.hardest_touchdown('cf1'):.2f} m/s; {watch.separation_line()}")


def test_a_safe_landing_from_the_ground_is_still_a_trajectory() -> None:
    plan = [PlanStep(node="p", t=0.0, pos=(0.0, 0.0, 0.0), kind="parking"),
            PlanStep(node="a", t=5.0, pos=(1.0, 0.0, 0.4), kind="air", edge="fly")]
    for at in ((0.5, 0.0, 0.0), (0.0, 0.0, -0.001)):  # sank beside the node, or onto it
        steps = safe_landing_steps(at, 3.0, plan, VehicleModel())
        assert steps[-1].node == "p" and abs(Trajectory(steps).sample(steps[-1].t + 1.0).z) < 1e-9
