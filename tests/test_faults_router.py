"""The zenoh router restarted mid-mission (issue 8). Every command, pose and token crosses the router,
so while it is down the gateways take over the flying vehicles (stale commands: they land them) and
the executors' poses go stale. Decided behaviour: the mission aborts cleanly. Every vehicle ends on
the ground, motors off, without contact or a hard touchdown; no vehicle resumes its plan after the
outage; every service reconnects (its token is back) and the executors own the vehicles again."""

from __future__ import annotations

import asyncio
import time

import pytest

from common.bus.messages import Pose
from common.bus.session import InProcessRouter
from common.crazyflie.thrust import thrust_command, to_flight_setpoint
from common.deploy.launcher import stop as stop_services
from common.domain.vehicle_model import G, VehicleModel
from common.flight.modes import Mode
from services.executor.vehicle_controller import VehicleController
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.alive import wait_for_services
from tests.support.closed_loop import Mocap, MocapNoise, plan_for, reference_steps, run
from tests.support.fleet_faults import TOWN_TASKS, Watch, airborne, fly, until

DOWN_S = 0.5
BLIND_TOUCHDOWN = 1.0
"""m/s: without poses the gateways land open loop, a little under the hover thrust so that they
never climb: harder than a landing under position control (about 0.5 m/s, the motors stop 2 cm
up), far from a fall from cruise height (2.8 m/s from 0.4 m)."""


@pytest.mark.flight
@pytest.mark.timeout(180)
def test_router_restart_mid_flight_aborts_the_mission_cleanly(tmp_path) -> None:
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)
    marks: dict[str, float] = {}
    restarted: list[InProcessRouter] = []

    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="routerfault",
                     router_in_process=True) as fleet:
        async def scenario(watch: Watch, runner: MissionRunner) -> None:
            await until(lambda: watch.mode("cf1") == "flying" and watch.mode("cf2") == "flying", 60, "both flying")
            await until(airborne(watch, "cf1"), 5, "cf1 at cruise height")
            marks["down"] = time.time()
            fleet.router.close()
            await asyncio.sleep(DOWN_S)
            restarted.append(InProcessRouter(fleet.router.endpoint, **fleet.credentials.router_options()))
            marks["up"] = time.time()

        try:
            result, watch = fly(fleet, spec, scenario)
            counts = {"planner": 1, "executor": 2, "gateway": -(-len(TOWN_TASKS) // 2), "sim": 1, "mocap": 1,
                      "telemetry": 1}
            assert asyncio.run(wait_for_services(fleet.client_config(), fleet.keys, counts, 10.0)) == []
        finally:
            stop_services(fleet.run_dir)  # while the new router still serves them: a clean stop
            for router in restarted:
                router.close()

    down, up = marks["down"], marks["up"]
    back = min(s.t for states in watch.states.values() for s in states if s.t > up)
    print(f"router down {up - down:.2f} s, states flow again {back - down:.2f} s after it went; touchdowns (m/s): "
          f"{ {vid: round(watch.hardest_touchdown(vid), 2) for vid in TOWN_TASKS} }")
    assert not result.ok and any(why in result.reason for why in ("lost contact", "in emergency landing", "lost its router")), result.reason
    assert result.contacts == 0 and not watch.contacts, (watch.separation_line(), watch.contacts[:5])
    assert watch.stats["sim"].figures["watchdog_cuts"] == 0  # no motors cut in the air
    for vid in TOWN_TASKS:  # every vehicle is faulted here: each came down safely, in ground truth
        assert watch.landed_safely(vid, touchdown=BLIND_TOUCHDOWN) == ""
        after = [s.mode for s in watch.states[vid] if s.t > up]
        assert after and not {"driving", "taking_off", "flying"} & set(after), (vid, after)  # no plan resumed
        owners = {s.owner for s in watch.states[vid]}
        assert len(owners) == 1, (vid, owners)  # nobody grabbed it while the tokens were gone


def test_a_blind_descent_whose_commands_were_lost_waits_for_the_vehicle_to_rest() -> None:
    """Closed loop without zenoh: cruising, the executor loses its router for 5 s (no poses in, no
    commands out; a gateway keeps the vehicle hovering meanwhile). Its blind descent predicted a
    touchdown long ago, but the poses that come back show the vehicle still in the air: the motors
    stop only once it rests on the ground (they used to stop at once: a fall from cruise height)."""
    model = VehicleModel()
    steps = reference_steps(model)
    t0 = 0.5
    sim = SimFlyingCar("cf1", model, pos=steps[0].pos, yaw=0.0)
    ctl = VehicleController("cf1", model)
    ctl.on_pose(Pose(vid="cf1", t=0.0, x=0.0, y=0.0, z=0.0, yaw=0.0))
    ctl.load(plan_for("cf1", steps, model, t0=t0))
    mocap = Mocap(MocapNoise(), seed=5)
    run(ctl, sim, t0 + next(s.t for s in steps if s.edge == "fly") - 2.0, mocap)
    hover = to_flight_setpoint(0.0, 0.0, 0.0, thrust_command(model.mass * G))  # the gateway holds it up
    back = sim.t + 5.0
    while sim.t < back:
        ctl.tick(sim.t)  # blind, and nobody hears it
        sim.apply(hover, sim.t)
        sim.step(0.01)
    assert ctl.mode == Mode.EMERGENCY_LANDING and sim.z > 0.4
    run(ctl, sim, sim.t + 6.0, mocap)
    assert ctl.mode == Mode.DONE and sim.z == 0.0 and sim.last_impact_speed < 0.7
