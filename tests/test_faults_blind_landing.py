"""The gateway's blind safety landing (no pose: the router, and with it the motion capture, is gone)
started at any moment of a flight (issue 8). It can only set a thrust, so it must start from the
hover thrust the owner had found: the last setpoint alone is up to 29 % off (the executor brakes the
end of a takeoff), and both ways are dangerous (a hard touchdown, or a climb until the motors stop
in the air). Closed loop without zenoh: the executor's controller flies the simulated vehicle
through the gateway's `VehicleChannel`, then falls silent; the channel lands it on its own."""

from __future__ import annotations

import contextlib

import pytest

from common.bus.messages import FlightSetpoint, Pose, Setpoint, StopSetpoint, WheelSetpoint
from common.deploy.radios import GatewayParams
from common.domain.vehicle_model import VehicleModel
from services.executor.vehicle_controller import VehicleController
from services.radio_gateway.vehicle import Refused, VehicleChannel
from services.sim.crazyflie.physics import PhysicsParams, SimFlyingCar
from tests.support.closed_loop import Mocap, MocapNoise, plan_for, reference_steps
from tests.support.gateway_packets import decode

pytestmark = pytest.mark.compute

MODEL = VehicleModel()
STEPS = reference_steps(MODEL)
T0 = 0.5
TAKEOFF_END = T0 + next(s.t for s in STEPS if s.edge == "takeoff")
DT = 0.01
PERTURBED = PhysicsParams(thrust_scale=0.95, mass_scale=1.04, tau_motor=0.04)


def blind_landing(silent_at: float, physics: PhysicsParams,
                  stray: Setpoint | None = None) -> tuple[SimFlyingCar, float, float]:
    """Fly the plan until `silent_at` (sim time), then only the gateway commands (one `stray`
    setpoint from the owner 1 s into its landing): the vehicle, the height when the commands
    stopped and the highest point after."""
    car = SimFlyingCar("cf1", MODEL, physics, pos=STEPS[0].pos, yaw=0.0)
    ctl = VehicleController("cf1", MODEL)
    ctl.on_pose(Pose(vid="cf1", t=0.0, x=0.0, y=0.0, z=0.0, yaw=0.0))
    ctl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    ch = VehicleChannel("cf1", GatewayParams(), 0.0)
    mocap = Mocap(MocapNoise(), seed=2)
    silent_z, top = 0.0, 0.0
    while car.t < silent_at + 15.0:
        now = car.t
        if now < silent_at:
            ctl.on_pose(mocap.observe(car.truth()))
            ch.command(ctl.tick(now).setpoint, now)
            silent_z = top = car.z
        elif stray is not None and now >= silent_at + 1.0:
            with contextlib.suppress(Refused):  # refused: the landing goes on
                ch.command(stray, now)
            stray = None
        top = max(top, car.z)
        ch.supervise(now)
        raw, _ = ch.flight_packet(now)
        if raw is not None:
            packet = decode(raw)
            car.apply(packet if isinstance(packet, FlightSetpoint) else StopSetpoint(), now)
        car.step(DT)
    return car, silent_z, top


@pytest.mark.parametrize("physics", [PhysicsParams(), PERTURBED], ids=["nominal", "perturbed"])
@pytest.mark.parametrize("after_takeoff_end", [-1.0, -0.2, 0.1, 0.5, 3.0])
def test_a_blind_safety_landing_from_any_moment_of_the_flight_touches_down_gently(
        after_takeoff_end: float, physics: PhysicsParams) -> None:
    car, silent_z, top = blind_landing(TAKEOFF_END + after_takeoff_end, physics)
    print(f"silent at {silent_z:.2f} m: highest {top:.2f} m, touchdown {car.last_impact_speed:.2f} m/s")
    assert silent_z > 0.2
    assert car.z == 0.0 and car.thrust < 1e-3  # down, motors off
    assert top < silent_z + 0.15  # a climbing vehicle coasts up a little, never away
    assert car.last_impact_speed < 0.7


@pytest.mark.parametrize("stray", [StopSetpoint(), WheelSetpoint(left=0.0, right=0.0)], ids=["stop", "wheels"])
def test_a_stop_or_wheel_command_does_not_end_the_safety_landing_in_the_air(stray: Setpoint) -> None:
    """An owner back from a lost router may believe its vehicle down (its blind descent is over):
    obeyed, its stop would cut the motors in the air and its wheel command end the flight setpoints."""
    car, silent_z, _ = blind_landing(TAKEOFF_END + 3.0, PhysicsParams(), stray)
    assert silent_z > 0.4 and car.z == 0.0 and car.last_impact_speed < 0.7
