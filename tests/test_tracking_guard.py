"""The tracking guard (issue 15): a plan is collision-free only while each vehicle stays within the
margin it was planned with, so a vehicle whose tracking error leaves that margin is held where it is
(hovering in the air, stopped on the ground). Judged in the simulator's ground truth.

A slow control loop is modelled as the executor falling behind: poses reach it late and it computes
a setpoint only every few radio periods (the last one is repeated meanwhile, as the gateway does).
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import os
import signal
import threading
import time
from collections import deque

import msgspec
import pytest

from common.bus.keys import Keys
from common.bus.messages import FramePose, MissionAbort, Pose, PoseFrame, Telemetry
from common.bus.session import ZenohConfig
from common.deploy.launcher import status
from common.domain.vehicle_model import VehicleModel
from common.flight.modes import Mode
from services.executor.faults import FaultParams
from services.executor.service import ExecutorService
from services.executor.vehicle_controller import ControlParams, VehicleController
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from services.sim.crazyflie.physics import PhysicsParams, SimFlyingCar
from tests.support.closed_loop import Mocap, MocapNoise, plan_for, reference_steps, run
from tests.support.fleet_faults import NO_RECORDER, TOWN_TASKS, Watch, airborne, until
from tests.support.fleet_faults import fly as fly_mission

MODEL = VehicleModel(margin=0.03)  # the shipped maps' margin
STEPS = reference_steps(MODEL)
T0 = 0.5
DT = 0.01


@dataclasses.dataclass
class Flight:
    ctrl: VehicleController
    held_at: float | None  # simulator time the guard held the vehicle
    modes: list[Mode]
    error_before_hold: float  # largest truth distance from the reference until the hold (m)
    drift_after_hold: float  # largest truth distance from where it is held, after 1 s braking (m)


def fly(every: int, delay_s: float, guard: bool = True, until: float | None = None) -> Flight:
    """Fly the reference path with the controller ticking every `every` periods on poses
    `delay_s` old."""
    params = ControlParams(faults=FaultParams(guard=guard))
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test", params=params)
    ctrl.on_pose(Pose(vid="cf1", t=0.0, x=sim.x, y=sim.y, z=sim.z, yaw=sim.yaw))
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    mocap = Mocap(MocapNoise(pos_std=0.001), seed=3)
    late: deque[Pose] = deque()
    end = until if until is not None else T0 + STEPS[-1].t + 2.0
    held_at: float | None = None
    error = drift = 0.0
    modes: list[Mode] = []
    setpoint = None
    k = 0
    while sim.t < end - 1e-9:
        now = sim.t
        truth = sim.truth()
        pose = mocap.observe(truth)
        if pose is not None:
            late.append(pose)
        while late and late[0].t <= now - delay_s + 1e-9:
            ctrl.on_pose(late.popleft())
        if k % every == 0:
            if k % 10 == 0:
                ctrl.on_telemetry(Telemetry(vid="cf1", t=now, gateway="sim", vbat=sim.battery.vbat, link_quality=1.0,
                                            sent=k, dropped=0, cmd_rate_hz=100.0), now)
            cmd = ctrl.tick(now)
            setpoint = cmd.setpoint
            if held_at is None and ctrl.held:
                held_at = now
        if setpoint is not None:
            sim.apply(setpoint, now)
        ref = ctrl.reference(now)
        here = (truth.x, truth.y, truth.z)
        if held_at is None and ref is not None:
            error = max(error, math.dist(here, (ref.x, ref.y, ref.z)))
        elif held_at is not None and ref is not None and now > held_at + 1.0:
            drift = max(drift, math.dist(here, (ref.x, ref.y, ref.z)))
        modes.append(ctrl.mode)
        sim.step(DT)
        k += 1
    return Flight(ctrl, held_at, modes, error, drift)


def test_the_nominal_loop_never_trips_the_guard() -> None:
    flight = fly(every=1, delay_s=0.0)
    assert flight.ctrl.held is None
    assert flight.ctrl.mode == Mode.DONE
    assert flight.error_before_hold < MODEL.margin  # the margin the guard's threshold is made of


def test_a_loop_on_poses_a_fifth_of_a_second_old_stays_near_its_plan() -> None:
    """An overloaded machine's poses reach the executor up to 0.25 s after their capture (the
    motion-capture bridge drops older frames). The estimate is predicted to now with the commands
    given since, the yaw too: at the poses' yaw rate alone, the turn to the flight's heading at the
    top of the take-off was estimated 60-100 deg behind on 0.2 s old poses, and the vehicle flew
    off 20 m (2026-12-05; 8-24 m at 0.2-0.3 s, every control rate)."""
    flight = fly(every=1, delay_s=0.2, guard=False)
    assert flight.ctrl.mode == Mode.DONE
    assert flight.error_before_hold < 2.0 * MODEL.margin, flight.error_before_hold


SLOW = {"every": 12, "delay_s": 0.15}  # 8.3 Hz on 150 ms old poses (it tracks within 1.5x the margin
# at 12.5 Hz on 100 ms since it propagates its attitude over the time its commands held, and within
# 2.2x at 9 Hz on 100 ms since its gain follows the loop's period: `FlightLqr`; 17 Hz on 60 ms
# left 4x before either)


@pytest.fixture(scope="module")
def unguarded() -> Flight:
    return fly(**SLOW, guard=False)


def test_without_the_guard_the_slow_loop_leaves_four_times_the_margin(unguarded: Flight) -> None:
    assert unguarded.ctrl.held is None
    assert unguarded.error_before_hold > 4.0 * MODEL.margin, unguarded.error_before_hold


def test_a_slow_loop_is_held_before_it_leaves_three_times_the_margin(unguarded: Flight) -> None:
    flight = fly(**SLOW)
    assert flight.held_at is not None, "the guard never held the vehicle"
    assert "margin" in (flight.ctrl.held or "")
    # rejoinable only if held late on its plan's way, not off it (`test_a_vehicle_held_late_on_its_way_...`)
    assert flight.ctrl.rejoinable == ("late on it" in (flight.ctrl.held or "")), flight.ctrl.held
    assert flight.ctrl.mode in (Mode.HOLDING, Mode.HOVERING)
    assert flight.error_before_hold < 3.0 * MODEL.margin, flight.error_before_hold  # held past 2x (FaultParams)
    # hovering on the same slow loop stays within reach (at 8.3 Hz on 150 ms old poses, a loop at the
    # edge of its stability, no steadier than tracking the plan on it: 11 cm)
    assert flight.drift_after_hold < 6.0 * MODEL.margin, flight.drift_after_hold


def test_a_vehicle_held_in_the_air_hovers_and_lands_safely_on_abort() -> None:
    takeoff_end = next(s.t for s in STEPS if s.edge == "takeoff")
    # nominal until the vehicle is airborne, then the loop slows down
    params = ControlParams(faults=FaultParams())
    ctrl = VehicleController("cf1", MODEL, owner="test", params=params)
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    ctrl.machine.request(Mode.TAKING_OFF, 0.0, "test")
    ctrl.machine.request(Mode.FLYING, 0.0, "test")
    ref = ctrl.reference(T0 + takeoff_end + 0.5)
    assert ref is not None
    off = Pose(vid="cf1", t=T0 + takeoff_end + 0.5, x=ref.x + 0.1, y=ref.y, z=ref.z, yaw=0.0)
    for i in range(60):
        pose = msgspec.structs.replace(off, t=off.t + i * DT, seq=i + 1)
        ctrl.on_pose(pose)
        ctrl.tick(pose.t)
    assert ctrl.held and ctrl.mode == Mode.HOVERING
    hover = ctrl.reference(off.t + 1.0)
    assert hover is not None and hover.mode == Mode.HOVERING
    assert hover.x == pytest.approx(ctrl.estimator.estimate(off.t).x, abs=0.05)
    ctrl.abort("operator")
    ctrl.tick(off.t + 0.5)
    assert ctrl.mode == Mode.LANDING or ctrl.reference(off.t + 0.6).mode != Mode.HOVERING


@pytest.mark.parametrize("guard", [True, False], ids=["guard", "guard_off"])
def test_a_vehicle_its_mission_holds_in_the_air_hovers_where_it_is_and_may_come_back(guard: bool) -> None:
    """`MissionAbort.hold` for a vehicle in flight (its mission's replan could not place it): its
    executor holds it where it is, hovering, for the mission's sake (rejoinable: the mission may
    bring it back), as the proximity stop holds one; it does not land. With the tracking guard off
    nothing holds a vehicle: it lands, as on an abort."""
    svc = ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("hold"))  # never run: no session
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    ctrl = svc.controllers["cf1"] = VehicleController("cf1", MODEL, owner="e1",
                                                      params=ControlParams(faults=FaultParams(guard=guard)))
    plan = svc.plans["cf1"] = plan_for("cf1", STEPS, MODEL, t0=T0)
    ctrl.load(plan)
    cruise = T0 + next(s.t for s in STEPS if s.node == "a1") + 1.0
    run(ctrl, sim, cruise, Mocap())
    reason = "cf1: held where it is, no plan around the vehicles that left"
    svc._on_abort(MissionAbort(mission=plan.mission, reason=reason, vehicles=["cf1"], hold=True), "")
    at = (sim.x, sim.y, sim.z)
    run(ctrl, sim, cruise + 3.0, Mocap())
    if not guard:
        assert ctrl.mode in (Mode.LANDING, Mode.DONE) and not ctrl.held, ctrl.mode
        return
    assert ctrl.mode == Mode.HOVERING and ctrl.held == reason and ctrl.rejoinable, (ctrl.mode, ctrl.held)
    assert math.dist((sim.x, sim.y, sim.z), at) < 0.1, ((sim.x, sim.y, sim.z), at)


@pytest.mark.parametrize(("where", "rejoinable"), [("behind", True), ("beside", False)])
def test_a_vehicle_held_late_on_its_way_may_come_back_one_held_off_it_may_not(where: str, rejoinable: bool) -> None:
    """A vehicle the guard holds for its own tracking (a starved loop, a stalled take-off) is
    rejoinable when it stands on its plan's way, behind its reference (the mission brings it back
    there once it stands still: `services/mission/rejoin.py`); one pushed beside its way (wind) is
    not, and its report says which (`VehicleController._on_its_way`)."""
    takeoff_end = next(s.t for s in STEPS if s.edge == "takeoff")
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    ctrl.machine.request(Mode.TAKING_OFF, 0.0, "test")
    ctrl.machine.request(Mode.FLYING, 0.0, "test")
    t = T0 + takeoff_end + 2.0
    traj = ctrl.trajectory
    assert traj is not None
    now, before = traj.plan_position(t - T0), traj.plan_position(t - T0 - 0.6)
    way = [now[i] - before[i] for i in range(3)]
    assert math.hypot(*way) > 4.0 * MODEL.margin  # behind by more than the guard's burst
    side = (-way[1] / math.hypot(*way), way[0] / math.hypot(*way))  # horizontal, across its way
    at = before if where == "behind" else (now[0] + 4.0 * MODEL.margin * side[0],
                                           now[1] + 4.0 * MODEL.margin * side[1], now[2])
    for i in range(10):
        pose = Pose(vid="cf1", t=t + i * DT, x=at[0], y=at[1], z=at[2], yaw=0.0, seq=i + 1)
        ctrl.on_pose(pose)
        ctrl.tick(pose.t)
    assert ctrl.held and ctrl.mode == Mode.HOVERING, ctrl.mode
    assert ctrl.rejoinable == rejoinable, ctrl.held
    assert ("late on it" if rejoinable else "off it") in ctrl.held, ctrl.held


@pytest.mark.parametrize(("thrust_scale", "held"), [(0.7, True), (1.0, False)])
def test_a_take_off_left_among_the_vehicles_on_the_ground_is_held(thrust_scale: float, held: bool) -> None:
    """The guard judges a take-off's horizontal error only (late inside its own column is
    harmless), but once its plan has it 3x the margin above the ground layer (a body's height: the
    plan lets others cross its spot from then on) while it is still in it, it is held and reported,
    so that the vehicles whose plans cross there yield. (In 32-vehicle soaks cf16, late in its climb
    after a stalled loop, came down onto cf20 crossing its take-off node on time, three times.)
    Motors too weak to lift it (70 % of the model's thrust) stand for the stall; a take-off at
    20 Hz on 0.15 s old poses is not held."""
    sim = SimFlyingCar("cf1", MODEL, PhysicsParams(thrust_scale=thrust_scale), pos=STEPS[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    takeoff = next(s.t for s in STEPS if s.edge == "takeoff")
    run(ctrl, sim, T0 + takeoff + 1.0, Mocap(MocapNoise(pos_std=0.001), seed=1), every=5, delay_s=0.15)
    if held:
        assert ctrl.held is not None and "among the vehicles on the ground" in ctrl.held, ctrl.held
        assert ctrl.mode == Mode.HOVERING
    else:
        assert ctrl.held is None and ctrl.mode == Mode.FLYING, (ctrl.held, ctrl.mode)


# ---- in the fleet: one executor starved of CPU ----------------------------------------------------

STOP_S, RUN_S = 0.17, 0.03  # the starved executor runs 30 ms of every 200 ms


def test_a_vehicle_whose_plan_goes_where_another_is_held_holds_too() -> None:
    """The fleet's reflex (issue 15): told that another vehicle is held at a point its plan reaches
    within `yield_s`, a vehicle holds too, in the air and on the ground; a point it reaches later,
    or passes well clear of, leaves it flying its plan."""
    fly_at = next(s.t for s in STEPS if s.edge == "fly")
    for at, airborne_then in ((fly_at - 1.0, True), (0.2, False)):
        sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
        ctrl = VehicleController("cf1", MODEL, owner="test")
        ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
        run(ctrl, sim, T0 + at)
        now, traj = sim.t, ctrl.trajectory
        ahead = traj.plan_position(now - T0 + 2.0)
        later = traj.plan_position(min(now - T0 + FaultParams().yield_s + 4.0, traj.end_time))
        aside = (ahead[0], ahead[1] - 0.5, ahead[2])  # the path runs along +x and +y
        assert not ctrl.yield_to("cf9", aside, now) and not ctrl.yield_to("cf9", later, now)
        assert ctrl.yield_to("cf9", ahead, now)
        run(ctrl, sim, now + 1.0)
        assert ctrl.mode == (Mode.HOVERING if airborne_then else Mode.HOLDING), ctrl.mode
        assert ctrl.held is not None and ctrl.held.startswith("yields to cf9")
        held = (sim.x, sim.y, sim.z)
        run(ctrl, sim, sim.t + 2.0)
        assert math.dist(held, (sim.x, sim.y, sim.z)) < 0.05  # it stays there


def test_a_vehicle_whose_plan_leaves_a_held_one_beside_it_goes_on() -> None:
    """Within reach of a held vehicle but on a plan that takes it away (or keeps its distance), a
    vehicle does not yield: holding would keep it near. (A 32-vehicle soak: cf16, late, stopped
    short 1.6 cm behind cf07; cf07 yielded to it and the two, closer than the plan's envelopes,
    could not be planned back into the mission.) One whose plan comes nearer yields."""
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    run(ctrl, sim, T0 + STEPS[1].t + 1.0)  # on its drive from r1 to r2, along +x
    assert ctrl.mode == Mode.DRIVING
    now = sim.t
    behind = (sim.x - 2.0 * MODEL.radius - 0.02, sim.y, sim.z)  # 2 cm from contact, behind it
    assert not ctrl.yield_to("cf9", behind, now)
    assert ctrl.yield_to("cf9", (sim.x + 0.3, sim.y, sim.z), now)  # ahead, on its way


def test_a_vehicle_whose_plan_passes_under_one_coming_down_holds_too() -> None:
    """Another vehicle's emergency landing comes straight down from where it was: a vehicle whose
    plan passes under it within `yield_s` holds (on the ground, or in the air below it); one that
    passes over it, or under a vehicle merely held there, goes on."""
    fly_at = next(s.t for s in STEPS if s.edge == "fly")
    for at, airborne_then in ((0.2, False), (fly_at - 4.0, True)):  # (then in cruise for the next 4 s)
        sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
        ctrl = VehicleController("cf1", MODEL, owner="test")
        ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
        run(ctrl, sim, T0 + at)
        now = sim.t
        x, y, z = ctrl.trajectory.plan_position(now - T0 + 2.0)
        above, below = (x, y, z + 0.5), (x, y, z - 0.5)
        assert not ctrl.yield_to("cf9", above, now)  # held up there: no threat to a vehicle passing under
        assert not ctrl.yield_to("cf9", below, now, descending=True)  # it passes over it
        assert ctrl.yield_to("cf9", above, now, descending=True)
        assert ctrl.held is None and ctrl.tick(now) and ctrl.held is not None
        assert ctrl.held.startswith("yields to cf9, coming down from"), ctrl.held
        run(ctrl, sim, now + 1.0)
        assert ctrl.mode == (Mode.HOVERING if airborne_then else Mode.HOLDING), ctrl.mode


def test_a_vehicle_held_unseen_for_a_while_is_given_the_way_it_may_have_gone() -> None:
    """Held on a stale pose, a vehicle may have driven on blind past its last pose: the others
    yield to where it may be (its last pose, widened by the time unseen at its fastest speed), not
    only to that pose. (A 32-vehicle soak: held 14 cm past its last pose, a neighbour whose plan
    passed clear of that pose drove into it.)"""
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    run(ctrl, sim, T0 + 0.2)
    ahead = ctrl.trajectory.plan_position(sim.t - T0 + 2.0)
    near = (ahead[0] + 0.3 / math.sqrt(2), ahead[1] - 0.3 / math.sqrt(2), ahead[2])  # 0.28 m off the path
    assert not ctrl.yield_to("cf9", near, sim.t)
    assert not ctrl.yield_to("cf9", near, sim.t, unseen_s=0.1)
    assert ctrl.yield_to("cf9", near, sim.t, unseen_s=1.0)
    assert ctrl.held is None and ctrl.tick(sim.t) and ctrl.held is not None


def test_a_vehicle_stopped_by_a_stale_pose_is_held_for_good_once_its_plan_moved_on() -> None:
    """Stopped on the ground by a stale pose while its plan runs on, a vehicle is where the others'
    plans no longer expect it: once its reference is 2x the margin away it is held for good (and
    reported, so the others yield and are replanned), even before its pose comes back. (At 3x, in
    a 32-vehicle soak a neighbour on time drove into it while the report travelled.)"""
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    lost = T0 + 4.0
    run(ctrl, sim, lost + 3.0, Mocap(MocapNoise(pos_std=0.001, dropouts=((lost, lost + 2.0),)), seed=3))
    assert ctrl.machine.sequence() == [Mode.PARKED, Mode.DRIVING, Mode.HOLDING], ctrl.machine.sequence()
    assert ctrl.held is not None and ctrl.held.startswith("its plan moved on"), ctrl.held
    assert float(ctrl.held.split()[4]) < 2.5 * MODEL.margin, ctrl.held
    held_at = next(tr.t for tr in ctrl.machine.history if tr.dst == Mode.HOLDING)
    assert lost < held_at < lost + 2.0  # before the pose came back, after it went stale


def test_a_vehicle_first_seen_shortly_before_the_start_drives_its_plan() -> None:
    """No pose yet when its plan arrives (motion capture found it late): it holds, stale, and once
    seen it follows its plan. Where it stopped is not judged from an estimate it never had (it was:
    the filter's empty state, the origin, 1.1 m from its spot, so the guard held it for good before
    the start, its plan having "moved on 1.118 m while it was stopped")."""
    start = 3.0
    steps = [msgspec.structs.replace(s, pos=(s.pos[0] + 1.0, s.pos[1] + 0.5, s.pos[2])) for s in STEPS]
    sim = SimFlyingCar("cf1", MODEL, pos=steps[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    assert ctrl.load(plan_for("cf1", steps, MODEL, t0=start))
    run(ctrl, sim, start + steps[-1].t + 2.0, Mocap(MocapNoise(pos_std=0.001, dropouts=((0.0, start - 1.0),)), seed=3))
    assert ctrl.held is None, ctrl.held
    assert ctrl.machine.history[0].reason == "pose stale"
    assert ctrl.mode == Mode.DONE and math.dist((sim.x, sim.y, sim.z), steps[-1].pos) < 0.05


class Kept:
    """An executor's publishers where it has no session: what it puts is kept, nothing is sent."""

    def __init__(self) -> None:
        self.sent: list[tuple] = []

    def put(self, *args: object) -> None:
        self.sent.append(args)


def test_the_reflex_to_a_vehicle_its_own_executor_holds_comes_in_the_same_cycle() -> None:
    """An executor's reflex to one of its own vehicles held does not wait for the event to come
    back through the router (on a starved machine 0.25 s: in an 80-vehicle soak cf74 yielded to cf12,
    held by the same executor, that late, and touched it 0.1 s after). This executor has no session at all: its
    other vehicle, whose plan drives to where the held one stands, holds in the same cycle."""
    svc = ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("reflex"))  # never run: no session
    events = svc._event = Kept()
    for name in ("_cmd", "_batch", "_state", "_states", "_delay"):
        setattr(svc, name, Kept())
    shifted = [msgspec.structs.replace(s, pos=(s.pos[0] - 0.15, s.pos[1] - 0.15, s.pos[2])) for s in STEPS]
    for vid, steps in (("cf1", STEPS), ("cf2", shifted)):  # cf2's first drive ends where cf1 is parked
        ctrl = svc.controllers[vid] = VehicleController(vid, MODEL, owner="e1", bank=svc.bank)
        svc.plans[vid] = plan_for(vid, steps, MODEL, t0=T0)
        ctrl.load(svc.plans[vid])
        ctrl.start(T0)
    parked = [FramePose(vid, *steps[0].pos, 0.0) for vid, steps in (("cf1", STEPS), ("cf2", shifted))]

    def cycle(k: int) -> None:
        now = T0 + 0.01 * k
        frame = PoseFrame(t=now - 0.004, seq=k, poses=parked)
        svc._fuse([frame])
        svc._run_clocks(now)
        svc._cycle(now, k, frame.t, frame.t)

    for k in range(50):  # both parked, cf2's drive 0.5 s ahead
        cycle(k)
    assert not svc.controllers["cf2"].held and not events.sent
    svc._on_abort(MissionAbort(mission="sim", reason="cf1: held where it is", vehicles=["cf1"], hold=True), "")
    cycle(50)
    told = {vid: event.detail for vid, event in events.sent if event.kind == "tracking_hold"}
    assert told.keys() == {"cf1", "cf2"}, told
    assert told["cf2"].startswith("yields to cf1, held at (0.00, 0.00, 0.00)"), told
    assert svc.controllers["cf2"].mode == Mode.HOLDING


def starve(pid: int, stop: threading.Event) -> None:
    """Stop and continue process `pid` in turns until `stop` is set (it is left running)."""
    try:
        while not stop.is_set():
            os.kill(pid, signal.SIGSTOP)
            time.sleep(STOP_S)
            os.kill(pid, signal.SIGCONT)
            time.sleep(RUN_S)
    finally:
        os.kill(pid, signal.SIGCONT)


@pytest.mark.flight
@pytest.mark.timeout(240)
def test_a_starved_executor_holds_its_vehicles_and_nothing_touches(tmp_path) -> None:
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)
    marks: dict[str, float] = {}
    owners: dict[str, str] = {}
    runners: list[MissionRunner] = []

    async def scenario(watch: Watch, runner: MissionRunner) -> None:
        runners.append(runner)
        await until(lambda: watch.mode("cf1") == "flying", 60, "cf1 flying")
        await until(airborne(watch, "cf1"), 5, "cf1 at cruise height")
        owner = watch.states["cf1"][-1].owner
        owners.update({vid: watch.states[vid][-1].owner for vid in TOWN_TASKS})
        pid = next(p["pid"] for p in status(fleet.run_dir) if p["instance"] == owner)
        stop = threading.Event()
        marks["starved"] = time.time()
        thread = threading.Thread(target=starve, args=(pid, stop), daemon=True)
        thread.start()
        try:
            await until(lambda: watch.first("cf1", "tracking_hold") is not None or watch.mode("cf1") == "done",
                        20, "cf1 held or done")
            await asyncio.sleep(1.0)
        finally:
            stop.set()
            thread.join()
            marks["fed"] = time.time()

    # the guard's hold itself: a flyer off its plan (not a burst) first pauses its mission by default,
    # and the starved loop, paused, got back within its margin and went on (`tests/test_proximity_pause.py`)
    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="guard", without=NO_RECORDER,
                     extra_args={"executor": ["--no-tracking-pause"]}) as fleet:
        result, watch = fly_mission(fleet, spec, scenario)

    assert result.contacts == 0, result.summary()
    held = watch.first("cf1", "tracking_hold", since=marks["starved"])
    # judged in ground truth: until it was held (or the starvation ended), cf1 stayed near its plan
    plan, t0 = runners[0].first_plan, runners[0].t0
    assert plan is not None and t0 is not None
    states = watch.states["cf1"]

    def plan_time(t: float) -> float:  # (on the plan's clock, which waits for the late: its delay then)
        return t - t0 - max((s.delay for s in states if s.t <= t), default=0.0)

    worst = max(math.dist((s.x, s.y, s.z), plan.position("cf1", plan_time(s.t)))
                for s in watch.truth_between("cf1", marks["starved"], held or marks["fed"]))
    # unguarded 0.22 and 1.37 m (two runs); guarded 8-12 cm on an idle machine (four runs), 8-18 cm
    # beside a busy process (twelve runs, 2026-12-05: three over the 6-margin bound this had, which
    # also failed twice in a row in a CI run): a loop this starved (30 ms of every 200 ms) tracks within the margin
    # until it does not, and the guard judges on poses up to 200 ms late, the vehicle flying on
    # meanwhile; when the error crosses the guard's threshold just after a window, it is held two
    # windows later (0.79 s into the starvation instead of 0.38) and furthest off
    assert worst < 7.0 * plan.model.margin, f"cf1 {worst:.3f} m from its plan"
    assert held is not None, f"the guard did not hold cf1: {watch.kinds('cf1')}"
    # held late on its way, a vehicle comes back once its loop is fed again and stands still; held
    # off its way, it stays out and the mission fails (`VehicleController._on_its_way`)
    holds = {e.vid: e for t, e in watch.events if e.kind == "tracking_hold" and t >= marks["starved"]}
    print({vid: e.detail for vid, e in holds.items()}, result.events)
    for vid, event in holds.items():
        back = any(e.startswith(f"{vid} rejoined") for e in result.events)
        assert back == event.rejoinable == ("late on it" in event.detail), (vid, event, result.events)
        assert result.vehicles[vid].arrived == back, result.summary()
    assert result.ok == all(e.rejoinable for e in holds.values()), result.reason
    for vid in TOWN_TASKS:
        assert watch.at_rest_on_ground(vid), (vid, watch.truth[vid][-1])
    print(f"cf1 held {held - marks['starved']:.2f} s into the starvation of {owners['cf1']}; "
          f"worst truth distance from the plan before it: {worst:.3f} m")
