"""An attitude setpoint resent through its owner's silence goes out levelled after `level_s`
(`services/radio_gateway/vehicle.py`, FLIGHT): an attitude is the executor's command for one control
period, and a braking tilt resent for a stalled executor's 0.2 s swung a held flyer back."""

from __future__ import annotations

import math

import msgspec
import pytest

from common.bus.messages import FlightSetpoint
from common.crazyflie.thrust import thrust_command, thrust_newtons
from common.deploy.radios import GatewayParams
from common.domain.vehicle_model import VehicleModel
from services.radio_gateway.vehicle import HOVER_MARGIN, Drive, VehicleChannel
from tests.support.closed_loop import on_reference_plan, run
from tests.support.gateway_packets import decode

BRAKING = FlightSetpoint(roll=-4.0, pitch=-12.0, yawrate=10.0, thrust=47000)


def flying(params: GatewayParams | None = None) -> VehicleChannel:
    """A channel in flight, its thrust unlocked (the unlock's zero-thrust packets gone out)."""
    params = params or GatewayParams()
    ch = VehicleChannel("cf1", params, 0.0, wheels=False)
    ch.command(BRAKING, 0.0)
    for _ in range(params.stop_repeats):
        ch.flight_packet(0.0)
    return ch


def test_an_attitude_resent_past_level_s_goes_out_levelled_at_the_hover_thrust() -> None:
    ch = flying()
    assert decode(ch.flight_packet(0.01)[0]) == BRAKING
    assert decode(ch.flight_packet(0.05)[0]) == BRAKING  # within level_s: as the executor sent it
    levelled = decode(ch.flight_packet(0.06)[0])
    assert isinstance(levelled, FlightSetpoint)
    assert (levelled.roll, levelled.pitch, levelled.yawrate) == (0.0, 0.0, 0.0)
    lift = thrust_newtons(BRAKING.thrust) * math.cos(math.radians(4.0)) * math.cos(math.radians(12.0))
    assert thrust_newtons(levelled.thrust) == pytest.approx((1.0 - HOVER_MARGIN) * lift, rel=1e-3)  # the hover's
    assert decode(ch.flight_packet(0.15)[0]) == levelled and ch.mode == Drive.FLIGHT  # until stale_s
    ch.command(BRAKING, 0.16)  # a fresh command goes out as sent
    assert decode(ch.flight_packet(0.17)[0]) == BRAKING


def swing_back(params: GatewayParams, stall_s: float = 0.2) -> float:
    """A flyer at 0.3 m/s on its plan stops short; 20 ms later its executor goes silent for
    `stall_s` and the gateway resends its last setpoint; then the executor comes back. Its fastest
    speed back along the way it came (m/s, ground truth), from the stop on."""
    steps, sim, ctrl = on_reference_plan(VehicleModel(margin=0.03))
    a1, a2 = (next(s for s in steps if s.node == node) for node in ("a1", "a2"))
    records = run(ctrl, sim, 0.5 + (a1.t + a2.t) / 2)
    assert records[-1].truth.vx == pytest.approx(0.3, abs=0.02)
    assert ctrl.stop_short("stops short of cf9")
    records = run(ctrl, sim, sim.t + 0.02)
    ch = flying(params)
    ch.command(ctrl.tick(sim.t).setpoint, sim.t)  # the last command before the silence
    silent_until = sim.t + stall_s
    while sim.t < silent_until - 1e-9:
        sim.apply(decode(ch.flight_packet(sim.t)[0]), sim.t)
        records.append(type(records[0])(sim.t, sim.truth(), None, ctrl.mode))
        sim.step(0.01)
    assert ch.mode == Drive.FLIGHT
    records += run(ctrl, sim, sim.t + 1.0)
    return -min(r.truth.vx for r in records)


def test_a_held_flyer_whose_executor_falls_silent_does_not_swing_back() -> None:
    """Resent as it was (`level_s` past the silence), the hold's braking tilt swings the flyer back
    at more than 0.25 m/s; levelled, it comes back to its hold's point at its controller's pace."""
    assert swing_back(GatewayParams()) < 0.15
    assert swing_back(GatewayParams(level_s=0.5)) > 0.25


def climb(params: GatewayParams, stall_s: float = 0.2) -> float:
    """A flyer hovering on its plan, its executor's last command before a silence of `stall_s` a
    thrust 25 % over the hover (as in the soak: a sag's correction): how far it rises meanwhile (m,
    ground truth)."""
    steps, sim, ctrl = on_reference_plan(VehicleModel(margin=0.03))
    a2 = next(s for s in steps if s.node == "a2")
    run(ctrl, sim, 0.5 + a2.t + 0.5)
    hover = ctrl.tick(sim.t).setpoint
    assert isinstance(hover, FlightSetpoint)
    ch = flying(params)
    for _ in range(100):  # the owner's last second, hovering
        ch.command(hover, sim.t)
    ch.command(msgspec.structs.replace(hover, thrust=thrust_command(1.25 * thrust_newtons(hover.thrust))), sim.t)
    z0, silent_until = sim.truth().z, sim.t + stall_s
    while sim.t < silent_until - 1e-9:
        sim.apply(decode(ch.flight_packet(sim.t)[0]), sim.t)
        sim.step(0.01)
    return sim.truth().z - z0


def test_a_flyer_whose_executor_falls_silent_after_a_climbing_thrust_holds_its_level() -> None:
    """A soak's traced contact (docs/reliability.md): a climbing thrust resent through a stall took
    a flyer 17 cm over its level, and its executor, back, brought it down at 0.9 m/s onto the
    vehicle below. Levelled at the hover thrust after 50 ms it rises on what the climb gave it
    by then (1.8 cm in 0.2 s), resent as it was it goes on climbing (3.6 cm; 2.6 and 4.5 before its
    controller led its commands' actuation, `ACTUATION_S`)."""
    assert climb(GatewayParams()) < 0.025
    assert climb(GatewayParams(level_s=0.5)) > 0.03

