"""Simulated flying car: send_setpoint conventions, commander watchdog, ground contact, differential
drive and the battery of eq. 4-5 / Table II."""

from __future__ import annotations

import math

import pytest

from common.bus.messages import FlightSetpoint, StopSetpoint, WheelSetpoint
from common.crazyflie.firmware import WATCHDOG_CUT_S, WATCHDOG_LEVEL_S
from common.crazyflie.thrust import WheelBase, hover_command
from common.domain.vehicle_model import G, VehicleModel
from services.sim.crazyflie.physics import (
    PhysicsParams,
    SimFlyingCar,
    open_circuit_voltage,
    unit_thrust,
)

MODEL = VehicleModel()
HOVER = hover_command(MODEL.mass)


def hovering(yaw: float = 0.0, z: float = 0.5) -> SimFlyingCar:
    sim = SimFlyingCar("cf1", MODEL, pos=(0.0, 0.0, z), yaw=yaw)
    sim.thrust = MODEL.mass * G  # motors already spun up
    return sim


def fly(sim: SimFlyingCar, sp: FlightSetpoint, seconds: float, rate: float = 100.0) -> None:
    for _ in range(round(seconds * rate)):
        sim.apply(sp, sim.t)
        sim.step(1.0 / rate)


def test_hover_command_holds_altitude() -> None:
    sim = hovering()
    fly(sim, FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=HOVER), 2.0)
    assert sim.z == pytest.approx(0.5, abs=0.005)
    assert sim.airborne


@pytest.mark.parametrize(("yaw", "roll", "pitch", "direction"), [
    (0.0, 0.0, 5.0, (1.0, 0.0)),  # positive pitch: nose down, forward
    (0.0, 5.0, 0.0, (0.0, -1.0)),  # positive roll: right side down, to the right (-y)
    (math.pi / 2, 0.0, 5.0, (0.0, 1.0)),  # forward is +y when facing +y
])
def test_send_setpoint_angle_conventions(yaw: float, roll: float, pitch: float,
                                         direction: tuple[float, float]) -> None:
    sim = hovering(yaw)
    fly(sim, FlightSetpoint(roll=roll, pitch=pitch, yawrate=0.0, thrust=HOVER), 0.4)
    moved = (sim.x, sim.y)
    assert math.hypot(*moved) > 0.02
    cos = (moved[0] * direction[0] + moved[1] * direction[1]) / math.hypot(*moved)
    assert cos > 0.99


def test_positive_yawrate_turns_clockwise() -> None:
    sim = hovering()
    fly(sim, FlightSetpoint(roll=0.0, pitch=0.0, yawrate=90.0, thrust=HOVER), 1.0)
    assert sim.yaw < -math.radians(60)  # clockwise seen from above: yaw decreases


def test_attitude_follows_a_first_order_lag() -> None:
    sim = hovering()
    fly(sim, FlightSetpoint(roll=10.0, pitch=0.0, yawrate=0.0, thrust=HOVER), sim.params.tau_roll_pitch)
    assert math.degrees(sim.roll) == pytest.approx(10.0 * (1 - math.exp(-1)), rel=0.05)


def test_watchdog_levels_after_half_a_second_then_cuts_the_motors() -> None:
    sim = hovering(z=1.0)
    fly(sim, FlightSetpoint(roll=10.0, pitch=0.0, yawrate=0.0, thrust=HOVER), 0.5)
    assert math.degrees(sim.roll) > 9.0
    last = sim.t - 0.01  # time of the last setpoint
    sim.step(last + WATCHDOG_LEVEL_S + 0.3 - sim.t)
    assert abs(math.degrees(sim.roll)) < 1.0  # levelled ...
    assert sim.flight_command()[3] == HOVER  # ... keeping the thrust
    sim.step(last + WATCHDOG_CUT_S - 0.02 - sim.t)
    assert sim.flight_command()[3] == HOVER and sim.airborne
    sim.step(0.04)
    assert sim.flight_command()[3] == 0  # motors cut after 2 s
    assert sim.z > 0.5
    while sim.airborne:
        sim.step(0.01)
    assert sim.last_impact_speed > 3.0  # it fell (free fall from > 0.5 m)


def test_stop_cuts_the_motors_at_once() -> None:
    sim = hovering()
    fly(sim, FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=HOVER), 0.1)
    sim.apply(StopSetpoint(), sim.t)
    sim.step(0.3)
    assert sim.vz < -1.0
    assert not sim.truth().motors


def test_ground_contact_liftoff_needs_more_thrust_than_weight() -> None:
    sim = SimFlyingCar("cf1", MODEL)
    fly(sim, FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=HOVER - 3000), 1.0)
    assert sim.z == 0.0 and not sim.airborne
    fly(sim, FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=HOVER + 3000), 1.0)
    assert sim.z > 0.05 and sim.airborne


def test_wheels_drive_straight_turn_in_place_and_respect_the_limit() -> None:
    wheels = WheelBase()
    sim = SimFlyingCar("cf1", MODEL)
    for _ in range(100):
        sim.apply(WheelSetpoint(left=0.1, right=0.1), sim.t)
        sim.step(0.01)
    assert sim.x == pytest.approx(0.1 - 0.1 * wheels.tau, abs=0.003)  # 1 s at 0.1 m/s after the lag
    assert sim.y == pytest.approx(0.0, abs=1e-9)
    yaw0 = sim.yaw
    for _ in range(50):
        sim.apply(WheelSetpoint(left=-0.05, right=0.05), sim.t)
        sim.step(0.01)
    turned = sim.yaw - yaw0
    assert turned == pytest.approx(2 * 0.05 / wheels.track * (0.5 - wheels.tau), rel=0.05)
    x = sim.x
    for _ in range(100):
        sim.apply(WheelSetpoint(left=1.0, right=1.0), sim.t)
        sim.step(0.01)
    assert math.hypot(sim.x - x, sim.y) < wheels.max_speed * 1.0 + 1e-9


def test_wheels_stop_when_setpoints_stop() -> None:
    sim = SimFlyingCar("cf1", MODEL)
    sim.apply(WheelSetpoint(left=0.1, right=0.1), 0.0)
    sim.step(2.0)
    x = sim.x
    assert x < 0.1 * (sim.params.wheel_watchdog_s + 0.1)
    sim.step(1.0)
    assert sim.x == pytest.approx(x, abs=1e-6)


def test_a_parked_vehicle_steps_at_once_as_in_substeps_and_moves_on_the_next_command() -> None:
    """A vehicle at rest is advanced in one step (the simulator's fast path): the same place,
    charge and voltage as through 2 ms sub-steps, after a drive that ran down under its watchdog."""
    fast, slow = SimFlyingCar("a", MODEL, yaw=0.3), SimFlyingCar("b", MODEL, yaw=0.3)
    for sim in (fast, slow):
        sim.apply(WheelSetpoint(left=0.1, right=0.12), 0.0)
        sim.step(3.0)  # driven until the wheel watchdog stopped it, then at rest
    fast.step(60.0)
    for _ in range(30000):
        slow.step(0.002)
    assert (fast.x, fast.y, fast.yaw, fast.z) == pytest.approx((slow.x, slow.y, slow.yaw, slow.z), abs=1e-9)
    assert fast.charge_used_ah == pytest.approx(slow.charge_used_ah, rel=1e-9)
    assert fast.battery.vbat == pytest.approx(slow.battery.vbat, abs=1e-9)
    fast.apply(WheelSetpoint(left=0.1, right=0.1), fast.t)
    fast.step(0.3)
    assert fast.wheel_left > 0.05
    fast.apply(FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=int(1.3 * HOVER)), fast.t)
    fast.step(0.3)
    assert fast.airborne and fast.z > 0.0


def test_hover_drains_fly_power_and_idle_drains_idle_power_via_eq_4_5() -> None:
    sim = hovering()
    fly(sim, FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=HOVER), 10.0)
    assert sim.charge_used_ah == pytest.approx(MODEL.charge_ah(MODEL.power.fly, 10.0), rel=0.02)
    parked = SimFlyingCar("cf2", MODEL)
    parked.step(10.0)
    assert parked.charge_used_ah == pytest.approx(MODEL.charge_ah(MODEL.power.idle, 10.0), rel=1e-6)


def test_driving_at_nominal_speed_drains_drive_power() -> None:
    sim = SimFlyingCar("cf1", MODEL)
    for _ in range(1000):
        sim.apply(WheelSetpoint(left=MODEL.speed.drive, right=MODEL.speed.drive), sim.t)
        sim.step(0.01)
    assert sim.charge_used_ah == pytest.approx(MODEL.charge_ah(MODEL.power.drive, 10.0), rel=0.02)


def test_voltage_sags_with_charge_used_and_under_load() -> None:
    full, used = SimFlyingCar("a", MODEL), SimFlyingCar("b", MODEL, charge_used_ah=0.8 * MODEL.capacity_ah)
    assert full.battery.vbat == pytest.approx(4.2 - MODEL.power.idle / MODEL.voltage * 0.15, abs=0.01)
    assert used.battery.vbat < full.battery.vbat - 0.3
    sim = hovering()
    fly(sim, FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=HOVER), 0.5)
    loaded = sim.battery
    assert loaded.vbat < open_circuit_voltage(loaded.soc) - 0.2  # ~2 A over 0.15 ohm
    assert sim.truth().vbat == loaded.vbat
    assert sim.truth().charge_used_ah == loaded.charge_used_ah


def test_mass_and_thrust_perturbations_change_the_hover_balance() -> None:
    heavy = SimFlyingCar("cf1", MODEL, PhysicsParams(mass_scale=1.1), pos=(0.0, 0.0, 0.5))
    heavy.thrust = MODEL.mass * G
    fly(heavy, FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=HOVER), 0.5)
    assert heavy.vz < -0.3


def test_units_differ_in_thrust_within_the_spread_each_the_same_every_run() -> None:
    """`fleet sim --thrust-spread`: each unit's thrust scale, fixed by its id, spread over the range."""
    scales = [unit_thrust(f"cf{i:02d}", 0.05) for i in range(1, 33)]
    assert all(0.95 <= s <= 1.05 for s in scales)
    assert min(scales) < 0.97 and max(scales) > 1.03  # spread over the range, not bunched
    assert scales == [unit_thrust(f"cf{i:02d}", 0.05) for i in range(1, 33)]
    assert unit_thrust("cf01", 0.0) == 1.0


def test_rejects_what_is_not_a_setpoint() -> None:
    with pytest.raises(TypeError):
        SimFlyingCar("cf1", MODEL).apply("up", 0.0)  # type: ignore[arg-type]
