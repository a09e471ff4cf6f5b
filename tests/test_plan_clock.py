"""The plan's clock (issue 15, `common/flight/plan_clock.py`): a mission's plan runs on one clock
that waits for the vehicles behind their plans, so that a late vehicle delays the others instead of
meeting them on time. The arithmetic of the clocks the executors keep, a controller's pace and
reference on it, and a fleet in which one vehicle stops on a stale pose while the others wait for
it, judged in ground truth."""

from __future__ import annotations

import asyncio
import math

import pytest

from common.bus.keys import Keys
from common.bus.messages import Pose, SimFault
from common.bus.session import ZenohConfig
from common.domain.vehicle_model import VehicleModel
from common.flight.modes import Mode
from common.flight.plan_clock import ClockParams, PlanClock, latency_pace, pace_for
from services.executor.vehicle_controller import VehicleController
from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from tests.support.closed_loop import plan_for, reference_steps
from tests.support.fleet_faults import NO_RECORDER, TOWN_TASKS, Watch, fly, until

MODEL = VehicleModel(margin=0.03)
DT = 0.01


def test_the_pace_falls_from_half_a_margin_to_a_whole_one() -> None:
    p = ClockParams()
    assert pace_for(0.010, 0.03, p) == 1.0
    assert pace_for(0.0225, 0.03, p) == pytest.approx(0.5)
    assert pace_for(0.031, 0.03, p) == 0.0
    assert pace_for(0.5, 0.0, p) == 1.0  # a plan without a margin: nothing to keep
    assert pace_for(0.5, 0.03, ClockParams(enabled=False)) == 1.0


def test_a_loop_whose_commands_come_late_slows_the_clock_in_proportion() -> None:
    p = ClockParams()
    assert latency_pace(0.05, p) == latency_pace(0.15, p) == 1.0
    assert latency_pace(0.2, p) == pytest.approx(0.75)  # as far within the latency as at 0.15 s
    assert latency_pace(2.0, p) == p.latency_floor == 0.5  # a whole mission at it still fits its time limit
    assert latency_pace(0.2, ClockParams(enabled=False)) == 1.0


def exchange(a: PlanClock, b: PlanClock, pace_a: float, pace_b: float, seconds: float, t: float) -> float:
    """Two executors' clocks, each waiting at its pace every cycle and hearing the other's delay."""
    for _ in range(round(seconds / DT)):
        t += DT
        da, db = a.wait(t, pace_a), b.wait(t, pace_b)
        b.hear("a", da, pace_a, t)
        a.hear("b", db, pace_b, t)
    return t


def test_an_executor_whose_vehicle_lags_stops_every_executors_clock() -> None:
    a, b = PlanClock(), PlanClock()
    t = exchange(a, b, 1.0, 1.0, 1.0, 0.0)
    assert a.delay == b.delay == 0.0
    t = exchange(a, b, 0.0, 1.0, 1.0, t)  # a's vehicle 3 cm behind for 1 s: the plan stands still
    assert a.delay == pytest.approx(1.0, abs=0.02) and b.delay == pytest.approx(a.delay)
    t = exchange(a, b, 0.5, 1.0, 1.0, t)  # half a second more at half pace
    assert b.delay == pytest.approx(1.5, abs=0.02)
    exchange(a, b, 1.0, 1.0, 1.0, t)  # caught up: the delay stays what it came to
    assert b.delay == pytest.approx(1.5, abs=0.02)


def test_two_executors_waiting_at_once_count_the_wait_once() -> None:
    a, b = PlanClock(), PlanClock()
    exchange(a, b, 0.0, 0.0, 0.5, 0.0)
    assert a.delay == pytest.approx(0.5, abs=0.02) and b.delay == pytest.approx(0.5, abs=0.02)


def test_a_heard_pace_stops_the_clock_at_once_until_it_is_no_longer_fresh() -> None:
    clock = PlanClock(ClockParams(fresh_s=0.1))
    clock.hear("a", 0.2, 0.0, 10.0)  # a stood still from 10.0 s on, as far as heard
    assert clock.behind(10.05) == pytest.approx(0.25)  # carried on at its pace before the next word
    assert clock.heard_pace(10.05) == 0.0
    assert clock.heard_pace(10.5) == 1.0
    clock.hear("a", 0.1, 0.0, 9.0)  # an older message changes nothing
    assert clock.heard_pace(10.5) == 1.0 and clock.delay == 0.2
    fresh = PlanClock(ClockParams(fresh_s=0.1))
    fresh.hear("a", 0.2, 0.0, 10.0)
    assert fresh.behind(10.5) == pytest.approx(0.2)  # not heard again: its last delay, no more


def test_the_plan_time_given_never_goes_back_and_a_late_cycle_counts_as_waiting() -> None:
    clock = PlanClock(ClockParams(max_step_s=0.05))
    assert clock.behind(10.0) == 0.0
    clock.hear("a", 0.3, 1.0, 10.01)  # a stalled executor's wait, heard at once
    assert clock.behind(10.1) == pytest.approx(0.1)  # the plan's time stands still ...
    assert clock.behind(10.3) == pytest.approx(0.3)  # ... until the wall clock caught up
    clock.wait(11.0, 1.0)
    clock.wait(11.2, 1.0)  # this executor's own cycle 0.2 s late: 0.05 s of it run, the rest waited
    assert clock.delay == pytest.approx(0.45) and clock.waited == pytest.approx(0.15)


def controller(t0: float = 1.0) -> VehicleController:
    steps = reference_steps(MODEL)
    ctl = VehicleController("cf1", MODEL, owner="test")
    ctl.on_pose(Pose(vid="cf1", t=0.0, x=steps[0].pos[0], y=steps[0].pos[1], z=steps[0].pos[2], yaw=0.0))
    assert ctl.load(plan_for("cf1", steps, MODEL, t0=t0))
    return ctl


def test_a_controller_follows_its_plan_on_the_plan_clock_at_its_pace() -> None:
    ctl = controller()
    traj = ctl.trajectory
    assert traj is not None
    moving = next(t for t in (0.1 * k for k in range(300)) if math.hypot(traj.sample(t).vx, traj.sample(t).vy) > 0.05)
    now = 1.0 + moving + 2.0
    ctl.delay, ctl.pace = 2.0, 0.5
    ref, plan = ctl.reference(now), traj.sample(moving)
    assert (ref.t, ref.x, ref.y, ref.z) == (plan.t, plan.x, plan.y, plan.z)  # two seconds behind the wall clock
    assert (ref.vx, ref.vy) == pytest.approx((0.5 * plan.vx, 0.5 * plan.vy))  # at half the speed


def lagging_pace(ctl: VehicleController, behind_m: float, seconds: float, beside_m: float = 0.0) -> list[float]:
    """Tick a driving vehicle whose estimate stays `behind_m` m behind its reference and `beside_m`
    to its left (its poses say so; it drives along +x), for `seconds`; its pace at every tick."""
    paces = []
    now = ctl.t0 + 4.0  # type: ignore[operator]  (driving along +x, then waiting at its corner)
    for _ in range(round(seconds / DT)):
        ref = ctl.reference(now)
        assert ref is not None
        ctl.on_pose(Pose(vid="cf1", t=now, x=ref.x - behind_m, y=ref.y + beside_m, z=ref.z, yaw=0.0))
        ctl.machine.mode = Mode.DRIVING  # (as its plan has it from here on)
        ctl.tick(now)
        paces.append(ctl.clock_pace)
        now += DT
    return paces


def test_a_vehicle_a_margin_behind_its_plan_stops_the_clock_and_is_held_when_it_keeps_it_waiting() -> None:
    ctl = controller()
    paces = lagging_pace(ctl, 0.01, 1.0)
    assert min(paces) == 1.0  # a third of the margin: full pace
    ctl = controller()
    paces = lagging_pace(ctl, 0.0, 1.0, beside_m=0.027)
    assert min(paces) == 1.0  # beside its reference, not behind it: waiting would not bring it back
    ctl = controller()
    paces = lagging_pace(ctl, 0.035, ClockParams().max_wait_s + 0.5)
    assert paces[50] == 0.0 and ctl.held is not None, ctl.held
    assert ctl.held.startswith("kept its plan's clock waiting"), ctl.held
    assert paces[-1] == 1.0  # held: it no longer holds the clock


@pytest.mark.flight
@pytest.mark.timeout(180)
def test_the_fleet_waits_for_a_vehicle_stopped_on_a_stale_pose_and_every_vehicle_arrives(tmp_path) -> None:
    """cf3 loses its body for 1.5 s while it drives: it stops on the stale pose, its plan's clock
    stops for every vehicle of the mission (cf1 and cf2 in flight, on another executor), and when
    its poses come back it drives on: nobody is held, the mission succeeds 1-2 s later than planned,
    every vehicle arrives and nothing touches, in ground truth. On the wall clock (`fleet executor
    --no-plan-clock`, or the row of docs/reliability.md's table) cf3 was held as left behind
    (`tracking_hold`) and the mission had to plan around it."""
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20)
    marks: dict[str, float] = {}

    async def scenario(watch: Watch, runner: MissionRunner) -> None:
        await until(lambda: watch.mode("cf3") == "driving" and watch.mode("cf1") == "flying", 60, "cf3 driving")
        await asyncio.sleep(1.0)
        marks["lost"] = watch.inject(SimFault(vid="cf3", kind="mocap_dropout", duration_s=1.5))

    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="clock", without=NO_RECORDER) as fleet:
        result, watch = fly(fleet, spec, scenario)

    owners = {vid: watch.states[vid][-1].owner for vid in TOWN_TASKS}
    stopped = [s for s in watch.states["cf3"] if s.t >= marks["lost"] and s.mode == "holding"]
    assert stopped, "cf3 did not stop on its stale pose"
    assert not [e for _t, e in watch.events if e.kind == "tracking_hold"], watch.events
    assert result.ok, result.summary()
    assert 0.5 < result.delay_s < 4.0, result.summary()
    for vid in TOWN_TASKS:  # every executor's clock waited as long
        assert watch.states[vid][-1].delay == pytest.approx(result.delay_s, abs=0.1), (vid, owners)
        goal = result.plan.graph.nodes[TOWN_TASKS[vid].goal].pos  # type: ignore[union-attr]
        assert watch.at_rest_on(vid, goal), (vid, watch.truth[vid][-1])
    assert not watch.contacts, watch.separation_line()
    assert len(set(owners.values())) == 2, owners  # the wait crossed from one executor to the other
    print(f"the plan's clock waited {result.delay_s:.2f} s; owners {owners}; {watch.separation_line()}")

def test_a_missions_time_limit_is_on_the_plan_clock_whose_waits_count_up_to_the_plans_length() -> None:
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", slack_s=5.0)
    runner = MissionRunner(spec, ZenohConfig.client("tcp/127.0.0.1:7447"), Keys("clock"), progress=False)
    runner.t0 = 1000.0
    for r in runner.reports.values():
        r.planned_s = 16.0
    assert runner.end_reason(1000.0 + 22.0) is not None  # 16 s of plan and 5 s of slack gone
    runner.delay = 3.0  # the plan's clock waited 3 s
    assert runner.end_reason(1000.0 + 22.0) is None
    assert runner.end_reason(1000.0 + 25.0) is not None
    runner.delay = 60.0  # waits count up to the plan's length again, no more
    assert runner.end_reason(1000.0 + 36.0) is None
    assert runner.end_reason(1000.0 + 38.0) is not None
