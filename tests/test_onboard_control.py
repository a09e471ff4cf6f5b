"""Onboard control mode (issue 17, DESIGN.md "Vehicles"), without zenoh: the full-state setpoint on
the wire, external pose into the simulated firmware's Kalman estimator, the executor flying the
town-like path through the simulated firmware (no attitude setpoints), a fault landing and an
emergency descent without motion capture, and the gateway's schedule (poses streamed within the
radio's budget, wheel commands still serialised, attitude setpoints refused, its safety landing by
position setpoints)."""

from __future__ import annotations

import math
from collections import Counter

import pytest
from cflib.crazyflie.commander import Commander

from common.bus.messages import FlightSetpoint, Pose, PositionSetpoint, WheelSetpoint
from common.crazyflie import crtp
from common.deploy.radios import ONBOARD_PARAMS, GatewayParams, VehicleLink
from common.flight.modes import AIRBORNE, Mode
from services.executor.vehicle_controller import VehicleController
from services.radio_gateway.scheduler import Scheduler
from services.radio_gateway.vehicle import Drive, Refused, VehicleChannel
from services.sim.crazyflie.firmware.onboard import KALMAN, MELLINGER
from services.sim.crazyflie.firmware.system import CrazyflieFirmware
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.closed_loop import Mocap, MocapNoise, Record, plan_for, run
from tests.support.gateway_packets import decode
from tests.support.onboard_loop import FirmwareCar
from tests.test_closed_loop import MODEL, NOISE, PERTURBED, STEPS, T0, TAKEOFF, abort_at

pytestmark = pytest.mark.compute


def fly_onboard(noise: MocapNoise = NOISE, dropouts: tuple[tuple[float, float], ...] = (), hook=None,
                until: float | None = None) -> tuple[VehicleController, FirmwareCar, list[Record]]:
    """The reference path in onboard mode through the simulated firmware; `dropouts` cut the
    streamed external poses too (the motion capture is one system)."""
    car = SimFlyingCar("cf1", MODEL, PERTURBED, pos=STEPS[0].pos, yaw=0.0)
    sim = FirmwareCar(car, dropouts=dropouts)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.on_pose(Pose(vid="cf1", t=0.0, x=car.x, y=car.y, z=car.z, yaw=car.yaw))
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    records = run(ctrl, sim, until if until is not None else T0 + STEPS[-1].t + 2.0, Mocap(noise, seed=7),
                  on_tick=None if hook is None else lambda now: hook(ctrl, now), control="onboard")
    return ctrl, sim, records


@pytest.fixture(scope="module")
def mission() -> tuple[VehicleController, FirmwareCar, list[Record]]:
    return fly_onboard()


def _error(r: Record) -> float:
    assert r.ref is not None
    return math.dist((r.truth.x, r.truth.y, r.truth.z), (r.ref.x, r.ref.y, r.ref.z))


# ---- the wire and the firmware model --------------------------------------------------------------

@pytest.mark.parametrize("sp", [PositionSetpoint(x=1.234, y=-0.5, z=0.5, vx=0.3, vy=-0.1, vz=0.2, ax=1.0, ay=-2.0,
                                                 az=0.5, yaw=2.5),
                                PositionSetpoint(x=0.0, y=0.0, z=0.0, yaw=-math.pi / 2)])
def test_full_state_setpoint_is_cflibs_and_the_firmware_reads_it(sp: PositionSetpoint) -> None:
    sent: list[bytes] = []

    class Cf:
        def send_packet(self, pk) -> None:
            sent.append(bytes((pk.header,)) + bytes(pk.data))

    half = 0.5 * sp.yaw
    Commander(Cf()).send_full_state_setpoint((sp.x, sp.y, sp.z), (sp.vx, sp.vy, sp.vz), (sp.ax, sp.ay, sp.az),
                                             (0.0, 0.0, math.sin(half), math.cos(half)), 0.0, 0.0, 0.0)
    assert crtp.encode_full_state(sp) == sent[0]
    read = decode(sent[0])
    assert read.kind == "position" and read.pos == pytest.approx((sp.x, sp.y, sp.z), abs=1e-3)
    assert read.vel == pytest.approx((sp.vx, sp.vy, sp.vz), abs=1e-3)
    assert read.acc == pytest.approx((sp.ax, sp.ay, sp.az), abs=1e-3)
    assert math.remainder(read.yaw - sp.yaw, 2 * math.pi) == pytest.approx(0.0, abs=0.01)


def test_ext_pose_packets_reach_the_kalman_estimator_and_no_longer_after_they_stop() -> None:
    car = SimFlyingCar("cf1", MODEL, pos=(1.0, 2.0, 0.0))
    fw = CrazyflieFirmware(car, wheels=False)
    fw.receive(crtp.encode_ext_pose(1.0, 2.0, 0.0, 0.0), car.t)
    assert fw.estimator.ext_count == 0  # the complementary filter (the default) ignores it
    for name, value in ONBOARD_PARAMS.items():
        fw.params.set(name, value)
    assert (fw.estimator.kind, fw.controller.kind) == (KALMAN, MELLINGER)
    fw.params.set("kalman.resetEstimation", 1)
    assert fw.estimator.variance(0) == pytest.approx(100.0**2)  # stdDevInitialPosition_xy
    t = car.t
    for _ in range(50):  # 0.5 s of poses 3 cm off the truth: the estimate moves to them
        t += 0.01
        car.step(0.01)
        fw.receive(crtp.encode_ext_pose(1.03, 2.0, 0.0, 0.0), t)
        fw.tick(t)
    assert fw.estimator.ext_count == 50 and fw.estimator.ext_pos == pytest.approx((1.03, 2.0, 0.0))
    assert fw._state().pos[0] == pytest.approx(1.03, abs=0.005)
    fused = fw.estimator.variance(0)
    assert fused < 0.01**2  # locSrv.extPosStdDev
    for _ in range(100):  # a second without: the estimate's variance grows
        t += 0.01
        car.step(0.01)
        fw.tick(t)
    assert fw.estimator.variance(0) > 10 * fused


# ---- the executor through the simulated firmware ---------------------------------------------------

def test_onboard_mode_flies_the_path_with_position_setpoints_only(mission) -> None:
    ctrl, sim, records = mission
    assert sim.kinds == {"PositionSetpoint", "WheelSetpoint", "StopSetpoint"}  # never an attitude setpoint
    assert sim.firmware.estimator.ext_count > 2000  # the poses reached its estimator
    air = [_error(r) for r in records if r.ref is not None and r.mode in AIRBORNE and r.t > T0 + TAKEOFF - 2.0]
    ground = [_error(r) for r in records if r.ref is not None and r.mode == Mode.DRIVING]
    assert math.sqrt(sum(e * e for e in air) / len(air)) <= 0.05
    assert max(air) <= 0.08
    assert math.sqrt(sum(e * e for e in ground) / len(ground)) <= 0.03  # driving is unchanged
    modes = [m for i, m in enumerate(r.mode for r in records) if i == 0 or records[i - 1].mode != m]
    assert modes == [Mode.PARKED, Mode.DRIVING, Mode.TAKING_OFF, Mode.FLYING, Mode.LANDING, Mode.DRIVING, Mode.DONE]
    assert sim.car.last_impact_speed <= 0.35
    assert math.dist((sim.car.x, sim.car.y), STEPS[-1].pos[:2]) <= 0.05
    assert sim.firmware.locks == 0


def test_a_fault_landing_in_onboard_mode_lands_at_the_nearest_ground_node() -> None:
    ctrl, sim, records = fly_onboard(hook=abort_at(T0 + TAKEOFF + 1.5), until=T0 + TAKEOFF + 12.0)
    assert ctrl.mode == Mode.DONE
    assert Mode.LANDING in {r.mode for r in records}
    car = sim.car
    assert not car.airborne and car.z < 0.01 and sim.firmware.motor_command == 0
    ground = [s.pos for s in STEPS if s.kind != "air"]
    assert min(math.dist((car.x, car.y), p[:2]) for p in ground) <= 0.05
    assert car.last_impact_speed <= 0.35
    assert sim.kinds <= {"PositionSetpoint", "WheelSetpoint", "StopSetpoint"}


def test_emergency_descent_without_motion_capture_in_onboard_mode_lands_gently() -> None:
    """Poses stop for good in the air: neither the executor nor the vehicle's estimator gets any.
    The executor descends its dead-reckoned state as position setpoints; the vehicle's controller
    follows them on its IMU-only estimate; the motors stop after the predicted touchdown."""
    lost = T0 + TAKEOFF + 2.0
    noise = MocapNoise(pos_std=0.001, dropouts=((lost, 1e9),))
    ctrl, sim, records = fly_onboard(noise, dropouts=((lost, 1e9),), until=lost + 8.0)
    assert Mode.EMERGENCY_LANDING in {r.mode for r in records}
    assert ctrl.mode == Mode.DONE
    car = sim.car
    assert not car.airborne and sim.firmware.motor_command == 0
    assert car.last_impact_speed <= 0.35
    at_loss = next(r.truth for r in records if r.t >= lost)
    assert math.dist((car.x, car.y), (at_loss.x, at_loss.y)) <= 0.3  # braked, drifted little
    assert sim.kinds <= {"PositionSetpoint", "WheelSetpoint", "StopSetpoint"}


# ---- the gateway ---------------------------------------------------------------------------------

TICK = 0.01


def _pose(vid: str, t: float) -> Pose:
    return Pose(vid=vid, t=t, x=1.0, y=2.0, z=0.5, yaw=0.3)


def _channels(onboard: int, drivers: int, params: GatewayParams) -> list[VehicleChannel]:
    chans = [VehicleChannel(f"o{i}", params, 0.0, onboard=True) for i in range(onboard)]
    return chans + [VehicleChannel(f"d{i}", params, 0.0) for i in range(drivers)]


def test_the_radios_file_sets_onboard_parameters_and_refuses_onboard_without_flight() -> None:
    link = VehicleLink(uri="udp://127.0.0.1:1", control="onboard", params={"ctrlMel.mass": 0.05})
    assert link.firmware_params({"locSrv.extPosStdDev": 0.001}, 0.041) == {
        "locSrv.extPosStdDev": 0.001, "stabilizer.estimator": 2, "stabilizer.controller": 2, "ctrlMel.mass": 0.05}
    assert VehicleLink(uri="udp://127.0.0.1:1").firmware_params({}, 0.041) == {}


def test_gateway_streams_poses_within_the_budget_and_keeps_the_driving_switch() -> None:
    """Four onboard vehicles flying and two driving on one radio: each onboard vehicle gets its
    poses and setpoints at the same share, the packets per second stay within the budget, the
    wheel commands keep their switch's pace, and no attitude setpoint goes out."""
    params = GatewayParams()
    chans = _channels(4, 2, params)
    sched = Scheduler(chans, 480.0, params, 0.0)
    sent: dict[str, list] = {ch.vid: [] for ch in chans}
    now, total = 0.0, 0
    while now < 3.0 - 1e-9:
        now += TICK
        for ch in chans:
            if round(now / TICK) % 10 == 0:
                ch.health.on_log({"pm.vbatMV": 3900, "supervisor.info": 0x021E}, now)
            if ch.onboard:
                ch.on_pose(_pose(ch.vid, now), now)
                ch.command(PositionSetpoint(x=1.0, y=2.0, z=0.5), now)
            else:
                ch.command(WheelSetpoint(left=0.05, right=0.05), now)
            ch.supervise(now)
        batch, _ = sched.tick(now)
        total += len(batch)
        for vid, raw in batch:
            sent[vid].append(decode(raw))
    assert total <= 480.0 * 3.0 + 2 * 480.0 / params.tick_hz  # the budget (its bucket holds two ticks)
    for i in range(4):
        kinds = Counter(type(p).__name__ for p in sent[f"o{i}"])
        assert kinds["FlightSetpoint"] == 0
        assert kinds["ExtPose"] >= 150 and kinds["Setpoint"] >= 150  # about 60 Hz each, shared equally
    for i in range(2):
        assert 29 <= Counter(type(p).__name__ for p in sent[f"d{i}"])["Wheels"] <= 31  # unchanged: every 0.1 s


def test_onboard_vehicle_refuses_attitude_and_lands_by_position_setpoints_when_commands_stop() -> None:
    params = GatewayParams()
    ch = VehicleChannel("o0", params, 0.0, onboard=True)
    off = VehicleChannel("f0", params, 0.0)
    with pytest.raises(Refused) as refused:
        ch.command(FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=48000), 0.0)
    assert refused.value.reason == "attitude_onboard"
    with pytest.raises(Refused):
        off.command(PositionSetpoint(x=0.0, y=0.0, z=0.5), 0.0)
    sched = Scheduler([ch], 500.0, params, 0.0)
    now, packets, events = 0.0, [], []
    while now < 6.0:
        now += TICK
        if round(now / TICK) % 10 == 0:
            ch.health.on_log({"pm.vbatMV": 3900, "supervisor.info": 0x021E}, now)
        if now < 1.0:
            ch.command(PositionSetpoint(x=1.0, y=2.0, z=0.5), now)  # then the executor goes silent
        if now < 1.1:  # poses until it goes stale, then none: the landing ends on its predicted time
            ch.on_pose(_pose("o0", now), now)
        events += ch.supervise(now)
        batch, _ = sched.tick(now)
        packets += [(now, decode(raw)) for _vid, raw in batch]
    assert [k for k, _d in events][:1] == ["stale_cmd_landing"]
    landing = [(t, p) for t, p in packets if t > 1.25 and getattr(p, "kind", "") == "position"]
    zs = [p.pos[2] for _t, p in landing]
    assert zs[0] == pytest.approx(0.5, abs=0.01) and min(zs) == pytest.approx(-2 * params.landing.touchdown_height)
    assert all(p.pos[:2] == pytest.approx((1.0, 2.0)) for _t, p in landing)
    assert not any(isinstance(p, FlightSetpoint) for _t, p in packets)
    assert ch.mode in (Drive.STOPPING, Drive.IDLE) and any(isinstance(p, crtp.Stop) for _t, p in packets)
