"""Closed loop without zenoh: VehicleController + simulated flying car + noisy 100 Hz mocap along a
town-like path (park, drive, take off, fly, land, drive, park), and the fault reactions.

Acceptance (issue 4): RMS tracking error <= 3 cm on the ground and <= 5 cm in the air, every node
reached within 0.5 s of its plan time, the mode sequence of the path's edge kinds, battery drain
within 10 % of eq. 4-5's prediction.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import pytest

import common.flight.estimator as estimator_module
from common.bus.messages import PlanStep, Pose, Telemetry
from common.domain.vehicle_model import VehicleModel
from common.flight.estimator import LIFT_ERROR_MAX
from common.flight.modes import AIRBORNE, Mode
from services.executor.faults import FaultMonitor
from services.executor.vehicle_controller import ACTUATION_S, ControlParams, VehicleController
from services.planner.sipp.turns import turn_time
from services.sim.crazyflie.physics import PhysicsParams, SimFlyingCar
from tests.support.closed_loop import Mocap, MocapNoise, Record, plan_for, reference_steps, run

pytestmark = pytest.mark.compute

MODEL = VehicleModel()
STEPS = reference_steps(MODEL)
T0 = 0.5  # mission start on the simulator's clock
TAKEOFF = next(s.t for s in STEPS if s.edge == "takeoff")  # arrival at the air node, plan time
# the simulated vehicle is not the nominal one the controllers were designed on
PERTURBED = PhysicsParams(thrust_scale=0.95, mass_scale=1.04, tau_roll_pitch=0.12, tau_yaw_rate=0.18,
                          tau_motor=0.04)
NOISE = MocapNoise(pos_std=0.001, outlier_rate=0.005, dropouts=((T0 + 6.0, T0 + 6.15), (T0 + 17.0, T0 + 17.15)))


Hook = Callable[[VehicleController, float], None]


def fly_plan(steps: Sequence[PlanStep] = STEPS, params: PhysicsParams = PERTURBED, noise: MocapNoise = NOISE,
             until: float | None = None, charge_used_ah: float = 0.0, hook: Hook | None = None,
             telemetry_every: int = 10, bodies: Sequence[tuple[float, float, float]] = (),
             ) -> tuple[VehicleController, SimFlyingCar, list[Record]]:
    """Fly `steps` from T0; `hook(controller, now)` runs before every tick (fault injection);
    `bodies`: where other vehicles stand (as the executor would tell the controller)."""
    sim = SimFlyingCar("cf1", MODEL, params, pos=steps[0].pos, yaw=0.0, charge_used_ah=charge_used_ah)
    ctrl = VehicleController("cf1", MODEL, owner="test", bodies=lambda: bodies)
    ctrl.on_pose(Pose(vid="cf1", t=0.0, x=sim.x, y=sim.y, z=sim.z, yaw=sim.yaw))
    ctrl.load(plan_for("cf1", steps, MODEL, t0=T0))
    records = run(ctrl, sim, until if until is not None else T0 + steps[-1].t + 2.0, Mocap(noise, seed=7),
                  telemetry_every=telemetry_every, on_tick=None if hook is None else lambda now: hook(ctrl, now))
    return ctrl, sim, records


def abort_at(when: float) -> Hook:
    def hook(ctrl: VehicleController, now: float) -> None:
        if now >= when:
            ctrl.abort("abort")
    return hook


def rms(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


def position(r: Record) -> tuple[float, float, float]:
    return (r.truth.x, r.truth.y, r.truth.z)


def predicted_charge(steps: Sequence[PlanStep]) -> float:
    """Eq. 4-5 over the plan: each traversal at its mode's power, each wait at idle or hover power."""
    total = 0.0
    for a, b in zip(steps, steps[1:], strict=False):
        if a.node == b.node:
            total += MODEL.wait_charge(b.t - a.t, airborne=b.kind == "air")
        else:
            total += MODEL.edge_charge(b.edge, b.t - a.t)  # type: ignore[arg-type]
    return total


@pytest.fixture(scope="module")
def mission() -> tuple[VehicleController, SimFlyingCar, list[Record]]:
    return fly_plan()


def test_tracking_error_on_the_ground_and_in_the_air(mission) -> None:
    ctrl, _, records = mission
    ground = [math.dist(position(r)[:2], (r.ref.x, r.ref.y)) for r in records if r.mode == Mode.DRIVING]
    air = [math.dist(position(r), (r.ref.x, r.ref.y, r.ref.z)) for r in records if r.mode in AIRBORNE]
    assert len(ground) > 1500 and len(air) > 900
    assert rms(ground) <= 0.03
    assert rms(air) <= 0.05
    assert ctrl.estimator.rejected > 0  # the injected outliers were gated out ...
    assert ctrl.machine.refused == 0  # ... and nothing asked for a transition outside the table


def test_every_node_is_reached_within_half_a_second(mission) -> None:
    _, _, records = mission
    for i, step in enumerate(STEPS):
        t_plan = T0 + step.t
        near = [r.t for r in records if math.dist(position(r), step.pos) <= 0.03]
        assert near, f"{step.node} never reached"
        assert min(abs(t - t_plan) for t in near) <= 0.5, step.node
        passing = 0 < i < len(STEPS) - 1 and STEPS[i - 1].node != step.node != STEPS[i + 1].node
        if passing:  # driven or flown through: the closest approach itself is on time
            window = [r for r in records
                      if T0 + 0.5 * (STEPS[i - 1].t + step.t) <= r.t <= T0 + 0.5 * (step.t + STEPS[i + 1].t)]
            closest = min(window, key=lambda r: math.dist(position(r), step.pos))
            assert abs(closest.t - t_plan) <= 0.5, step.node


def test_mode_sequence_follows_the_edge_kinds(mission) -> None:
    ctrl, sim, _ = mission
    assert ctrl.machine.sequence() == [Mode.PARKED, Mode.DRIVING, Mode.TAKING_OFF, Mode.FLYING, Mode.LANDING,
                                       Mode.DRIVING, Mode.DONE]
    takeoff = next(tr for tr in ctrl.machine.history if tr.dst == Mode.TAKING_OFF)
    assert takeoff.t == pytest.approx(T0 + STEPS[5].t, abs=0.02)
    assert not sim.airborne and math.dist((sim.x, sim.y, sim.z), STEPS[-1].pos) < 0.03


def test_battery_drain_matches_eq_4_5(mission) -> None:
    ctrl, _, records = mission
    end = next(r for r in records if r.t >= T0 + STEPS[-1].t)
    start = next(r for r in records if r.t >= T0)
    used = end.truth.charge_used_ah - start.truth.charge_used_ah
    assert used == pytest.approx(predicted_charge(STEPS), rel=0.10)
    assert ctrl.charge_used_ah == pytest.approx(end.truth.charge_used_ah, rel=0.10)


def test_state_reports_progress_and_arrival(mission) -> None:
    ctrl, sim, _ = mission
    ctrl.tick(sim.t)
    state = ctrl.state()
    assert state.mode == "done" and state.arrived and state.pose_ok
    assert state.step == state.steps == len(STEPS)
    assert state.mission == "sim" and state.owner == "test"


def test_pose_lost_in_the_air_lands_blind_and_gently() -> None:
    lost = MocapNoise(dropouts=((T0 + TAKEOFF + 2.0, 1e9),))
    ctrl, sim, records = fly_plan(noise=lost, until=T0 + TAKEOFF + 8.0)
    assert ctrl.machine.sequence()[-3:] == [Mode.FLYING, Mode.EMERGENCY_LANDING, Mode.DONE]
    descending = [r for r in records if r.mode == Mode.EMERGENCY_LANDING]
    start = descending[0].truth
    # its horizontal speed braked (0.25 m from 0.3 m/s; level all the way it drifted 0.52 m), then level
    assert max(math.hypot(r.truth.x - start.x, r.truth.y - start.y) for r in descending) < 0.3
    assert max(abs(r.truth.roll) + abs(r.truth.pitch) for r in descending[100:]) < math.radians(2)
    assert not sim.airborne and not sim.truth().motors
    # the vehicle is 9 % weaker than its model: the descent does not add the thrust the estimator
    # learned it lacks (a lift error learned too weak makes a blind descent climb), so it touches
    # down faster than its 0.25 m/s
    assert sim.last_impact_speed < 0.75


@pytest.mark.parametrize(("thrust_scale", "climbed"), [(1.1, 0.4), (1.1, 0.8), (0.9, 0.8)])
def test_a_vehicle_stronger_or_weaker_than_its_model_that_loses_its_poses_in_the_climb_lands_blind(
        thrust_scale: float, climbed: float) -> None:
    """Its motors give 10 % more (or less) thrust than the model says; the poses go for good when
    the take-off has climbed `climbed` of its height, a second or two after lift-off. The blind
    descent allows for the error the estimator learned in that time (`PoseEstimator.lift_error`).
    (With the flight integrators' settled bias, learned only on the reference, the stronger vehicle
    climbed on its descent to 3.4 and 2.4 m and its motors stopped there: 7.8 and 6.3 m/s.)"""
    lost = T0 + TAKEOFF - 2.5 * (1.0 - climbed)  # the climb takes 2.5 s
    ctrl, sim, records = fly_plan(params=PhysicsParams(thrust_scale=thrust_scale), until=lost + 10.0,
                                  noise=MocapNoise(pos_std=0.001, dropouts=((lost, 1e9),)))
    descent = [r for r in records if r.mode == Mode.EMERGENCY_LANDING]
    assert descent, ctrl.machine.sequence()
    assert max(r.truth.z for r in descent) < 0.6
    assert ctrl.mode == Mode.DONE and not sim.airborne and not sim.truth().motors
    assert sim.last_impact_speed < 0.75, sim.last_impact_speed


@pytest.mark.parametrize(("wound", "settled"), [(-1.0, False), (1.0, False), (-1.0, True)])
def test_an_emergency_descent_after_a_wound_up_integrator_neither_climbs_nor_falls(wound: float, settled: bool) -> None:
    """A stalled loop (commands that never arrived while the error grew) leaves the LQR's height
    integrator at its limit, a thrust bias of 5.5 m/s^2, as the poses go stale for 1.2 s. The
    descent does not take it over (it allows for the thrust model's error the estimator learned).
    Had the estimator learned the vehicle a fifth weaker than it is, the descent bounds the extra
    thrust, and once poses are back the flight controller, its
    integrators reset, lands it where it is; its motors stop once it rests. (It used to keep the
    last bias: in a 32-vehicle soak three vehicles climbed to 30 m and fell at 25 m/s.)"""
    lost = T0 + TAKEOFF + 2.0

    wound_at: list[float] = []

    def wind_up(ctrl: VehicleController, now: float) -> None:
        if ctrl.mode == Mode.EMERGENCY_LANDING and not wound_at:
            wound_at.append(now)
            ctrl.lqr.integral[2] = wound * ctrl.lqr.integral_limit
            if settled:  # the estimator learned as wrong a thrust model as it can
                ctrl.estimator.lift_error = -LIFT_ERROR_MAX

    noise = MocapNoise(pos_std=0.001, dropouts=((lost, lost + 1.2),))
    ctrl, sim, records = fly_plan(noise=noise, until=lost + 10.0, hook=wind_up)
    assert ctrl.machine.sequence()[-2:] == [Mode.EMERGENCY_LANDING, Mode.DONE]
    start = next(r for r in records if r.mode == Mode.EMERGENCY_LANDING)
    descent = [r for r in records if r.mode == Mode.EMERGENCY_LANDING]
    assert max(r.truth.z for r in descent) < start.truth.z + (0.5 if settled else 0.05)
    assert not sim.airborne and not sim.truth().motors
    assert sim.last_impact_speed < 0.7, sim.last_impact_speed


@pytest.mark.parametrize(("every", "delay_s"), [(3, 0.1), (5, 0.15), (8, 0.2)])
def test_an_emergency_descent_on_a_slow_loop_with_poses_coming_and_going_lands_gently(every: int, delay_s: float) -> None:
    """The 32-vehicle soak's world on 2 loaded cores: the loop at 33, 20 or 12.5 Hz on poses
    0.1-0.2 s old, which vanish for 0.45 s of every 0.6 s for 3.6 s (the simulator stalling). The
    pose goes stale in the air: an emergency landing, blind while they are gone, landed in place by
    the flight controller while they are back. It used to climb away (to 2.4-2.7 m, never landing)
    or fall (4.8-6 m/s): a wound-up bias kept, and a touchdown predicted blind that the poses had
    since shown wrong cut the motors 0.8 m up. At 12.5 Hz the landed vehicle hopped 2-5 cm on the
    flight controller's late corrections for 10 s, motors on, never at rest (`SETTLE_THRUST`)."""
    cruise = T0 + TAKEOFF + 1.0
    gaps = tuple((cruise + 0.6 * k, cruise + 0.6 * k + 0.45) for k in range(6))
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    records = run(ctrl, sim, cruise + 12.0, Mocap(MocapNoise(pos_std=0.001, dropouts=gaps), seed=1),
                  every=every, delay_s=delay_s)
    descent = [r for r in records if r.mode == Mode.EMERGENCY_LANDING]
    assert descent, ctrl.machine.sequence()
    assert ctrl.mode == Mode.DONE and not sim.airborne and not sim.truth().motors
    assert max(r.truth.z for r in descent) < descent[0].truth.z + 0.5
    assert sim.last_impact_speed < 0.7, sim.last_impact_speed


def test_low_battery_in_the_air_lands_at_the_nearest_ground_node() -> None:
    # nearly empty: fine on the ground, the voltage sags below 3.3 V under flight load
    ctrl, sim, _ = fly_plan(charge_used_ah=0.93 * MODEL.capacity_ah, until=T0 + TAKEOFF + 10.0)
    reasons = {tr.dst: tr.reason for tr in ctrl.machine.history}
    assert reasons[Mode.LANDING] == "low battery" and reasons[Mode.DONE] == "landed after fault"
    landing = next(tr for tr in ctrl.machine.history if tr.dst == Mode.LANDING)
    planned_landing = next(a.t for a, b in zip(STEPS, STEPS[1:], strict=False) if b.edge == "land")
    assert landing.src in AIRBORNE and landing.t < T0 + planned_landing  # driving did not trip it
    ground_nodes = [s.pos for s in STEPS if s.kind != "air"]
    assert min(math.dist((sim.x, sim.y, sim.z), p) for p in ground_nodes) < 0.03
    assert not sim.airborne and not sim.truth().motors


def corner_steps(wait: float) -> list[PlanStep]:
    """30 cm of road, a 135 deg corner (a parking spot's onto its road in city934), 30 cm more;
    the plan waits `wait` s at the corner."""
    d = 0.3 / MODEL.speed.drive
    steps = [PlanStep(node="p0", t=0.0, pos=(0.0, 0.0, 0.0), kind="parking"),
             PlanStep(node="c", t=d, pos=(0.3, 0.0, 0.0), kind="waypoint", edge="drive")]
    if wait:
        steps.append(PlanStep(node="c", t=d + wait, pos=(0.3, 0.0, 0.0), kind="waypoint"))
    end = (0.3 - 0.3 * math.sqrt(0.5), 0.3 * math.sqrt(0.5), 0.0)
    return [*steps, PlanStep(node="e", t=2 * d + wait, pos=end, kind="parking", edge="drive")]


@pytest.mark.parametrize("wait", [0.0, turn_time(0.0, 0.75 * math.pi, 3.0)], ids=["unbudgeted", "budgeted"])
def test_at_a_corner_it_turns_in_the_wait_its_plan_budgets(wait: float) -> None:
    """On a slow loop (12.5 Hz on 0.1 s old poses), a 135 deg corner the plan passes on the spot
    puts the vehicle 4.3 cm behind it (the 3 cm margin's worth and more); with the turn budgeted as
    a wait (`services/planner/sipp/turns.py`: 45 deg tail first at 3 rad/s) it turns in the wait,
    drives off tail first and stays within 2 cm."""
    steps = corner_steps(wait)
    sim = SimFlyingCar("cf1", MODEL, PERTURBED, pos=(0.0, 0.0, 0.0), yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.on_pose(Pose(vid="cf1", t=0.0, x=0.0, y=0.0, z=0.0, yaw=0.0))
    ctrl.load(plan_for("cf1", steps, MODEL, t0=1.0))
    records = run(ctrl, sim, 1.0 + steps[-1].t + 1.0, Mocap(NOISE, seed=3), every=8, delay_s=0.1)
    worst = max(math.dist((r.truth.x, r.truth.y), (r.ref.x, r.ref.y)) for r in records if r.ref is not None)
    assert math.dist((sim.x, sim.y, 0.0), steps[-1].pos) < 0.01 and ctrl.mode == Mode.DONE
    if wait:
        assert worst < 0.02 and ctrl.pursuit.reversing, f"{worst:.3f} m off its plan"
    else:
        assert worst > 0.035, f"{worst:.3f} m off its plan"


def test_a_vehicle_parked_facing_away_turns_to_its_first_drive_before_the_start() -> None:
    """Parked facing away from its first edge (135 deg off), with the plan in the start's 2 s lead:
    it turns in place before the start, by 45 deg to drive off tail first, and then drives on its
    plan's time (turning on the plan's time instead, it fell 6-9 cm behind: held by the tracking
    guard under load)."""
    lead, d1 = 2.0, math.hypot(0.15, 0.15) / MODEL.speed.drive
    steps = [PlanStep(node="p0", t=0.0, pos=(0.0, 0.0, 0.0), kind="parking"),
             PlanStep(node="r1", t=d1, pos=(0.15, 0.15, 0.0), kind="waypoint", edge="drive"),
             PlanStep(node="r2", t=d1 + 0.5 / MODEL.speed.drive, pos=(0.65, 0.15, 0.0), kind="waypoint", edge="drive")]
    sim = SimFlyingCar("cf1", MODEL, PERTURBED, pos=(0.0, 0.0, 0.0), yaw=-0.5 * math.pi)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.on_pose(Pose(vid="cf1", t=0.0, x=0.0, y=0.0, z=0.0, yaw=sim.yaw))
    ctrl.load(plan_for("cf1", steps, MODEL, t0=lead))
    records = run(ctrl, sim, lead + steps[-1].t, Mocap(MocapNoise(pos_std=0.001), seed=3))
    at_start = next(r for r in records if r.t >= lead)
    assert abs(math.remainder(at_start.truth.yaw + 0.75 * math.pi, 2 * math.pi)) < math.radians(10)  # tail first
    assert math.hypot(at_start.truth.x, at_start.truth.y) < 0.01  # turned in place
    first_leg = [r for r in records if lead + 0.5 <= r.t <= lead + d1]
    worst = max(math.dist((r.truth.x, r.truth.y), (0.15 * (r.t - lead) / d1, 0.15 * (r.t - lead) / d1))
                for r in first_leg)
    assert worst < 0.03, f"{worst:.3f} m behind its plan"  # the shipped maps' margin


def test_a_voltage_not_measured_yet_is_not_a_low_battery() -> None:
    """A gateway still connecting publishes 0 V (no log block yet): unknown, not empty."""
    monitor = FaultMonitor(MODEL)

    def telemetry(vbat: float, link_ok: bool, now: float) -> None:
        monitor.on_telemetry(Telemetry(vid="cf1", t=now, gateway="sim", vbat=vbat, link_quality=0.0, sent=0,
                                       dropped=0, cmd_rate_hz=0.0, link_ok=link_ok), now)

    for k in range(30):
        telemetry(0.0, False, 0.1 * k)
    assert not monitor.low_battery(0.0, 3.0)
    for k in range(30, 45):
        telemetry(3.1, True, 0.1 * k)
    assert monitor.low_battery(0.0, 4.4)


def test_the_reserve_is_spent_at_the_capacity_or_near_the_firmwares_shutdown_voltage() -> None:
    """What ends a fault landing's wait for a clear node (`VehicleController._choose_landing`): the
    charge used reaches the whole capacity, or the voltage stays under 3.1 V for a second (the
    firmware shuts down after 5 s under 3.0 V); 0 V is no measurement."""
    monitor = FaultMonitor(MODEL)
    assert not monitor.reserve_spent(MODEL.usable_ah, 0.0) and monitor.reserve_spent(MODEL.capacity_ah, 0.0)
    for k, vbat in enumerate([0.0] * 20 + [3.2] * 20 + [3.05] * 9):
        monitor.on_telemetry(Telemetry(vid="cf1", t=0.1 * k, gateway="sim", vbat=vbat, link_quality=1.0, sent=0,
                                       dropped=0, cmd_rate_hz=100.0), 0.1 * k)
    assert monitor.low_battery(0.0, 4.8) and not monitor.reserve_spent(0.0, 4.8)  # 0.8 s under 3.1 V
    assert monitor.reserve_spent(0.0, 5.0)


def test_abort_lands_a_flying_vehicle_and_stops_a_driving_one() -> None:
    in_air = T0 + TAKEOFF + 2.0
    ctrl, sim, _ = fly_plan(until=in_air + 6.0, hook=abort_at(in_air))
    assert [tr.reason for tr in ctrl.machine.history][-2:] == ["abort", "landed after fault"]
    assert min(math.dist((sim.x, sim.y, sim.z), s.pos) for s in STEPS if s.kind != "air") < 0.03
    on_road = T0 + 5.0
    ctrl, sim, records = fly_plan(until=on_road + 2.0, hook=abort_at(on_road))
    assert ctrl.mode == Mode.DONE
    assert records[-1].truth.x == pytest.approx(records[-60].truth.x, abs=0.002)  # stopped


def landing_node(ctrl: VehicleController) -> str | None:
    """Where a fault landing of `ctrl`'s vehicle is heading (None: none under way)."""
    step = ctrl.landing_step
    return step.node if step is not None else None


def test_an_abort_lands_on_the_nearest_landing_node_clear_of_the_vehicles_standing_there() -> None:
    """Aborted while it hovers above its landing node: it lands there; with another vehicle parked
    on that node, it flies back to the node it took off from instead (executor: `_bodies_besides`)."""
    hovering = T0 + next(s.t for s in STEPS if s.node == "a2")
    landing = {s.node: s.pos for s in STEPS if s.node in ("l1", "l2")}
    parked = (*landing["l2"][:2], 0.0)
    for bodies, node in (((), "l2"), ((parked, (5.0, 5.0, 0.0)), "l1")):
        ctrl, sim, records = fly_plan(until=hovering + 11.0, hook=abort_at(hovering + 0.5), bodies=bodies)
        assert [tr.reason for tr in ctrl.machine.history][-2:] == ["abort", "landed after fault"], node
        assert math.dist((sim.x, sim.y, sim.z), landing[node]) < 0.03, (node, sim.x, sim.y, sim.z)
        if bodies:  # never came down within reach of the parked body: its column stayed clear
            low = [r for r in records if r.t > hovering and r.truth.z < 0.4]
            assert low and min(math.dist((r.truth.x, r.truth.y), parked[:2]) for r in low) > 0.5


@pytest.mark.parametrize("parked", [None, 0.0, 0.5], ids=["nothing_below", "stopped_there", "rolls_in_later"])
def test_an_abort_in_a_planned_landing_lands_elsewhere_with_a_body_below_it(parked: float | None) -> None:
    """Aborted in its plan's landing onto l2, the vehicle lands there, the mission ending at its
    touchdown; but with a vehicle on l2 (an abort stops every driver where it is: an 80-vehicle
    soak's abort had a landing come down 11 cm deep onto a vehicle standing below it), at
    the abort or rolling in half a second later, it stops its descent and lands on the nearest
    clear node instead (l1), never lower than a few centimetres under where it was over the body."""
    landing = T0 + [s.t for s in STEPS if s.node == "a2"][-1]  # (its plan's landing begins)
    abort = landing + 0.5
    l1, l2 = (next(s.pos for s in STEPS if s.node == node) for node in ("l1", "l2"))
    bodies: list[tuple[float, float, float]] = []

    def hook(ctrl: VehicleController, now: float) -> None:
        if now >= abort:
            assert ctrl.mode in (Mode.LANDING, Mode.DONE), ctrl.mode
            ctrl.abort("abort")
        if parked is not None and now >= abort + parked and not bodies:
            bodies.append((l2[0], l2[1], 0.0))

    ctrl, sim, records = fly_plan(until=abort + 10.0, hook=hook, bodies=bodies)
    assert ctrl.mode == Mode.DONE and sim.z < 0.01
    if parked is None:
        assert math.dist((sim.x, sim.y, sim.z), l2) < 0.03
        return
    assert math.dist((sim.x, sim.y, sim.z), l1) < 0.03, (sim.x, sim.y, sim.z)
    column = 2.0 * MODEL.radius + MODEL.margin
    seen = abort + parked
    over = [r.truth.z for r in records if r.t >= seen and math.dist((r.truth.x, r.truth.y), l2[:2]) < column]
    there = next(r.truth.z for r in records if r.t >= seen)
    assert min(over) > there - 0.05, (min(over), there)


@pytest.mark.parametrize("way", ["clear again", "crossed"])
def test_an_aborted_vehicle_whose_flight_to_its_node_heads_into_a_body_hovers_and_chooses_again(way: str) -> None:
    """The proximity stop on an abort's flight to its landing node (in an 80-vehicle soak two
    pairs of aborted vehicles' flights crossed, 11 cm deep): told to stop short on its way, the
    vehicle hovers there, not held, its node given up, and chooses again half a second later. With
    the way clear again it flies on to its node; with a body hovering on its way (the one it
    stopped for) it passes that node over: here, with the other node taken, straight down."""
    hovering = T0 + next(s.t for s in STEPS if s.node == "a2")
    l1, l2 = (next(s.pos for s in STEPS if s.node == node) for node in ("l1", "l2"))
    bodies: list[tuple[float, float, float]] = [(l2[0], l2[1], 0.0)]  # parked on l2: it flies back to l1
    stop: list[tuple[float, tuple[float, float, float]]] = []
    seen: list[tuple[Mode, str | None, str | None, str]] = []

    def hook(ctrl: VehicleController, now: float) -> None:
        if now >= hovering + 0.5:
            ctrl.abort("abort")
        if not stop and landing_node(ctrl) == "l1" and now >= hovering + 2.0:
            assert ctrl.motion() is not None
            assert ctrl.stop_short("stops short of cf9")
            est = ctrl.estimator.estimate(now)
            stop.append((now, (est.x, est.y, est.z)))
            if way == "crossed":
                bodies.append((1.2, l1[1], 0.52))
        elif stop and now < stop[0][0] + 0.45:
            seen.append((ctrl.mode, landing_node(ctrl), ctrl.held, ctrl.landing_wait))

    ctrl, sim, records = fly_plan(until=hovering + 14.0, hook=hook, bodies=bodies)
    at, where = stop[0]
    assert seen[-1] == (Mode.HOVERING, None, None, "stops short of cf9"), seen[-1]  # to choose again, not held
    paused = [r for r in records if at <= r.t < at + 0.45]
    assert max(math.dist(position(r), where) for r in paused) < 0.05
    assert [tr.reason for tr in ctrl.machine.history][-1] == "landed after fault"
    if way == "clear again":
        assert math.dist((sim.x, sim.y, sim.z), l1) < 0.03
    else:
        assert math.dist((sim.x, sim.y), where[:2]) < 0.05 and sim.z < 0.01
        assert min(r.truth.x for r in records if r.t > at) > 1.2 + 2 * MODEL.radius


def link_lost_during(start: float, end: float) -> Hook:
    def hook(ctrl: VehicleController, now: float) -> None:
        ctrl.on_telemetry(Telemetry(vid="cf1", t=now, gateway="sim", vbat=4.0, link_quality=1.0, sent=0,
                                    dropped=0, cmd_rate_hz=100.0, link_ok=not start <= now < end), now)
    return hook


def test_lost_link_on_the_ground_holds_then_resumes() -> None:
    lost = (T0 + 4.0, T0 + 5.0)
    ctrl, sim, records = fly_plan(until=T0 + 12.0, hook=link_lost_during(*lost), telemetry_every=0)
    assert ctrl.machine.sequence()[:4] == [Mode.PARKED, Mode.DRIVING, Mode.HOLDING, Mode.DRIVING]
    held = [r for r in records if r.mode == Mode.HOLDING]
    assert held[0].t == pytest.approx(lost[0], abs=0.02) and held[-1].t == pytest.approx(lost[1], abs=0.02)
    assert math.dist(position(held[-1]), position(held[10])) < 0.005  # stood still
    assert math.dist(position(records[-1])[:2], (records[-1].ref.x, records[-1].ref.y)) < 0.02  # caught up


def test_a_vehicle_held_up_past_its_plans_end_drives_on_to_its_goal() -> None:
    """Held on the last road leg until after the plan ended (as the gateway stops a driver whose
    executor was cut off, and the next owner resumes it late): it still parks on its goal."""
    end = T0 + STEPS[-1].t
    ctrl, sim, records = fly_plan(until=end + 6.0, hook=link_lost_during(end - 1.5, end + 0.5), telemetry_every=0)
    assert [tr.reason for tr in ctrl.machine.history][-2:] == ["behind the plan: driving on to the goal", "plan"]
    assert ctrl.mode == Mode.DONE and math.dist((sim.x, sim.y), STEPS[-1].pos[:2]) < 0.05
    ctrl.tick(sim.t)
    assert ctrl.state().arrived


def test_a_vehicle_far_from_its_goal_at_its_plans_end_does_not_drive_off_the_roads() -> None:
    end = T0 + STEPS[-1].t
    ctrl, sim, _ = fly_plan(until=end + 3.0, hook=link_lost_during(end - 7.0, end + 0.5), telemetry_every=0)
    miss = math.dist((sim.x, sim.y), STEPS[-1].pos[:2])
    assert ctrl.mode == Mode.DONE and miss > ctrl.params.finish_radius
    assert "behind the plan: driving on to the goal" not in [tr.reason for tr in ctrl.machine.history]


def test_stale_pose_on_the_ground_gives_up_after_the_longest_hold() -> None:
    ctrl, sim, _ = fly_plan(noise=MocapNoise(dropouts=((T0 + 4.0, 1e9),)), until=T0 + 9.0)
    assert ctrl.machine.sequence() == [Mode.PARKED, Mode.DRIVING, Mode.HOLDING, Mode.DONE]
    assert ctrl.machine.history[-1].reason == "held too long, plan given up"


def test_a_plan_the_vehicle_cannot_follow_is_refused_not_crashed() -> None:
    """Starting 'in the air' while parked on the ground: every tick asks for FLYING, which the table
    refuses; the vehicle stays parked with motors off."""
    steps = [PlanStep(node="a", t=0.0, pos=(0.0, 0.0, 0.5), kind="air"),
             PlanStep(node="b", t=3.0, pos=(0.9, 0.0, 0.5), kind="air", edge="fly")]
    ctrl, sim, _ = fly_plan(steps, until=T0 + 2.0)
    assert ctrl.mode == Mode.PARKED and ctrl.machine.refused > 100
    assert sim.z == 0.0 and not sim.truth().motors


def test_before_the_mission_starts_the_vehicle_stays_parked() -> None:
    ctrl = VehicleController("cf1", MODEL)
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=0.0))  # not started
    cmd = ctrl.tick(10.0)
    state = ctrl.state()
    assert cmd.setpoint.__class__.__name__ == "StopSetpoint" and cmd.vid == "cf1" and cmd.seq == 1
    assert state.mode == "parked" and not state.pose_ok
    ctrl.start(10.0)
    with pytest.raises(ValueError):
        ctrl.load(plan_for("cf2", STEPS, MODEL))


def test_telemetry_silence_in_the_air_lands_and_a_plan_is_not_loaded_mid_air() -> None:
    silent_from = T0 + TAKEOFF + 1.0
    refused: list[bool] = []

    def hook(ctrl: VehicleController, now: float) -> None:
        if now < silent_from:
            ctrl.on_telemetry(Telemetry(vid="cf1", t=now, gateway="sim", vbat=4.0, link_quality=1.0, sent=0,
                                        dropped=0, cmd_rate_hz=100.0), now)
        elif not refused:
            refused.append(ctrl.load(plan_for("cf1", STEPS, MODEL, t0=now)))

    ctrl, sim, _ = fly_plan(until=silent_from + 6.0, hook=hook, telemetry_every=0)
    assert refused == [False] and ctrl.plan is not None and ctrl.plan.t0 == T0
    reasons = {tr.dst: tr.reason for tr in ctrl.machine.history}
    assert reasons[Mode.LANDING] == "link lost" and reasons[Mode.DONE] == "landed after fault"
    assert not sim.airborne and not sim.truth().motors


@pytest.mark.parametrize(("lead", "least", "most"), [(ACTUATION_S, 0.0, 0.015), (0.0, 0.03, 1.0)])
def test_a_flyer_whose_commands_act_late_holds_its_height_when_its_controller_leads(
        lead: float, least: float, most: float) -> None:
    """Its commands act 40 ms after its controller's tick, poses 30 ms old (a loaded executor, the
    bus, its gateway's tick and radio slot). Acting on the state and reference of when its command
    acts (`ACTUATION_S`), it flies its plan's level leg within 1.5 cm of height peak to peak (0.4
    cm); unled, its height loop swings 4.7 cm (an 80-vehicle soak's flyers swung +-3 cm at 0.3
    m/s, docs/reliability.md)."""
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test", params=ControlParams(actuation_s=lead))
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    a2 = next(s for s in STEPS if s.node == "a2")
    records = run(ctrl, sim, T0 + a2.t, delay_s=0.03, act_delay_s=0.04)
    level = [r.truth.z - r.ref.z for r in records if r.t >= T0 + TAKEOFF + 1.0 and r.ref is not None]
    assert least < max(level) - min(level) < most, (max(level) - min(level), len(level))


@pytest.mark.parametrize("steady_only", [True, False])
def test_a_flyer_on_a_late_loop_holds_its_height_when_only_steady_thrust_teaches_the_lift_error(
        steady_only: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Poses 0.1 s old, a tick every other period, commands acting 60 ms late (a starved executor):
    the take-off's and the height loop's swings, learned as a thrust-model error, fed back into its
    predictions and swung it more. With only steady commands teaching on a late loop
    (`PoseEstimator._teaches`) it flies its level leg within 14 cm of height peak to peak (10-12)
    and learns next to no error (it has none); every command teaching (as before), 23 cm and 0.09."""
    if not steady_only:
        monkeypatch.setattr(estimator_module, "LIFT_LATE_S", math.inf)
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    a2 = next(s for s in STEPS if s.node == "a2")
    records = run(ctrl, sim, T0 + a2.t, delay_s=0.1, act_delay_s=0.06, every=2)
    level = [r.truth.z - r.ref.z for r in records if r.t >= T0 + TAKEOFF + 1.0 and r.ref is not None]
    swing = max(level) - min(level)
    if steady_only:
        assert swing < 0.14 and abs(ctrl.estimator.lift_error) < 0.04, (swing, ctrl.estimator.lift_error)
    else:
        assert swing > 0.18, swing
