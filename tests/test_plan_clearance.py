"""The proximity stop judged once more on the plans (issue 15, services/executor/plan_clearance.py):
two vehicles keeping to plans that keep them apart go on, however the motion capture's view of
them alone foretells a touch; one off its plan, held, stalled or unheard is judged as before."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from common.bus.keys import Keys
from common.bus.messages import FramePose, PlanStep, PoseFrame, VehicleState
from common.bus.session import ZenohConfig
from common.domain.vehicle_model import VehicleModel
from common.flight.modes import Mode
from services.executor.plan_clearance import drift_time, nearest, on_its_way
from services.executor.proximity import Closing, ProximityParams
from services.executor.service import STATE_FRESH_S, ExecutorService
from services.executor.trajectory import Trajectory
from services.executor.vehicle_controller import VehicleController
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.closed_loop import Mocap, plan_for, reference_steps, run
from tests.support.sent import SentMessages

MODEL = VehicleModel(margin=0.03)
GX, GY = -1.0, 0.0
DT = 0.01
CROSSING = (1.4, 0.45)
"""Where the two flyers' ways cross: cf1 flies along +x (the reference plan's flight), cf2 along +y."""
AHEAD_S = 0.57
"""s by which cf2 crosses before cf1: at 0.3 m/s each their centres come 0.121 m near, their bodies
(radius 0.045) 3.1 cm: the plans' 3 cm margin."""


def crossing_steps() -> dict[str, list[PlanStep]]:
    """cf1's reference plan, and cf2's: the same turned a quarter about `CROSSING` (its flight along
    +y through it) and AHEAD_S s earlier after its first wait."""
    steps = reference_steps(MODEL)
    cx, cy = CROSSING

    def turned(s: PlanStep, k: int) -> PlanStep:
        x, y, z = s.pos
        return msgspec.structs.replace(s, pos=(cx - (y - cy), cy + (x - cx), z), t=s.t - AHEAD_S * (k > 0))
    return {"cf1": steps, "cf2": [turned(s, k) for k, s in enumerate(steps)]}


def fly_crossing(trust: bool, hold_cf2_at: float | None = None, react: float = 0.1, pause: bool = True,
                 gust: float = 0.0) -> tuple[ExecutorService, float]:
    """Both flyers in one executor, judged by its proximity stop every cycle on their bodies in
    ground truth, their plan's clock run by it, until cf1 is past the crossing (or held): the
    executor and the nearest their bodies came (m, ground truth). `hold_cf2_at`: cf2 stops short
    that far (m) before the crossing, as a vehicle its executor holds; `gust`: cf2 is blown
    towards cf1's side at that acceleration (m/s^2) as it comes to the crossing."""
    svc = ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("clearance"),
                          proximity=ProximityParams(trust_plans=trust, pause=pause))
    svc._delay = SentMessages()  # (one executor: its clock's delay told to no one)
    svc.stats.add_latency(react, react)  # a loaded executor's pose-to-command p99 (80-vehicle soaks: 0.07-0.1 s)
    radius, height = MODEL.body()
    loops = []
    for k, (vid, steps) in enumerate(crossing_steps().items()):
        sim = SimFlyingCar(vid, MODEL, pos=steps[0].pos, yaw=0.0)
        ctrl = svc.controllers[vid] = VehicleController(vid, MODEL, owner="e1")
        ctrl.load(plan := plan_for(vid, steps, MODEL, t0=0.5))
        svc.plans[vid] = plan
        loops.append((ctrl, sim, Mocap(seed=k)))
    (_, sim1, _), (cf2, sim2, _) = loops
    a1 = next(s for s in crossing_steps()["cf1"] if s.node == "a1")
    end = 0.5 + a1.t + (CROSSING[0] - a1.pos[0] + 0.4) / 0.3
    closest = math.inf
    k = 0
    while sim1.t < end:
        now = sim1.t
        svc.bodies.update(PoseFrame(t=now, seq=k, poses=[FramePose(s.vid, s.x, s.y, s.z, 0.0) for _c, s, _m in loops]))
        svc.bodies.settle(now)
        if hold_cf2_at is not None and not cf2.held and sim2.z > 0.4 and CROSSING[1] - sim2.y < hold_cf2_at:
            assert cf2.stop_short("held by its executor")
        if gust and sim2.z > 0.4 and abs(CROSSING[1] - 0.12 - sim2.y) < 0.005:
            sim2.push(GX * gust, GY * gust, now + 0.2)
        svc._end_pauses(now)
        svc._stop_short(now)
        svc._run_clocks(now)
        for ctrl, sim, mocap in loops:
            run(ctrl, sim, now + DT, mocap=mocap)
        if abs(sim1.z - sim2.z) < height:
            closest = min(closest, math.hypot(sim1.x - sim2.x, sim1.y - sim2.y) - 2 * radius)
        k += 1
    return svc, closest


@pytest.mark.parametrize("trust", [True, False])
def test_two_flyers_on_plans_that_cross_at_their_margin_go_on(trust: bool) -> None:
    """cf2 crosses cf1's way 0.57 s before it, the plans 3.1 cm apart at their nearest. Seen from
    the motion capture alone, cf2 at the crossing stands in cf1's way, and cf1 stopped short
    (each of four failed 80-vehicle soaks began with such a stop, 2026-12-07); judged on the
    plans, both keep to theirs and go on, and in ground truth their bodies never touch."""
    svc, closest = fly_crossing(trust, pause=False)
    cf1, cf2 = svc.controllers["cf1"], svc.controllers["cf2"]
    if not trust:
        assert cf1.held and "stops short of cf2" in cf1.held, cf1.held
        return
    assert not cf1.held and not cf2.held and cf1.mode == cf2.mode == Mode.FLYING
    assert svc.counters.get("proximity_kept_apart_by_plans") > 0
    assert 0.015 < closest < 0.045, closest


def test_a_flyer_crossing_the_way_of_one_held_off_its_plan_stops_short() -> None:
    """cf2 is held hovering 2 cm before the crossing (its plan goes on without it): it keeps to no
    plan, and cf1 is judged as before: it stops short, and in ground truth they never touch."""
    svc, closest = fly_crossing(True, hold_cf2_at=0.02)
    cf1 = svc.controllers["cf1"]
    assert cf1.held and "stops short of cf2" in cf1.held, cf1.held
    assert closest > 0.0, closest


def state(mode: str = "flying", t: float = 100.0, **kw) -> VehicleState:
    return VehicleState(vid="cf2", t=t, owner="e2", mode=mode, x=0.0, y=0.0, z=0.5, yaw=0.0, mission="sim", **kw)


@pytest.mark.parametrize(("why", "heard", "mission", "keeps"), [
    ("on its plan, heard 0.1 s ago", state(), "sim", True),
    ("parked before its mission", state("parked"), "sim", True),
    ("heard too long ago: its executor may have stalled", state(t=100.0 - STATE_FRESH_S - 0.05), "sim", False),
    ("held", state("hovering", held="stops short of cf1"), "sim", False),
    ("in a fault landing", state("landing", landing=(1.0, 1.0, 0.0)), "sim", False),
    ("in an emergency landing", state("emergency_landing"), "sim", False),
    ("without a pose", state(pose_ok=False), "sim", False),
    ("in another mission", state(), "other", False),
])
def test_another_executors_vehicle_keeps_to_its_plan_by_its_state(why: str, heard: VehicleState, mission: str,
                                                                   keeps: bool) -> None:
    svc = ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("clearance"))
    svc.plans["cf2"] = plan_for("cf2", crossing_steps()["cf2"], MODEL, t0=0.5)
    svc._heard["cf2"] = heard
    assert (svc._keeping_to_plan("cf2", mission, 100.1) is not None) == keeps, why


def test_another_executors_vehicle_on_a_plan_no_executor_can_follow_keeps_to_none() -> None:
    """A plan with two entries at one time (no trajectory can be made of it) is no plan to judge on."""
    svc = ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("clearance"))
    steps = crossing_steps()["cf2"]
    svc.plans["cf2"] = plan_for("cf2", [*steps[:2], msgspec.structs.replace(steps[2], t=steps[1].t)], MODEL, t0=0.5)
    svc._heard["cf2"] = state()
    assert svc._keeping_to_plan("cf2", "sim", 100.1) is None


def test_a_vehicle_goes_on_along_its_plan_offset_and_drifting_as_now() -> None:
    """`on_its_way`: on a reference along +x at 0.3 m/s, a vehicle 1 cm beside it at its speed goes
    on 1 cm beside; one stalled (at rest) lags its reference by its speed for the reaction (0.1 s),
    then less and less (`drift_time`); one farther than the margin is not judged on its plan.
    Through a corner (to +y) the reference's own turn is no drift: a vehicle on it goes on along it."""
    way = Trajectory([PlanStep("a", 0.0, (0.0, 0.0, 0.5), "air"), PlanStep("b", 10.0, (3.0, 0.0, 0.5), "air", "fly"),
                      PlanStep("c", 20.0, (3.0, 3.0, 0.5), "air", "fly")])
    taus = np.linspace(0.0, 0.2, 5)
    beside = on_its_way(way, np.array([1.5, 0.01, 0.5]), np.array([0.3, 0.0, 0.0]), 5.0, 1.0, taus, 0.03, 0.1, 0.1, 0.12)
    assert beside is not None and beside[-1] == pytest.approx((1.56, 0.01, 0.5))
    stalled = on_its_way(way, np.array([1.49, 0.0, 0.5]), np.zeros(3), 5.0, 1.0, taus, 0.03, 0.1, 0.1, 0.12)
    lag = drift_time(taus, 0.1, 0.12)
    assert lag[:3] == pytest.approx(taus[:3]) and lag[-1] == pytest.approx(0.1 + 0.12 * (1.0 - math.exp(-0.1 / 0.12)))
    assert stalled is not None and np.allclose(stalled[:, 0], 1.49 + 0.3 * (taus - lag)) and stalled[-1, 0] < 1.5
    assert on_its_way(way, np.array([1.5, 0.04, 0.5]), np.array([0.3, 0.0, 0.0]), 5.0, 1.0, taus, 0.03, 0.1, 0.1, 0.12) is None
    ref = [way.sample(t) for t in (9.95, 10.05)]  # the reference's velocity over the last 0.1 s, through the corner
    vel = np.subtract((ref[1].x, ref[1].y, ref[1].z), (ref[0].x, ref[0].y, ref[0].z)) / 0.1
    on_it = on_its_way(way, np.array([ref[1].x, ref[1].y, ref[1].z]), vel, 10.05, 1.0, taus, 0.03, 0.1, 0.1, 0.12)
    assert on_it is not None
    assert np.allclose(on_it, [(r.x, r.y, r.z) for r in map(way.sample, 10.05 + taus)], atol=1e-9)
    radius, height = MODEL.body()
    other = np.tile((1.56 + 2 * radius + 0.015, 0.01, 0.5), (5, 1))  # 1.5 cm beyond where it goes
    assert nearest(beside, other, radius, height) == pytest.approx(0.015)
    assert nearest(beside, other - (0.02, 0.0, 0.0), radius, height) == pytest.approx(-0.005)
    assert nearest(None, other, radius, height) == -math.inf


def test_a_closing_between_vehicles_of_no_plan_is_not_spared() -> None:
    """A mover whose plan is not running (no controller clock) is never spared."""
    svc = ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("clearance"))
    svc.controllers["cf1"] = VehicleController("cf1", MODEL, owner="e1")
    closing = Closing("cf1", "cf2", 0.05, 0.3, (0.3, 0.0, 0.0), (0.0, 0.0, 0.0), 0.1)
    radius, height = MODEL.body()
    assert not svc._plans_keep_apart(closing, radius, height, 100.0)
