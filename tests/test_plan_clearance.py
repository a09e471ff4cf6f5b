"""The proximity stop judged once more on the plans (issue 15, services/executor/plan_clearance.py):
two vehicles keeping to plans that keep them apart go on, however the motion capture's view of
them alone foretells a touch; one off its plan, held, stalled or unheard is judged as before."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from common.bus.keys import Keys
from common.bus.messages import PlanStep, VehicleState
from common.bus.session import ZenohConfig
from common.flight.modes import Mode
from services.executor.plan_clearance import drift_time, nearest, on_its_way
from services.executor.proximity import Closing, ProximityParams
from services.executor.service import STATE_FRESH_S, ExecutorService
from services.executor.trajectory import Trajectory
from services.executor.vehicle_controller import VehicleController
from tests.support.closed_loop import plan_for
from tests.support.crossing import MODEL, crossing_steps, fly_crossing

pytestmark = pytest.mark.compute  # (no service, no loop on the clock)


@pytest.mark.parametrize("trust", [True, False])
def test_two_flyers_on_plans_that_cross_at_their_margin_go_on(trust: bool) -> None:
    """cf2 crosses cf1's way 0.57 s before it, the plans 3.1 cm apart at their nearest. Seen from
    the motion capture alone, cf2 at the crossing stands in cf1's way, and cf1 stopped short
    (each of four failed 80-vehicle soaks began with such a stop, 2026-12-07); judged on the
    plans, both keep to theirs and go on, and in ground truth their bodies never touch."""
    svc, closest = fly_crossing(ProximityParams(trust_plans=trust, pause=False))
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
    svc, closest = fly_crossing(ProximityParams(), hold_cf2_at=0.02)
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
