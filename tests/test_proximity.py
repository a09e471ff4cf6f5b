"""The proximity stop (issue 15, services/executor/proximity.py): a vehicle moving on its plan that
heads into another body, as the motion capture sees them, stops short; one passing by, moving
away, keeping its distance or standing still does not."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

import msgspec
import numpy as np
import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.messages import FramePose, PoseFrame, VehicleState, VehicleStates
from common.bus.pubsub import Publisher
from common.bus.session import ZenohConfig
from common.domain.planfile import Task
from common.domain.vehicle_model import Speeds, VehicleModel
from common.flight.modes import Mode
from services.executor import vehicle_controller
from services.executor.faults import in_way
from services.executor.proximity import Bodies, ProximityParams, standing
from services.executor.service import BODIES_FRESH_S, ExecutorService
from services.executor.vehicle_controller import VehicleController
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.closed_loop import Mocap, on_reference_plan, plan_for, reference_steps, run
from tests.support.fleet_faults import NO_RECORDER, TOWN_TASKS, Watch, until
from tests.support.fleet_faults import fly as fly_mission

RADIUS, HEIGHT = 0.045, 0.02  # the shipped maps' bodies (envelope 0.06 x 0.05, margin 0.03)
DT = 0.01


def frames(bodies: Bodies, moves: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]],
           seconds: float = 0.3, t0: float = 100.0) -> float:
    """Feed `bodies` `seconds` of frames of bodies moving at a constant velocity to where `moves`
    says they are at the end; the last frame's time."""
    t = t0
    n = round(seconds / DT)
    for k in range(n + 1):
        t = t0 + k * DT
        poses = [FramePose(vid, *(np.add(p, np.multiply(v, (k - n) * DT))).tolist(), 0.0)
                 for vid, (p, v) in moves.items()]
        bodies.update(PoseFrame(t=t, seq=k, poses=poses))
        bodies.settle(t)
    return t


def closing(bodies: Bodies, velocities: dict[str, tuple[float, float, float]], now: float,
            react_s: float = 0.15) -> list:
    """(A loaded executor's reaction by default: the 80-vehicle soak's pose-to-command p99.)"""
    movers = list(velocities)
    v = np.array([[velocities[m], velocities[m]] for m in movers])
    return bodies.closing(movers, v, RADIUS, HEIGHT, now, react_s)


def test_velocities_are_measured_from_the_frames() -> None:
    bodies = Bodies()
    frames(bodies, {"a": ((0.0, 0.0, 0.0), (0.1, -0.05, 0.0)), "b": ((1.0, 0.0, 0.3), (0.0, 0.0, 0.2))})
    assert bodies.vel[bodies.rows["a"]] == pytest.approx((0.1, -0.05, 0.0), abs=1e-6)
    assert bodies.vel[bodies.rows["b"]] == pytest.approx((0.0, 0.0, 0.2), abs=1e-6)


def test_a_vehicle_driving_on_into_one_that_stalled_stops_short() -> None:
    """The 80-vehicle soak's contact (docs/reliability.md): a leader stalled behind its plan, the
    follower on time drives on into it."""
    bodies = Bodies()
    gap = 0.025  # under a margin (the plan's 3 cm) and closing at driving speed: 1.75 cm before it stops
    now = frames(bodies, {"follower": ((0.0, 0.0, 0.0), (0.1, 0.0, 0.0)),
                          "leader": ((2 * RADIUS + gap, 0.0, 0.0), (0.0, 0.0, 0.0))})
    [(mover, other, at, speed, _, _, _)] = closing(bodies, {"follower": (0.1, 0.0, 0.0)}, now)
    assert (mover, other) == ("follower", "leader") and at == pytest.approx(gap, abs=1e-6) and speed == pytest.approx(0.1)
    # an executor that reacts within 30 ms stops it later: 1.55 cm before contact, not yet
    assert closing(bodies, {"follower": (0.1, 0.0, 0.0)}, now, react_s=0.03) == []
    # the leader, standing, is not the one to stop; on the move away from the follower neither
    assert closing(bodies, {"leader": (0.0, 0.0, 0.0)}, now) == []
    assert closing(bodies, {"leader": (0.1, 0.0, 0.0)}, now) == []


def test_while_the_frames_stall_a_vehicle_driving_on_into_a_body_stops_short() -> None:
    """The 80-vehicle soak's contact on the proximity stop's code (docs/reliability.md): the motion
    capture stalled for a tenth of a second, the follower drove on on its estimate into a vehicle
    stopped before it. The judgement goes on without frames, over the age of the newest one."""
    bodies = Bodies()
    gap, v = 0.04, (0.1, 0.0, 0.0)
    now = frames(bodies, {"follower": ((0.0, 0.0, 0.0), v), "leader": ((2 * RADIUS + gap, 0.0, 0.0), (0.0, 0.0, 0.0))})
    assert bodies.reaction(now + 0.005, 0.02, 0.01) == pytest.approx(0.03)  # the executor's p99 and a period
    assert closing(bodies, {"follower": v}, now + 0.005, bodies.reaction(now + 0.005, 0.02, 0.01)) == []
    # no frame for 0.3 s: the follower has driven on 3 cm of its 4 on its estimate
    react = bodies.reaction(now + 0.3, 0.02, 0.01)
    assert react == pytest.approx(0.31)
    [hit] = closing(bodies, {"follower": v}, now + 0.3, react)
    assert (hit.mover, hit.other) == ("follower", "leader") and hit.gap == pytest.approx(gap, abs=1e-6)


def test_a_vehicle_driving_in_under_a_fault_landings_descent_stops_short() -> None:
    """An 80-vehicle soak's contact under a lost link's landing (docs/reliability.md): a driver
    went on towards the spot a vehicle was coming down on, that vehicle counted as standing (a
    body coming closer is its own executor's to stop, but no proximity stop stops a fault
    landing's descent), and it came down on the driver, 12 cm deep. Counted as going on (its
    executor's state says it is in a fault landing), its descent stops the driver short."""
    bodies = Bodies()
    down, v = (0.0, 0.0, -0.25), (0.0, -0.07, 0.0)
    now = frames(bodies, {"lander": ((0.0, 0.0, 0.06), down), "driver": ((0.0, 2 * RADIUS + 0.02, 0.0), v)})
    assert closing(bodies, {"driver": v}, now, react_s=0.19) == []  # standing 6 cm above the driver's level
    [hit] = bodies.closing(["driver"], np.array([[v, v]]), RADIUS, HEIGHT, now, 0.19, going_on=lambda: {"lander"})
    assert (hit.mover, hit.other) == ("driver", "lander") and hit.v_other == pytest.approx(down, abs=1e-6)
    # one the driver moves away from, or comes down clear of its way, does not stop it
    assert bodies.closing(["driver"], np.array([[(0.0, 0.07, 0.0)] * 2]), RADIUS, HEIGHT, now, 0.19,
                          going_on=lambda: {"lander"}) == []
    away = Bodies()
    now = frames(away, {"lander": ((0.0, 0.0, 0.06), down), "driver": ((0.0, 2 * RADIUS + 0.2, 0.0), v)})
    assert away.closing(["driver"], np.array([[v, v]]), RADIUS, HEIGHT, now, 0.19, going_on=lambda: {"lander"}) == []


@pytest.mark.timeout(30)
def test_the_executor_counts_other_executors_fault_and_emergency_landings_as_going_on(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    """Heard in another executor's states: cf2 in a fault landing (its `landing` spot), cf3 in an
    emergency landing, cf4 flying on its plan. The first two go on (`_going_on`), until a state
    says otherwise (cf2 landed) or none comes for `BODIES_FRESH_S`; and so does its own cf1 once
    it comes down in an emergency landing."""
    keys = Keys("proximity")

    def state(vid: str, mode: str, landing: tuple[float, float, float] | None = None) -> VehicleState:
        return VehicleState(vid=vid, t=0.0, owner="e2", mode=mode, x=1.0, y=1.0, z=0.5, yaw=0.0, landing=landing)

    async def scenario() -> list[set[str]]:
        svc = ExecutorService("e1", ZenohConfig.client(zenoh_router), keys)
        run_svc = asyncio.create_task(svc.run())
        theirs = Publisher(zsession(), keys.executor_states("e2"), VehicleStates)
        heard: list[set[str]] = []
        try:
            for states in ([state("cf2", "landing", (1.0, 1.5, 0.0)), state("cf3", "emergency_landing"),
                            state("cf4", "flying")],
                           [state("cf2", "done"), state("cf3", "emergency_landing"), state("cf4", "flying")]):
                for _ in range(100):  # until the executor has heard it (the first may go before it subscribed)
                    theirs.put(VehicleStates(owner="e2", t=0.0, states=states))
                    await asyncio.sleep(0.02)
                    if svc._unstopped and ("cf2" in svc._unstopped) == (states[0].landing is not None):
                        break
                heard.append(svc._going_on(time.time()))
            heard.append(svc._going_on(time.time() + BODIES_FRESH_S + 0.1))
        finally:
            svc.stop()
            assert await run_svc == 0
        own = svc.controllers["cf1"] = VehicleController("cf1", VehicleModel(), owner="e1")  # (its loop stopped)
        heard.append(svc._going_on(time.time()))
        own.machine.resume(Mode.EMERGENCY_LANDING, 0.0, "pose stale in the air")
        heard.append(svc._going_on(time.time()))
        return heard

    assert asyncio.run(scenario()) == [{"cf2", "cf3"}, {"cf3"}, set(), {"cf3"}, {"cf1", "cf3"}]


@pytest.mark.parametrize(("what", "follower", "leader", "v_follower"), [
    ("farther than the horizon reaches", (0.0, 0.0, 0.0), (2 * RADIUS + 0.05, 0.0, 0.0), (0.1, 0.0, 0.0)),
    ("keeping its distance in a convoy", (0.0, 0.0, 0.0), (2 * RADIUS + 0.02, 0.0, 0.0), (0.1, 0.0, 0.0)),
    ("passing by in the other direction", (0.0, 0.0, 0.0), (0.4, 2 * RADIUS + 0.03, 0.0), (0.3, 0.0, 0.0)),
    ("flying over it", (0.0, 0.0, HEIGHT + 0.03), (0.03, 0.0, 0.0), (0.3, 0.0, 0.0)),
    ("taking off beside it", (0.0, 0.0, 0.0), (2 * RADIUS + 0.03, 0.0, 0.0), (0.0, 0.0, 0.2)),
])
def test_no_stop_for_a_vehicle(what: str, follower, leader, v_follower) -> None:
    bodies = Bodies()
    v_leader = (0.1, 0.0, 0.0) if what.startswith("keeping") else (-0.3, 0.0, 0.0) if what.startswith("passing") else (0.0, 0.0, 0.0)
    now = frames(bodies, {"follower": (follower, v_follower), "leader": (leader, v_leader)})
    assert closing(bodies, {"follower": v_follower}, now) == [], what


def corner(v: float, t_corner: float) -> Callable[[str, np.ndarray], np.ndarray]:
    """A plan straight on along +x at `v` m/s that turns to +y at `t_corner` s: its bend."""
    def bend(_vid: str, taus: np.ndarray) -> np.ndarray:
        past = np.maximum(taus - t_corner, 0.0)
        return np.stack((-v * past, v * past, 0.0 * taus), axis=1)
    return bend


def test_a_vehicle_is_judged_on_its_way_bent_as_its_plan_bends() -> None:
    """Judged on a straight line, a vehicle on time into a corner beside a body its plan passes 5
    cm away heads into it and stops (the first hold of 80-vehicle soaks that failed, 2026-12-07);
    its way bent as its plan turns passes the body by. A body its plan turns towards stops it,
    one it passes straight by does not."""
    v = (0.3, 0.0, 0.0)
    ahead = (0.03 + 2 * RADIUS + 0.05, 0.0, 0.0)  # 5 cm beyond the corner, 3 cm (0.1 s) ahead
    bodies = Bodies()
    now = frames(bodies, {"car": ((0.0, 0.0, 0.0), v), "parked": (ahead, (0.0, 0.0, 0.0))})
    [hit] = bodies.closing(["car"], np.array([[v, v]]), RADIUS, HEIGHT, now, 0.15)
    assert (hit.mover, hit.other) == ("car", "parked") and hit.gap == pytest.approx(0.08, abs=1e-6)
    assert bodies.closing(["car"], np.array([[v, v]]), RADIUS, HEIGHT, now, 0.15, bend=corner(0.3, 0.1)) == []
    beside = (0.03, 2 * RADIUS + 0.05, 0.0)  # 5 cm beside the corner: passed straight by, turned into
    bodies = Bodies()
    now = frames(bodies, {"car": ((0.0, 0.0, 0.0), v), "parked": (beside, (0.0, 0.0, 0.0))})
    assert bodies.closing(["car"], np.array([[v, v]]), RADIUS, HEIGHT, now, 0.15) == []
    [hit] = bodies.closing(["car"], np.array([[v, v]]), RADIUS, HEIGHT, now, 0.15, bend=corner(0.3, 0.1))
    assert (hit.mover, hit.other) == ("car", "parked") and hit.speed > 0.1


def test_a_flyer_on_time_into_its_hover_beside_a_body_does_not_stop_short() -> None:
    """The controller's bend (`VehicleController.bend`, from the reference it follows): flying on
    time at 0.3 m/s 4 cm before the node where its plan hovers, 3 cm short of a body hovering
    beyond it, the flyer does not stop; straight on it would have. A body on its way before that
    node stops it."""
    steps, sim, ctrl = on_reference_plan(VehicleModel(margin=0.03))
    a2 = next(s for s in steps if s.node == "a2")
    records = run(ctrl, sim, 0.5 + a2.t - 0.04 / 0.3)
    assert ctrl.mode == Mode.FLYING
    motion = ctrl.motion()
    assert motion is not None and motion[3:] == pytest.approx((0.3, 0.0, 0.0), abs=0.01)
    assert motion[:3] == pytest.approx((0.3, 0.0, 0.0), abs=0.03)  # on time

    def judged(body: tuple[float, float, float], bend: bool) -> list:
        bodies = Bodies()
        for k, r in enumerate(records[-31:]):
            bodies.update(PoseFrame(t=r.t, seq=k, poses=[FramePose("cf1", r.truth.x, r.truth.y, r.truth.z, 0.0),
                                                          FramePose("cf9", *body, 0.0)]))
            bodies.settle(r.t)
        motion = np.array(ctrl.motion()).reshape(1, 2, 3)
        return bodies.closing(["cf1"], motion, RADIUS, HEIGHT, records[-1].t, 0.15,
                              bend=(lambda _vid, taus: ctrl.bend(taus)) if bend else None)

    beyond = (a2.pos[0] + 2 * RADIUS + 0.03, a2.pos[1], a2.pos[2])
    assert [h.other for h in judged(beyond, bend=False)] == ["cf9"]
    assert judged(beyond, bend=True) == []
    on_its_way = (records[-1].truth.x + 2 * RADIUS + 0.03, a2.pos[1], a2.pos[2])  # 3 cm ahead, where it goes
    assert [h.other for h in judged(on_its_way, bend=True)] == ["cf9"]


def test_a_stop_short_says_how_a_body_stood_as_its_executor_last_told() -> None:
    """The report of a proximity stop names each body's mode, hold, distance from its reference and
    plan clock's delay (`standing`): the one off its plan shows without a trace."""
    told = VehicleState(vid="cf2", t=99.96, owner="e2", mode="driving", x=0.0, y=0.0, z=0.0, yaw=0.0,
                        tracking_error=0.123, delay=1.5)
    assert standing("cf2", told, 100.0) == "cf2: driving, 12.3 cm from its reference, clock 1.50 s behind, 40 ms ago"
    held = msgspec.structs.replace(told, mode="holding", held="tracking error 0.12 m", tracking_error=0.0)
    assert standing("cf2", held, 100.0) == "cf2: holding, held, 0.0 cm from its reference, clock 1.50 s behind, 40 ms ago"
    assert standing("cf3", None, 100.0) == "cf3: no state"


def test_a_body_the_motion_capture_lost_is_not_counted() -> None:
    bodies = Bodies()
    now = frames(bodies, {"follower": ((0.0, 0.0, 0.0), (0.1, 0.0, 0.0)),
                          "leader": ((2 * RADIUS + 0.035, 0.0, 0.0), (0.0, 0.0, 0.0))})
    later = frames(bodies, {"follower": ((0.12, 0.0, 0.0), (0.1, 0.0, 0.0))}, seconds=1.2, t0=now)
    assert closing(bodies, {"follower": (0.1, 0.0, 0.0)}, later) == []


def test_a_vehicle_told_to_stop_short_holds_where_it_is() -> None:
    model = VehicleModel(margin=0.03)
    steps = reference_steps(model)
    sim = SimFlyingCar("cf1", model, pos=steps[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", model, owner="test")
    ctrl.load(plan_for("cf1", steps, model, t0=0.5))
    run(ctrl, sim, 2.5)  # (parked for a second, then on the road)
    assert ctrl.mode == Mode.DRIVING and ctrl.motion() is not None
    assert ctrl.stop_short("stops short of cf9")
    run(ctrl, sim, 3.5)
    assert ctrl.mode == Mode.HOLDING and ctrl.held == "stops short of cf9"
    assert ctrl.motion() is None and not ctrl.stop_short("again")
    held = (sim.x, sim.y)
    run(ctrl, sim, 5.0)
    assert np.hypot(sim.x - held[0], sim.y - held[1]) < 0.005


@pytest.mark.parametrize(("edge", "speed"), [("fly", 0.15), ("fly", 0.3), ("fly", 0.45), ("fly", 0.6),
                                             ("drive", 0.1), ("drive", 0.15)])
def test_a_vehicle_stopped_short_comes_to_rest_within_the_way_the_stop_counted(edge: str, speed: float) -> None:
    """The proximity stop looks ahead as far as a vehicle goes once it holds (`Bodies.stop_time`):
    flying or driving on its plan at `speed`, told to stop short, it comes to rest (ground truth)
    within that way and the control period the hold takes to start. (Counted at a brake of 2 m/s^2
    alone, the flight LQR's hold from 0.3 m/s went 3.1 cm where 2.3 cm were counted.)"""
    model = VehicleModel(margin=0.05, speed=Speeds(**{edge: speed}))
    steps = reference_steps(model)
    k = next(i for i, s in enumerate(steps) if s.edge == edge)
    sim = SimFlyingCar("cf1", model, pos=steps[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", model, owner="test")
    ctrl.load(plan_for("cf1", steps, model, t0=0.5))
    run(ctrl, sim, 0.5 + (steps[k - 1].t + steps[k].t) / 2)  # half way along the edge
    truth = sim.truth()
    at, v = np.array([truth.x, truth.y, truth.z]), np.array([truth.vx, truth.vy, truth.vz])
    moving = float(np.linalg.norm(v))
    assert abs(moving - speed) < 0.02, moving
    assert ctrl.stop_short("stops short of cf9")
    went = max(float(np.dot([r.truth.x, r.truth.y, r.truth.z] - at, v / moving)) for r in run(ctrl, sim, sim.t + 1.5))
    counted = moving * (DT + float(Bodies().stop_time(moving)))
    assert went <= counted, (went, counted)


@pytest.mark.flight
@pytest.mark.timeout(180)
def test_a_vehicle_stops_short_of_a_body_its_plan_did_not_know(tmp_path) -> None:
    """A vehicle left on cf3's goal, unknown to the mission (not in its tasks): cf3's plan drives
    into it. cf3 stops short, held and reported, and nothing touches in ground truth. The mission
    does not bring cf3 back (`Replan.rejoin`): it sees cf4 in the motion capture's frames, where
    cf3's way goes. (With the guard's switch off, `--no-tracking-guard`, cf3 drove into it: checked
    by hand, 2026-12-05.)"""
    tasks = {**TOWN_TASKS, "cf4": Task(start="WP3", goal="WP3")}  # parked on cf3's goal
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)

    async def scenario(watch: Watch, runner: MissionRunner) -> None:
        await until(lambda: watch.first("cf3", "tracking_hold") is not None or watch.mode("cf3") == "done",
                    60, "cf3 held or done")
        await asyncio.sleep(1.0)

    with local_fleet("town", tasks, tmp_path / "run", executors=2, fleet="proximity", without=NO_RECORDER) as fleet:
        result, watch = fly_mission(fleet, spec, scenario)

    assert not watch.contacts, watch.separation_line()
    # the mission's own judge (the simulator's `sim/truths` frames) saw it too, cf4 outside its tasks
    assert 0.0 < result.min_gap < 0.05 and set(result.min_pair) == {"cf3", "cf4"}, (result.min_gap, result.min_pair)
    [held] = [e for _t, e in watch.events if e.vid == "cf3" and e.kind == "tracking_hold"]
    assert held.detail.startswith("stops short of cf4"), held.detail
    # how each stood, to tell which was off its plan: cf3 on its way, cf4 reported by no executor
    assert "; cf3: driving, " in held.detail and held.detail.endswith("; cf4: no state"), held.detail
    assert any(e.startswith("cf3 not back yet") and "crosses where cf4 may be" in e for e in result.events), \
        result.events  # cf4 is outside the mission: the mission sees it in the motion capture's frames
    assert not any(e.startswith("cf3 rejoined") for e in result.events), result.events
    assert not result.ok
    for vid in tasks:
        assert watch.at_rest_on_ground(vid), (vid, watch.truth[vid][-1])
    print(held.detail, "|", watch.separation_line())


def test_a_held_hover_too_near_another_body_is_pushed_away_level() -> None:
    """`Bodies.push_apart`: a hover point 1 cm from a body beside it moves 3 cm directly away (to the
    4 cm standoff), level; not for a body far enough above, nor one the motion capture lost, nor
    when the move would take it nearer to a body on its other side (squeezed: it stays)."""
    at = (0.0, 0.0, 0.5)
    beside = (2 * RADIUS + 0.01, 0.0, 0.5)
    bodies = Bodies()
    now = frames(bodies, {"cf1": (at, (0.0, 0.0, 0.0)), "cf2": (beside, (0.0, 0.0, 0.0))})
    assert bodies.push_apart("cf1", at, RADIUS, HEIGHT, now) == pytest.approx((-0.03, 0.0), abs=1e-9)
    assert bodies.push_apart("cf1", at, RADIUS, HEIGHT, now + 1.1) is None  # (cf2 not seen for fresh_s)
    far_above = (0.01, 0.0, 0.5 + HEIGHT + 0.05)
    bodies = Bodies()
    now = frames(bodies, {"cf1": (at, (0.0, 0.0, 0.0)), "cf2": (far_above, (0.0, 0.0, 0.0))})
    assert bodies.push_apart("cf1", at, RADIUS, HEIGHT, now) is None
    other_side = (-(2 * RADIUS + 0.02), 0.0, 0.5)
    bodies = Bodies()
    now = frames(bodies, {"cf1": (at, (0.0, 0.0, 0.0)), "cf2": (beside, (0.0, 0.0, 0.0)),
                          "cf3": (other_side, (0.0, 0.0, 0.0))})
    assert bodies.push_apart("cf1", at, RADIUS, HEIGHT, now) is None


@pytest.mark.parametrize("standoff", [True, False])
def test_two_vehicles_held_hovering_near_each_other_move_apart(standoff: bool) -> None:
    """Two flyers held hovering side by side 2 cm apart (each stopped short of the other, as in an
    80-vehicle soak where two held 2.7 cm apart wandered into each other): the executor moves each
    one's hover point away from the other (`ExecutorService._keep_apart`), and in ground truth they
    come to rest at least the standoff apart, each within `standoff_reach` of where it was held.
    Without the standoff they stay 2 cm apart."""
    model = VehicleModel(margin=0.03)
    radius, _height = model.body()
    proximity = ProximityParams() if standoff else ProximityParams(standoff=0.0)
    svc = ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("standoff"), proximity=proximity)
    beside = 2 * radius + 0.02
    loops = []
    for k, vid in enumerate(("cf1", "cf2")):
        steps = [msgspec.structs.replace(s, pos=(s.pos[0], s.pos[1] + k * beside, s.pos[2]))
                 for s in reference_steps(model)]
        sim = SimFlyingCar(vid, model, pos=steps[0].pos, yaw=0.0)
        ctrl = svc.controllers[vid] = VehicleController(vid, model, owner="e1")
        ctrl.load(plan_for(vid, steps, model, t0=0.5))
        a2 = next(s for s in steps if s.node == "a2")
        run(ctrl, sim, 0.5 + a2.t + 0.5)  # waiting at a2
        assert ctrl.stop_short(f"stops short of cf{2 - k}")
        run(ctrl, sim, sim.t + 0.05)
        assert ctrl.mode == Mode.HOVERING and ctrl.held_hover() is not None
        loops.append((ctrl, sim, Mocap(seed=k)))
    held = [(sim.x, sim.y) for _ctrl, sim, _m in loops]
    gaps = []
    for k in range(300):
        now = loops[0][1].t
        svc.bodies.update(PoseFrame(t=now, seq=k, poses=[FramePose(sim.vid, sim.x, sim.y, sim.z, 0.0)
                                                         for _ctrl, sim, _m in loops]))
        svc.bodies.settle(now)
        svc._keep_apart(now)
        for ctrl, sim, mocap in loops:
            run(ctrl, sim, now + DT, mocap=mocap)
        (_, a, _), (_, b, _) = loops
        gaps.append(math.hypot(a.x - b.x, a.y - b.y) - 2 * radius)
    assert all(ctrl.held and ctrl.mode == Mode.HOVERING for ctrl, _sim, _m in loops)
    moved = [math.hypot(sim.x - x, sim.y - y) for (_c, sim, _m), (x, y) in zip(loops, held, strict=True)]
    if standoff:  # (the shipped 4 cm and 5 cm)
        assert min(gaps[-100:]) >= 0.035, min(gaps[-100:])
        assert max(moved) <= 0.055, moved
    else:
        assert max(gaps[-100:]) < 0.03, max(gaps[-100:])


@pytest.mark.parametrize("kept_off", [True, False])
def test_a_held_flyer_blown_off_its_hover_point_does_not_fly_back_through_a_body(
        kept_off: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """cf1, held hovering, is blown 30 cm off its hover point (a gust here; a stall of its
    executor in an 80-vehicle soak), and a body is seen between it and that point: it waits where
    it is (`VehicleController._keep_off_the_way_back`), and in ground truth never comes within
    contact; once the body is gone it goes back to its point. Without it, it flew straight back
    through the body."""
    if not kept_off:
        monkeypatch.setattr(vehicle_controller, "ASTRAY_M", math.inf)
    model = VehicleModel(margin=0.03)
    radius, height = model.body()
    steps = reference_steps(model)
    seen: list[tuple[float, float, float]] = []
    sim = SimFlyingCar("cf1", model, pos=steps[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", model, owner="test", bodies=lambda: seen)
    ctrl.load(plan_for("cf1", steps, model, t0=0.5))
    a2 = next(s for s in steps if s.node == "a2")
    run(ctrl, sim, 0.5 + a2.t + 0.5)  # waiting at a2
    assert ctrl.stop_short("stops short of cf9")
    run(ctrl, sim, sim.t + 0.05)
    point = ctrl.held_hover()
    assert point is not None
    sim.push(0.0, 5.0, sim.t + 0.5)
    run(ctrl, sim, sim.t + 0.5)
    assert sim.y - point[1] > 0.3, sim.y - point[1]
    body = (point[0], point[1] + 0.145, point[2])  # 5.5 cm clear of its hover point, on its way back
    seen.append(body)
    records = run(ctrl, sim, sim.t + 3.0)
    nearest = min(math.hypot(r.truth.x - body[0], r.truth.y - body[1]) - 2 * radius for r in records
                  if abs(r.truth.z - body[2]) < height)
    assert ctrl.held and ctrl.mode == Mode.HOVERING
    if not kept_off:
        assert nearest < 0.0, nearest
        return
    assert nearest > 0.0, nearest  # (2.0 cm clear: it overshoots where it waits, coming back from 1 m/s)
    seen.clear()
    run(ctrl, sim, sim.t + 3.0)
    assert math.hypot(sim.x - point[0], sim.y - point[1]) < 0.01


def test_only_a_body_between_a_held_flyer_and_its_hover_point_is_on_its_way_back() -> None:
    """`faults.in_way(..., beyond=False)`, as `VehicleController._keep_off_the_way_back` asks: a body
    between the flyer and its point is on its way; one just past the point is not (it is the
    standoff's: in an 80-vehicle soak a held flyer that braked 5.8 cm past its point waited there,
    towards the body it had yielded to, for one past its point, and touched the first 40 ms
    later), though a fault landing's flight counts it."""
    model = VehicleModel(margin=0.03)
    here, point = (0.0, 0.0, 0.5), (0.1, 0.0, 0.5)
    between, past = (0.05, 0.03, 0.5), (0.2, 0.0, 0.5)
    assert in_way(here, point, between, model, beyond=False)
    assert not in_way(here, point, past, model, beyond=False)
    assert in_way(here, point, past, model)
