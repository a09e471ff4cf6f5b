"""The proximity pause (issue 15, `ExecutorService._stop_short`, `VehicleController.pause`): a
vehicle that heads into another keeping to its plan of the same mission stops where it is and
stands the mission's plan clock, instead of being held and planned around; every vehicle comes to
its plan's place of one time, which keeps them apart, and the paused one goes on when the two plans
are judged to keep them apart from there. Judged in ground truth. A flyer the tracking guard would
hold for its own tracking pauses too (`VehicleController._pause_for_tracking`), and goes on once
back within its margin of its plan's standing place."""

from __future__ import annotations

import math

import msgspec
import pytest

from common.bus.keys import Keys
from common.bus.session import ZenohConfig
from common.domain.vehicle_model import VehicleModel
from common.flight.modes import Mode
from common.flight.plan_clock import ClockParams
from services.executor import vehicle_controller
from services.executor.proximity import ProximityParams
from services.executor.service import ExecutorService
from services.executor.vehicle_controller import ControlParams, VehicleController
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.closed_loop import Mocap, plan_for, reference_steps, run
from tests.support.crossing import fly_crossing
from tests.support.sent import SentMessages

pytestmark = pytest.mark.compute  # (no service, no loop on the clock)

BLOWN = (-2.0, 0.0)
"""m/s^2: cf2 blown towards cf1's side of the crossing, 12 cm before it, for 0.2 s: it passes
about 2 cm nearer cf1's way than its plan, and judged on the plans too cf1 would touch it."""


def test_a_flyer_heading_into_one_blown_off_its_plan_pauses_and_goes_on() -> None:
    """cf1 heads into cf2, blown off its plan: it pauses, the plan's clock stands while cf2 comes
    back to its plan's place, and cf1 goes on along its plan; neither is held (the mission plans
    no one around), and in ground truth their bodies never touch."""
    svc, closest = fly_crossing(ProximityParams(), gust=BLOWN)
    went_on(svc, "cf1", "proximity")
    assert closest > 0.01, closest


def went_on(svc: ExecutorService, paused: str, counted: str) -> None:
    """Neither flyer is held; `paused` paused once (counted begun and ended as `counted`) and flies
    on, the other never paused; the plan's clock stood for the pause."""
    assert not any(ctl.held for ctl in svc.controllers.values()), {v: c.held for v, c in svc.controllers.items()}
    assert {v: c.pauses for v, c in svc.controllers.items()} == {v: int(v == paused) for v in svc.controllers}
    assert svc.counters.get(f"{counted}_paused") == svc.counters.get(f"{counted}_pause_ended") == 1
    ctl = svc.controllers[paused]
    assert ctl.paused is None and ctl.mode == Mode.FLYING
    assert 0.3 < ctl.delay < 2.0, ctl.delay


def test_without_the_pause_the_same_closing_holds_the_flyer() -> None:
    """The same flight with the pause off: cf1 stops short of cf2 and is held for good (the
    mission would plan the others around it), and the plan's clock never stood."""
    svc, closest = fly_crossing(ProximityParams(pause=False), gust=BLOWN)
    cf1 = svc.controllers["cf1"]
    assert cf1.held and "stops short of cf2" in cf1.held, cf1.held
    assert cf1.pauses == 0 and cf1.delay == 0.0
    assert closest > 0.01, closest


def test_without_the_plans_clock_the_same_closing_holds_the_flyer() -> None:
    """On the wall clock (`fleet executor --no-plan-clock`) the plans would run on without a paused
    vehicle: cf1 is held, as without the pause."""
    svc, closest = fly_crossing(ProximityParams(), gust=BLOWN, control=ControlParams(clock=ClockParams(enabled=False)))
    cf1 = svc.controllers["cf1"]
    assert cf1.held and "stops short of cf2" in cf1.held, cf1.held
    assert cf1.pauses == 0 and svc.counters.get("proximity_paused") is None
    assert closest > 0.01, closest


def test_a_pause_not_ended_in_time_becomes_the_hold() -> None:
    """A pause the plans have not ended within `pause_max_s` holds the vehicle, as the proximity
    stop would have, with why."""
    svc, closest = fly_crossing(ProximityParams(pause_settle_s=0.3, pause_max_s=0.3), gust=BLOWN)
    cf1 = svc.controllers["cf1"]
    assert cf1.held and "stops short of cf2" in cf1.held and "paused 0.3 s" in cf1.held, cf1.held
    assert svc.counters.get("proximity_pause_held") == 1 and svc.counters.get("proximity_pause_ended") is None
    assert cf1.paused is None
    assert closest > 0.01, closest


def test_a_pause_for_a_vehicle_held_meanwhile_becomes_the_hold() -> None:
    """cf2 is held by its executor while cf1, paused for it, stands (0.3 s into the pause): the
    clock standing brings cf2 back to no place of its plan, so cf1 is held too once its pause has
    settled (the mission plans the others around both at once), with why; in ground truth they
    never touch."""
    def hold_cf2(svc: ExecutorService, now: float) -> None:
        cf1, cf2 = svc.controllers["cf1"], svc.controllers["cf2"]
        if cf1.paused is not None and now - cf1.paused.since > 0.3 and not cf2.held:
            assert cf2.stop_short("held by its executor")

    svc, closest = fly_crossing(ProximityParams(), gust=BLOWN, on_cycle=hold_cf2)
    cf1, cf2 = svc.controllers["cf1"], svc.controllers["cf2"]
    assert cf2.held == "held by its executor"
    assert cf1.held and "stops short of cf2" in cf1.held and "cf2 keeping to no plan now" in cf1.held, cf1.held
    assert "paused 0.5 s" in cf1.held, cf1.held  # as soon as it settled
    assert svc.counters.get("proximity_pause_held") == 1 and svc.counters.get("proximity_pause_ended") is None
    assert closest > 0.01, closest


def test_a_paused_flyer_whose_mission_is_aborted_lands_and_stands_its_clock_no_more() -> None:
    """cf1's mission is aborted while it pauses: the abort's landing goes on (a fault landing is
    not paused) and its plan's clock runs again; in ground truth they never touch."""
    aborted: list[float] = []

    def abort_cf1(svc: ExecutorService, now: float) -> None:
        cf1 = svc.controllers["cf1"]
        if cf1.paused is not None and not aborted:
            cf1.abort("the mission is aborted")
            aborted.append(svc.clocks["sim"].delay)

    svc, closest = fly_crossing(ProximityParams(), gust=BLOWN, on_cycle=abort_cf1)
    cf1 = svc.controllers["cf1"]
    assert aborted and cf1.paused is None and cf1.clock_pace == 1.0
    assert cf1.mode in (Mode.LANDING, Mode.DONE), cf1.mode
    assert svc.clocks["sim"].delay - aborted[0] < 0.1  # the clock stood no longer than the abort took
    assert closest > 0.01, closest


def alone_on_the_reference_plan(model: VehicleModel) -> tuple[ExecutorService, VehicleController, SimFlyingCar, Mocap]:
    """cf1 on the reference plan, alone in an executor that runs its plan's clock."""
    svc = ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("pause"))
    svc._delay = SentMessages()  # (one executor: its clock's delay told to no one)
    ctl = svc.controllers["cf1"] = VehicleController("cf1", model, owner="e1")
    ctl.load(plan := plan_for("cf1", reference_steps(model), model, t0=0.5))
    svc.plans["cf1"] = plan
    return svc, ctl, SimFlyingCar("cf1", model, pos=(0.0, 0.0, 0.0), yaw=0.0), Mocap()


def test_a_driver_paused_stops_where_it_is_and_drives_on_from_there() -> None:
    """A driver paused on its road stops its wheels where it is and stands its plan's clock (its
    executor's delay grows as long as it pauses); let go, it follows its plan again and keeps
    within its margin of it. Paused again for the same vehicle within `REPAUSE_S`, the pause
    continues the last one (its time from that one's start); for another, it starts anew. Going on,
    it brings its clock back to full pace over `RESUME_S`."""
    model = VehicleModel(margin=0.03)
    svc, ctl, sim, mocap = alone_on_the_reference_plan(model)
    paused_at = resumed_at = None
    errors = []
    while sim.t < 6.8:
        now = sim.t
        if paused_at is None and now >= 5.0:
            assert ctl.mode == Mode.DRIVING and ctl.pause("for a test", "cf2", now)
            paused_at, first = (sim.x, sim.y), now
        if resumed_at is None and now >= 6.0:
            ctl.back_onto_plan()
            ctl.go_on(now)
            resumed_at, delay = (sim.x, sim.y), ctl.delay
        svc._run_clocks(now)
        run(ctl, sim, now + 0.01, mocap=mocap)
        if resumed_at is not None and (ref := ctl.reference(sim.t)) is not None:
            errors.append(math.hypot(sim.x - ref.x, sim.y - ref.y))
    assert paused_at is not None and resumed_at is not None
    assert math.dist(paused_at, resumed_at) < 0.01, (paused_at, resumed_at)  # 0.1 m/s, stopped within a centimetre
    assert 0.95 < delay < 1.05, delay  # the clock stood for the second it paused
    assert ctl.mode == Mode.DRIVING and ctl.paused is None and not ctl.held
    assert sim.x > resumed_at[0] + 0.015  # it drove on along its road (0.32 s of its plan at 0.1 m/s: below)
    assert max(errors) < model.margin, max(errors)
    assert 0.4 < ctl.delay - delay < 0.55, ctl.delay - delay  # its clock back to full pace over `RESUME_S`:
    # in the 0.8 s since going on it ran 0.32 s (0.8^2 / 2), standing 0.48 s more
    now = sim.t
    assert ctl.pause("again", "cf2", now) and ctl.paused is not None
    assert (ctl.paused.since, ctl.paused.stopped) == (first, now), ctl.paused  # (0.8 s after going on)
    ctl.go_on(now)
    assert ctl.pause("for another", "cf3", now) and ctl.paused is not None and ctl.paused.since == now


# ---- a pause for a flyer's own tracking ---------------------------------------------------------

WIDE = VehicleModel(margin=0.05)
"""The city maps' margin: the guard holds a flyer 10 cm off its plan for 0.3 s, 15 cm at once."""
WIND = (0.0, 2.0)
"""m/s^2 across cf2's way for 1 s in cruise: it is blown 10-12 cm off its plan for over 0.3 s,
short of the guard's burst (the LQR takes a sustained push up slowly)."""


def blow_cf2(proximity: ProximityParams) -> ExecutorService:
    """cf1 on the reference plan, cf2 on the same a metre aside, one executor; cf2 blown by `WIND`
    once past x = 1 m in cruise."""
    steps = reference_steps(WIDE)
    aside = [msgspec.structs.replace(s, pos=(s.pos[0], s.pos[1] + 1.0, s.pos[2])) for s in steps]
    svc, _closest = fly_crossing(proximity, gust=WIND, gust_s=1.0, model=WIDE, steps={"cf1": steps, "cf2": aside},
                                 gust_when=lambda body: body.z > 0.4 and body.x > 1.0)
    return svc


def test_a_flyer_blown_off_its_plan_pauses_the_mission_and_goes_on() -> None:
    """cf2, blown 10 cm off its plan for 0.3 s (where the guard would hold it), pauses the
    mission: the plan's clock stands (cf1 stands at its plan's place too), cf2 flies back onto its
    plan's place and goes on once within its margin; neither is held, so the mission plans no one
    around it."""
    svc = blow_cf2(ProximityParams())
    went_on(svc, "cf2", "tracking")
    assert svc.controllers["cf1"].delay == svc.controllers["cf2"].delay  # (cf1 stood as long)
    assert svc.controllers["cf2"].state().tracking_error < WIDE.margin


def test_without_the_tracking_pause_the_blown_flyer_is_held() -> None:
    """The same flight with the tracking pause off: the guard holds cf2 where it is (the mission
    would plan the others around it), and the plan's clock never stood."""
    svc = blow_cf2(ProximityParams(pause_tracking=False))
    cf2 = svc.controllers["cf2"]
    assert cf2.held and cf2.held.startswith("tracking error"), cf2.held
    assert cf2.pauses == 0 and svc.controllers["cf1"].delay == 0.0


def test_a_tracking_pause_not_ended_in_time_becomes_the_guards_hold() -> None:
    """A pause for its own tracking that has not ended within `pause_max_s` holds the flyer as the
    guard would have, with why; the plan's clock runs again."""
    svc = blow_cf2(ProximityParams(pause_settle_s=0.3, pause_max_s=0.3))
    cf2 = svc.controllers["cf2"]
    assert cf2.held and cf2.held.startswith("tracking error") and "paused 0.3 s" in cf2.held, cf2.held
    assert svc.counters.get("tracking_pause_held") == 1 and svc.counters.get("tracking_pause_ended") is None
    assert cf2.paused is None and cf2.clock_pace == 1.0


@pytest.mark.parametrize("resume_s, worst", [(vehicle_controller.RESUME_S, (0.0, 0.025)), (1e-9, (0.03, 0.05))],
                         ids=["ramped", "at once"])
def test_a_flyer_going_on_from_a_pause_keeps_near_its_reference_as_the_clock_comes_back(
        monkeypatch, resume_s: float, worst: tuple[float, float]) -> None:
    """A flyer paused in cruise (0.3 m/s), back on its plan's place, goes on: its clock comes back
    to full pace over `RESUME_S`, and in ground truth it keeps within 2.5 cm of its reference (1.9
    cm); its reference jumping back to full speed at once, it lagged it 3.4 cm, as two flyers did in
    an 80-vehicle soak just before their bodies met."""
    monkeypatch.setattr(vehicle_controller, "RESUME_S", resume_s)
    model = VehicleModel(margin=0.05)
    svc, ctl, sim, mocap = alone_on_the_reference_plan(model)
    errors: list[float] = []
    went = None
    while sim.t < 19.0:
        now = sim.t
        if ctl.pauses == 0 and now >= 16.0:  # (cruising from a1 to a2)
            assert ctl.mode == Mode.FLYING and ctl.pause("for a test", "cf2", now)
        if ctl.paused is not None and now >= 17.0:
            ctl.back_onto_plan()
        if ctl.paused is not None and now >= 17.5:
            ctl.go_on(went := now)
        svc._run_clocks(now)
        run(ctl, sim, now + 0.01, mocap=mocap)
        if went is not None and (ref := ctl.reference(sim.t)) is not None:
            errors.append(math.dist((sim.x, sim.y, sim.z), (ref.x, ref.y, ref.z)))
    assert ctl.mode == Mode.FLYING and not ctl.held
    assert worst[0] < max(errors) < worst[1], max(errors)
