"""Take-over in the closed loop: a second controller continues a vehicle mid-flight, mid-landing and
on the ground from the last state the first one published (executor failover, issue 6)."""

from __future__ import annotations

import math

import msgspec
import pytest

from common.bus.messages import FlightSetpoint, Pose
from common.crazyflie.thrust import thrust_command
from common.domain.vehicle_model import G, VehicleModel
from common.flight.modes import AIRBORNE, Mode
from services.executor.vehicle_controller import VehicleController
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.closed_loop import Mocap, MocapNoise, plan_for, reference_steps, run

pytestmark = pytest.mark.compute

MODEL = VehicleModel()
STEPS = reference_steps(MODEL)
T0 = 0.5
FLY = next(s.t for s in STEPS if s.edge == "fly")  # plan time of arrival at the end of the flight
LAND = next(s.t for s in STEPS if s.edge == "land")


def first_owner(seed: int):
    """The simulated car, its plan, its first controller and the motion capture."""
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    plan = plan_for("cf1", STEPS, MODEL, t0=T0)
    a = VehicleController("cf1", MODEL, owner="exec-a")
    a.on_pose(Pose(vid="cf1", t=0.0, x=sim.x, y=sim.y, z=sim.z, yaw=0.0))
    a.load(plan)
    return sim, plan, a, Mocap(MocapNoise(pos_std=0.001), seed=seed)


def handover(at: float, gap: float = 0.05):
    """Controller A until `at` (mission time), nobody for `gap` s, then B from A's last state."""
    sim, plan, a, mocap = first_owner(3)
    first = run(a, sim, T0 + at, mocap)
    a.tick(sim.t)
    last_state = a.state()
    sim.step(gap)  # the setpoint of the dead executor is held by the gateway meanwhile
    b = VehicleController("cf1", MODEL, owner="exec-b")
    b.load(plan)
    b.take_over(last_state, sim.t)
    second = run(b, sim, T0 + STEPS[-1].t + 2.0, mocap)
    return a, b, sim, first, second


@pytest.mark.parametrize("at", [FLY - 2.0, LAND - 0.8])
def test_take_over_in_the_air_continues_the_plan(at: float) -> None:
    a, b, sim, first, second = handover(at)
    assert first[-1].mode in AIRBORNE
    assert b.machine.history[0].reason == "taken over from exec-a"
    errors = [math.dist((r.truth.x, r.truth.y, r.truth.z), (r.ref.x, r.ref.y, r.ref.z)) for r in second if r.ref]
    assert max(errors) < 0.08
    assert b.mode == Mode.DONE and math.dist((sim.x, sim.y, sim.z), STEPS[-1].pos) < 0.05
    assert sim.last_impact_speed < 0.7  # a normal landing cuts the motors 2 cm up: ~0.52 m/s


def test_take_over_on_the_ground_drives_on() -> None:
    a, b, sim, first, second = handover(3.0)
    assert first[-1].mode == Mode.DRIVING
    assert Mode.TAKING_OFF in [r.mode for r in second]
    assert b.mode == Mode.DONE and math.dist((sim.x, sim.y, sim.z), STEPS[-1].pos) < 0.05


def test_take_over_during_a_fault_landing_lands_at_the_nearest_safe_point() -> None:
    sim, plan, a, mocap = first_owner(4)
    run(a, sim, T0 + FLY - 3.0, mocap)
    a.abort("test abort")
    run(a, sim, T0 + FLY - 2.5, mocap)
    a.tick(sim.t)
    state = a.state()
    assert state.mode == "landing"
    b = VehicleController("cf1", MODEL, owner="exec-b")
    b.load(plan)
    b.take_over(state, sim.t)
    run(b, sim, T0 + FLY + 10.0, mocap)
    assert b.mode == Mode.DONE and sim.z < 0.02 and sim.last_impact_speed < 0.7  # a normal landing cuts the motors 2 cm up: ~0.52 m/s


def test_unknown_mode_is_taken_as_parked() -> None:
    b = VehicleController("cf1", MODEL, owner="exec-b")
    b.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    fresh = VehicleController("cf1", MODEL)
    fresh.tick(0.0)
    state = fresh.state()
    b.take_over(msgspec.structs.replace(state, mode="warp"), 0.1)
    assert b.mode == Mode.PARKED


def test_take_over_after_a_partition_starts_from_the_latest_pose_at_rest() -> None:
    """The first owner's last state is a lease (here 1.2 s) old: meanwhile its last setpoint was held
    0.2 s, then the vehicle sank level (as under the gateway's safety landing). The new owner gets
    that state and the latest pose; fusing the pose after the state read the 0.3-0.5 m moved
    meanwhile as a velocity, and the chase of it threw the vehicle around (seen in a cross-host run:
    up to 1.5 m, down 1.5 m off the map)."""
    sim, plan, a, mocap = first_owner(5)
    run(a, sim, T0 + FLY - 1.2, mocap)
    a.tick(sim.t)
    last_state = a.state()
    assert last_state.mode == "flying"
    sim.step(0.2)  # the dead owner's last setpoint, held
    sim.apply(FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=thrust_command(0.9 * MODEL.mass * G)), sim.t)
    for _ in range(110):
        sim.step(0.01)
    latest = mocap.observe(sim.truth())
    assert latest is not None and math.dist((latest.x, latest.y, latest.z), (last_state.x, last_state.y, last_state.z)) > 0.15
    b = VehicleController("cf1", MODEL, owner="exec-b")
    b.load(plan)
    b.take_over(last_state, sim.t, latest)
    est = b.estimator.estimate(sim.t)
    assert math.dist((est.x, est.y, est.z), (sim.x, sim.y, sim.z)) < 0.01 and math.hypot(est.vx, est.vy, est.vz) < 0.05
    second = run(b, sim, T0 + STEPS[-1].t + 3.0, mocap)
    assert max(r.truth.z for r in second) < max(s.pos[2] for s in STEPS) + 0.15
    assert b.mode == Mode.DONE and math.dist((sim.x, sim.y, sim.z), STEPS[-1].pos) < 0.05


@pytest.mark.parametrize("at, held", [(FLY - 2.0, Mode.HOVERING), (3.0, Mode.HOLDING)])
def test_a_held_vehicle_taken_over_stays_held_where_it_is(at: float, held: Mode) -> None:
    """The first owner held its vehicle (the proximity stop, in flight and driving); the mission
    planned the others around it. The new owner keeps it there: it used to take up its old plan
    again, back into the others' space."""
    sim, plan, a, mocap = first_owner(6)
    run(a, sim, T0 + at, mocap)
    assert a.stop_short("a test's")
    run(a, sim, T0 + at + 1.0, mocap)
    a.tick(sim.t)
    state = a.state()
    assert state.mode == held and state.held == "a test's" and state.rejoinable
    here = (sim.x, sim.y, sim.z)
    b = VehicleController("cf1", MODEL, owner="exec-b")
    b.load(plan)
    b.take_over(state, sim.t)
    second = run(b, sim, T0 + STEPS[-1].t + 2.0, mocap)
    assert max(math.dist((r.truth.x, r.truth.y, r.truth.z), here) for r in second) < 0.05
    assert b.mode == held and b.state().held == "a test's" and b.holds == 1
