"""The gateway's safety landing against the simulated flying car, on simulated time: under position
control (noisy poses), after the poses stop, and blind; each ends on the ground, gently, motors off."""

from __future__ import annotations

import math
import random

import pytest

from common.bus.messages import FlightSetpoint, Pose, Setpoint, Telemetry
from common.crazyflie.thrust import hover_command
from common.deploy.radios import GatewayParams, LandingParams
from common.domain.vehicle_model import VehicleModel
from services.radio_gateway.landing import HandBack, OpenLoopDescent, SafeLanding
from services.sim.crazyflie.physics import PhysicsParams, SimFlyingCar
from tests.support.closed_loop import Mocap, on_reference_plan

DT = 0.01
HOVER = FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=hover_command(0.041))


def _hovering(z: float, params: PhysicsParams | None = None) -> SimFlyingCar:
    car = SimFlyingCar("v1", params=params or PhysicsParams(), pos=(0.3, -0.2, z), yaw=0.4)
    car.apply(HOVER, car.t)
    car.thrust = car.mass * 9.81  # settled in hover
    return car


def _land(car: SimFlyingCar, poses_until: float, last: FlightSetpoint | None = HOVER,
          params: LandingParams | None = None, limit: float = 12.0,
          poses_from: float = -math.inf, throw: tuple[float, float] | None = None) -> tuple[SafeLanding, float]:
    """Run the landing from the car's clock; poses (1 mm noise) are fed while poses_from <= t <
    poses_until; `throw`: (s into the landing, vz) the car is thrown up at. Returns the landing and
    the time the motors were stopped."""
    rng = random.Random(1)
    landing = SafeLanding(car.t, last, params or LandingParams(), DT)
    start = car.t
    while car.t < start + limit:
        t = car.t
        if throw is not None and t - start >= throw[0]:
            car.vz, throw = throw[1], None
        if poses_from <= t < poses_until:
            truth = car.truth()
            landing.on_pose(Pose(vid="v1", t=t, x=truth.x + rng.gauss(0, 0.001), y=truth.y + rng.gauss(0, 0.001),
                                 z=truth.z + rng.gauss(0, 0.001), yaw=truth.yaw), t)
        sp = landing.step(t)
        if sp is None:
            car.apply(FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=0), t)
            car.step(0.5)
            return landing, t - start
        car.apply(sp, t)
        car.step(DT)
    raise AssertionError("no touchdown")


@pytest.mark.parametrize("physics", [PhysicsParams(), PhysicsParams(mass_scale=1.1, thrust_scale=0.95)])
def test_position_controlled_landing_is_gentle_and_holds_position(physics: PhysicsParams) -> None:
    car = _hovering(0.6, physics)
    landing, took = _land(car, poses_until=math.inf)
    assert landing.closed_loop
    assert car.z == 0.0 and not car.airborne and car.thrust < 1e-3
    assert car.last_impact_speed < 0.35
    assert math.hypot(car.x - 0.3, car.y + 0.2) < 0.05
    assert took == pytest.approx(0.5 + 0.6 / 0.2, abs=1.0)


def test_a_vehicle_thrown_up_near_the_ground_descends_afresh_and_touches_down_gently() -> None:
    """Near the ground, its descent's reference already on the floor, the vehicle is thrown up at
    2 m/s (it bounced off the ground on late poses, in a soak): it descends again from where it is
    instead of diving at the flight controller's full 0.5 g (2.15 m/s at touchdown in that soak)."""
    car = _hovering(0.3)
    landing, _took = _land(car, poses_until=math.inf, throw=(1.9, 2.0))
    assert landing.closed_loop
    assert car.z == 0.0 and not car.airborne
    assert car.last_impact_speed < 0.7, car.last_impact_speed


def test_open_loop_when_the_poses_stop_mid_descent() -> None:
    car = _hovering(0.8)
    start = car.t
    landing, _took = _land(car, poses_until=start + 1.5)
    assert landing.closed_loop  # it began under position control
    assert car.z == 0.0 and car.thrust < 1e-3 and car.last_impact_speed < 0.35


def test_blind_landing_without_any_pose() -> None:
    car = _hovering(0.5)
    landing, took = _land(car, poses_until=-math.inf, params=LandingParams(blind_height=0.8))
    assert not landing.closed_loop
    assert car.z == 0.0 and car.thrust < 1e-3 and car.last_impact_speed < 0.35
    assert took == pytest.approx(0.5 + OpenLoopDescent(0.8, 0.2, 1.0).duration, abs=0.05)


def test_poses_back_during_a_blind_descent_that_climbs_land_it_in_place() -> None:
    """The 32-vehicle soak on a loaded machine: the executor's commands went stale as its vehicle
    touched down, while no pose reached the gateway; its blind descent assumed `blind_height` and
    a hover thrust 15 % high (the executor's last setpoints braked the touchdown), so it climbed.
    The poses that come back 1 s later bring the position control back, from where it is: it lands
    gently. (The blind descent used to run to its end, motors off 12 m up: a fall at 14 m/s.)"""
    high = FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=hover_command(1.15 * 0.041))
    car = SimFlyingCar("v1", params=PhysicsParams(), pos=(0.3, -0.2, 0.0), yaw=0.4)
    car.apply(high, car.t)
    landing, _took = _land(car, poses_until=math.inf, poses_from=car.t + 1.0, last=high, limit=20.0)
    assert landing.closed_loop
    assert car.z == 0.0 and car.thrust < 1e-3 and car.last_impact_speed < 0.35, car.last_impact_speed


def test_open_loop_descent_profile() -> None:
    d = OpenLoopDescent(height=1.0, speed=0.2, accel=1.0)
    assert d.accel_at(0.0) == -1.0 and d.accel_at(1.0) == 0.0 and d.speed_at(0.1) == pytest.approx(0.1)
    assert d.touchdown == pytest.approx(0.2 + (1.0 - 0.02) / 0.2)  # a ramp of 0.02 m, then the coast
    assert d.accel_at(d.touchdown + 0.1) == 0.0 and d.accel_at(d.duration) is None
    fast = OpenLoopDescent(height=1.0, speed=0.2, accel=1.0, v0=0.5)  # already falling faster
    assert fast.accel_at(0.0) == 1.0 and fast.accel_at(0.35) == 0.0 and fast.speed_at(0.15) == pytest.approx(0.35)


@pytest.mark.parametrize("steadily", [True, False])
def test_an_executor_starved_in_bursts_gets_its_vehicle_back_only_once_its_commands_come_steadily(
        steadily: bool) -> None:
    """A flyer's executor, in its level flight, runs 40 ms at a time between 0.25 s silences (a
    saturated machine) for 4 s; its gateway takes the vehicle over after `stale_s` without commands
    (`SafeLanding`) and gives it back once the commands have come for `resume_s` (`HandBack`). Given
    back to each burst (`resume_s` 0: at once, as before), the vehicle flew on the executor's
    estimate carried over the silence on commands that never acted, between landings started
    afresh: thrown about at over 1 m/s (1.7). Held until the commands come steadily, it is landed
    by its gateway, never faster than 0.5 m/s (0.36)."""
    params = GatewayParams()
    resume_s = params.resume_s if steadily else 0.0
    model = VehicleModel(margin=0.05)
    steps, car, ctrl = on_reference_plan(model)
    mocap = Mocap(seed=1)
    start = 0.5 + next(s.t for s in steps if s.node == "a1") + 0.5
    setpoint: Setpoint | None = None
    landing: SafeLanding | None = None
    hand_back = HandBack(resume_s, params.stale_s / 2)
    cmd_at, top, k = -math.inf, 0.0, 0
    while car.t < start + 4.0:
        now = car.t
        truth = car.truth()
        pose = mocap.observe(truth)
        command = None
        if now < start or (now - start) % 0.29 >= 0.25:  # the executor's loop runs
            if k % 10 == 0:
                ctrl.on_telemetry(Telemetry(vid=car.vid, t=now, gateway="sim", vbat=car.battery.vbat,
                                            link_quality=1.0, sent=k, dropped=0, cmd_rate_hz=100.0), now)
            if pose is not None:
                ctrl.on_pose(pose)
            command = ctrl.tick(now).setpoint
        if command is not None and (landing is None or hand_back.command(now)):
            landing, setpoint, cmd_at = None, command, now
        elif command is not None:
            cmd_at = now
        elif landing is None and now - cmd_at > params.stale_s:
            landing, hand_back = SafeLanding(now, setpoint, params.landing, DT), HandBack(resume_s, params.stale_s / 2)
        if landing is not None:
            if pose is not None:
                landing.on_pose(pose, now)
            setpoint = landing.step(now) or FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=0)
        assert setpoint is not None
        car.apply(setpoint, now)
        if now >= start:
            top = max(top, math.hypot(truth.vx, truth.vy, truth.vz))
        car.step(DT)
        k += 1
    if steadily:
        assert top < 0.5 and not car.airborne, (top, car.z)
    else:
        assert top > 1.0, top
