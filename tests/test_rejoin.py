"""A vehicle held for another's sake (the proximity stop, the reflex) or left behind by a fault that
cleared comes back into the running mission (`Replan.rejoin`, `services/mission/rejoin.py`): its
old path shifted in time so that it is where the vehicle stands at the switch, planned on from its
next node, validated from the switch on; refused while its way crosses a body that left. Its
executor holds it until the new reference comes to it, then follows it."""

from __future__ import annotations

import math
import time

import msgspec
import pytest

from common.bus.keys import Keys
from common.bus.messages import PlanRequest, PlanStep, Replan, Sweep, VehiclePlan
from common.bus.session import ZenohConfig
from common.domain.planfile import PathEntry, Plan, Task
from common.flight.modes import Mode
from services.executor.vehicle_controller import VehicleController
from services.mission.rejoin import Candidate, progress_at, shifted_path
from services.mission.runner import MissionRunner, MissionSpec, plan_end
from services.mission.sweeps import held
from services.planner.registry import solve
from services.planner.validate import validate_plan
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.closed_loop import Mocap, MocapNoise, plan_for, run
from tests.test_replan import TASKS, plan_of
from tests.test_tracking_guard import MODEL, STEPS, T0

pytestmark = pytest.mark.compute


def drive_time(plan: Plan, vid: str) -> float:
    """A time at which `vid` drives mid-edge (the middle of its longest drive)."""
    path, nodes = plan.paths[vid], plan.graph.nodes
    a, b = max(((a, b) for a, b in zip(path, path[1:], strict=False) if a.node != b.node
                and nodes[a.node].kind != "air" and nodes[b.node].kind != "air"), key=lambda ab: ab[1].t - ab[0].t)
    return 0.5 * (a.t + b.t)


def held_plan(base: Plan, vid: str, t: float) -> tuple[Plan, tuple[float, float, float]]:
    """The plan of the others after `vid` was held at its plan's position at `t` (and where)."""
    here = base.position(vid, t)
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10,
                              replan=Replan(base=base, at=t + 1.0, left=[vid], sweeps=held(vid, here, t, 0.0, plan_end(base)))))
    assert reply.ok and reply.plan is not None, reply.error
    return reply.plan, here


def test_where_a_held_vehicle_stands_on_its_path_and_the_path_shifted_to_it() -> None:
    base = plan_of()
    t = drive_time(base, "cf3")
    path = base.paths["cf3"]
    here = base.position("cf3", t)
    assert progress_at(base, path, here, t + 1.0) == pytest.approx(t, abs=1e-6)
    off = (here[0] + 0.02, here[1], here[2])  # beside its path: the nearest point on it
    assert math.dist(base.position("cf3", progress_at(base, path, off, t + 1.0)), here) < 0.021
    shifted = shifted_path(path, t, t + 7.5)
    later = msgspec.structs.replace(base, paths={**base.paths, "cf3": shifted})
    assert math.dist(later.position("cf3", t + 7.5), here) < 1e-6
    assert [e.node for e in shifted] == [e.node for e in path]


def test_a_held_driver_rejoins_from_where_it_stands_and_reaches_its_goal() -> None:
    base = plan_of()
    t = drive_time(base, "cf3")
    others, here = held_plan(base, "cf3", t)
    assert "cf3" not in others.paths
    at = t + 6.0
    back = msgspec.structs.replace(others, paths={**others.paths, "cf3": shifted_path(base.paths["cf3"], t, at)},
                                   tasks={**others.tasks, "cf3": base.tasks["cf3"]})
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, replan=Replan(base=back, at=at, rejoin=["cf3"])))
    assert reply.ok and reply.plan is not None, reply.error
    plan = reply.plan
    assert set(plan.paths) == set(TASKS)
    assert math.dist(plan.position("cf3", at), here) < 1e-6  # on its way on from where it stands
    assert plan.paths["cf3"][-1].node == TASKS["cf3"].goal
    report = validate_plan(plan, check_cost=False, since=at)
    assert report.ok, report.errors


def test_a_vehicle_does_not_rejoin_through_a_body_that_left() -> None:
    base = plan_of()
    t = drive_time(base, "cf3")
    others, _ = held_plan(base, "cf3", t)
    at = t + 6.0
    ahead = base.position("cf3", t + 1.0)  # on the edge it drives along: a body rests there
    back = msgspec.structs.replace(others, paths={**others.paths, "cf3": shifted_path(base.paths["cf3"], t, at)},
                                   tasks={**others.tasks, "cf3": base.tasks["cf3"]})
    blocked = Replan(base=back, at=at, rejoin=["cf3"], sweeps=[Sweep("cf9", ahead, ahead, t, t, rest=True)])
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, replan=blocked))
    assert not reply.ok and reply.failed_vehicle == "cf3", reply
    assert "cf3 cannot rejoin yet: its way to" in reply.error and "cf9" in reply.error, reply.error


def test_every_vehicle_that_cannot_rejoin_yet_is_named_at_once() -> None:
    """Two vehicles that rejoin, a body resting on the way of each: the planner names both (its
    mission then brings the others back in one more request, not one per vehicle refused)."""
    base = plan_of()
    t = drive_time(base, "cf3")
    others, _ = held_plan(base, "cf3", t)
    at = t + 6.0
    back = msgspec.structs.replace(others, paths={**others.paths, "cf3": shifted_path(base.paths["cf3"], t, at)},
                                   tasks={**others.tasks, "cf3": base.tasks["cf3"]})
    mover = next(v for v, path in back.paths.items() if v != "cf3" and path[0].t < at < path[-1].t)
    on_its_way = back.position(mover, at)
    ahead = base.position("cf3", t + 1.0)
    sweeps = [Sweep("cf9", ahead, ahead, t, t, rest=True), Sweep("cf8", on_its_way, on_its_way, t, t, rest=True)]
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10,
                              replan=Replan(base=back, at=at, rejoin=["cf3", mover], sweeps=sweeps)))
    assert not reply.ok and reply.failed_vehicle == "cf3", reply
    assert set(reply.refused) == {"cf3", mover}, reply.refused
    assert "cf9" in reply.refused["cf3"] and "cf8" in reply.refused[mover]


def test_two_held_vehicles_within_reach_of_each_other_rejoin_one_named_refused() -> None:
    """Two held vehicles that stand within reach of each other (stopped short of one another)
    cannot both come back: the planner finds them in contact and names one of them, so that the
    mission leaves it out and brings the others back (named by no one, no vehicle came back: the
    mission retried them all, a 32-vehicle soak's planner spending a second a try)."""
    base = plan_of()
    t = drive_time(base, "cf3")
    path = base.paths["cf3"]
    a, b = next((a, b) for a, b in zip(path, path[1:], strict=False) if a.t < t < b.t)
    head_on = [PathEntry(node=b.node, t=a.t), PathEntry(node=a.node, t=b.t)]  # cf5 meets it mid-edge
    both = msgspec.structs.replace(base, paths={**base.paths, "cf5": head_on},
                                   tasks={**base.tasks, "cf5": Task(start=b.node, goal=TASKS["cf3"].start)})
    assert math.dist(both.position("cf3", t), both.position("cf5", t)) < 1e-6
    others, _ = held_plan(base, "cf3", t)
    at = t + 6.0
    back = msgspec.structs.replace(others, paths={**others.paths, "cf3": shifted_path(path, t, at),
                                                  "cf5": shifted_path(head_on, t, at)},
                                   tasks={**others.tasks, "cf3": base.tasks["cf3"], "cf5": both.tasks["cf5"]})
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=2, replan=Replan(base=back, at=at, rejoin=["cf3", "cf5"])))
    assert not reply.ok and "contact: cf3 and cf5" in reply.error, reply.error
    assert reply.failed_vehicle in ("cf3", "cf5")


def stopped_short(flying: bool = False) -> tuple[VehicleController, SimFlyingCar, float]:
    """The reference path's vehicle stopped short mid-drive (on r1 -> r2, along +x) or mid-flight
    (a1 -> a2, along +x) and standing still; the plan time of where it stands."""
    sim = SimFlyingCar("cf1", MODEL, pos=STEPS[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.load(plan_for("cf1", STEPS, MODEL, t0=T0))
    i = next(k for k, s in enumerate(STEPS) if s.node == ("a1" if flying else "r1"))
    a, b = STEPS[i], STEPS[i + 1]
    run(ctrl, sim, T0 + 0.5 * (a.t + b.t))
    moving, held = (Mode.FLYING, Mode.HOVERING) if flying else (Mode.DRIVING, Mode.HOLDING)
    assert ctrl.mode == moving and ctrl.stop_short("stops short of cf9: a test")
    run(ctrl, sim, sim.t + 2.0)
    assert ctrl.mode == held and ctrl.held is not None and ctrl.rejoinable
    progress = a.t + (sim.x - a.pos[0]) / (b.pos[0] - a.pos[0]) * (b.t - a.t)
    return ctrl, sim, progress


def back(delay: float = 0.0, path: list[PlanStep] = STEPS) -> VehiclePlan:
    """The reference path (`path`) later by `delay`, as a plan that brings the vehicle back."""
    steps = [msgspec.structs.replace(s, t=round(s.t + delay, 6)) for s in path]
    return msgspec.structs.replace(plan_for("cf1", steps, MODEL, t0=T0), rejoin=True)


@pytest.mark.parametrize("flying", [False, True], ids=["driving", "flying"])
def test_a_vehicle_stopped_short_waits_for_its_new_reference_then_goes_on_to_its_goal(flying: bool) -> None:
    ctrl, sim, progress = stopped_short(flying)
    switch = sim.t - T0 + 1.5
    plan = back(switch - progress)
    # a plan of the mission that does not say it brings the vehicle back is refused (one asked for
    # before the hold, handed out after it, had a held vehicle drive on unplanned for: a soak)
    assert not ctrl.replan(msgspec.structs.replace(plan, rejoin=False), sim.t)
    assert ctrl.replan(back(switch - progress - 0.5), sim.t)
    # while it waits for its reference, the mission's next plan (another fault's replan, which keeps
    # its way to its next node) replaces the one that brought it back
    assert ctrl.replan(msgspec.structs.replace(plan, rejoin=False), sim.t)
    still = (sim.x, sim.y, sim.z)
    run(ctrl, sim, sim.t + 1.2)
    held, moving = (Mode.HOVERING, Mode.FLYING) if flying else (Mode.HOLDING, Mode.DRIVING)
    assert ctrl.mode == held and math.dist(still, (sim.x, sim.y, sim.z)) < 0.02  # its reference not here yet
    run(ctrl, sim, sim.t + 1.0)
    assert ctrl.held is None and ctrl.mode == moving
    run(ctrl, sim, T0 + switch - progress + STEPS[-1].t + 3.0)
    assert ctrl.mode == Mode.DONE and ctrl.held is None, (ctrl.mode, ctrl.held)
    assert math.dist((sim.x, sim.y, sim.z), STEPS[-1].pos) < 0.05  # flew the rest and parked at its goal


@pytest.mark.parametrize(("where", "edge"), [("take-off", "takeoff"), ("take-off twice", "takeoff"),
                                             ("take-off, blown aside", "takeoff"), ("take-off, leaning", "takeoff"),
                                             ("landing", "land"), ("flight", "fly")])
def test_a_vehicle_that_came_down_blind_in_its_take_off_or_landing_is_held_there_and_taken_back(
        where: str, edge: str) -> None:
    """Poses lost for 1 s mid take-off or mid landing (a motion-capture stall): the emergency
    descent comes down in the column of its plan's take-off or landing, over its foot once the
    poses are back (blown 4 cm aside while blind, too; its foot, not the point below where the
    poses went, when the take-off leans 5 cm as town's do), and there, seen again, the vehicle is held
    (rejoinable), not done; a plan that brings it back (its path shifted: the take-off, or the
    drive after the landing, from where it stands) takes it on to its goal; lost again in the
    take-off that brought it back, it stays down (`BLIND_RETURNS`). Lost in cruise it comes down
    below its flight, off its plan: done, as before."""
    k = next(k for k, s in enumerate(STEPS) if s.edge == edge)
    lean = 0.05 if "leaning" in where else 0.0  # the take-off's top and all after it 5 cm along x
    path = [msgspec.structs.replace(s, pos=(s.pos[0] + lean, *s.pos[1:])) if i >= k else s
            for i, s in enumerate(STEPS)]
    a, b = path[k - 1], path[k]
    lost = T0 + 0.5 * (a.t + b.t)
    sim = SimFlyingCar("cf1", MODEL, pos=path[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", MODEL, owner="test")
    ctrl.load(plan_for("cf1", path, MODEL, t0=T0))
    mocap = Mocap(MocapNoise(dropouts=((lost, lost + 1.0),)))
    column = path[k - 1 if edge == "takeoff" else k].pos
    blown: list[float] = []

    def wind(now: float) -> None:  # 0.08 m/s^2 sideways while it is blind: about 4 cm
        if "blown" in where and lost <= now < lost + 1.0:
            sim.push(0.08, 0.0, lost + 1.0)
            blown.append(math.hypot(sim.x - column[0], sim.y - column[1]))

    records = run(ctrl, sim, lost + 5.0, mocap, on_tick=wind)
    assert Mode.EMERGENCY_LANDING in {r.mode for r in records}
    assert sim.z < 0.02 and not sim.truth().motors, (sim.z, ctrl.mode)
    if edge == "fly":
        assert ctrl.mode == Mode.DONE and ctrl.held is None
        # out of the mission where it came down: a replan of it that still has it on its way
        # (asked for before it left) is refused, it stays done (`VehicleController._off_plan`)
        assert not ctrl.replan(plan_for("cf1", path, MODEL, t0=T0), sim.t)
        run(ctrl, sim, sim.t + 2.0, Mocap(MocapNoise()))
        assert ctrl.mode == Mode.DONE and sim.z < 0.02 and not sim.truth().motors, ctrl.mode
        return
    if blown:
        assert max(blown) > 0.03, max(blown)
    assert math.hypot(sim.x - column[0], sim.y - column[1]) < 0.015, (sim.x - column[0], sim.y - column[1])
    assert ctrl.mode == Mode.HOLDING and ctrl.rejoinable and "landed blind" in (ctrl.held or ""), ctrl.held
    assert ctrl.state().tracking_error == 0.0  # held: its plan's reference runs on without it
    progress = a.t if edge == "takeoff" else b.t  # where `progress_at` puts it: the column's foot
    switch = sim.t - T0 + 1.5
    assert ctrl.replan(back(switch - progress, path), sim.t)
    if where == "take-off twice":
        again = lost + switch - progress
        mocap = Mocap(MocapNoise(dropouts=((again, again + 1.0),)))
    records = run(ctrl, sim, T0 + switch - progress + path[-1].t + 3.0, mocap)
    if where == "take-off twice":
        assert [r.mode for r in records].count(Mode.EMERGENCY_LANDING) > 0
        assert ctrl.mode == Mode.DONE and sim.z < 0.02, (ctrl.mode, ctrl.held)
        return
    if edge == "takeoff":
        assert Mode.TAKING_OFF in {r.mode for r in records}
    assert ctrl.mode == Mode.DONE and ctrl.held is None, (ctrl.mode, ctrl.held)
    assert math.dist((sim.x, sim.y, sim.z), path[-1].pos) < 0.05


def test_a_plan_whose_reference_does_not_come_by_is_refused_and_the_hold_reported_again() -> None:
    ctrl, sim, _ = stopped_short()
    holds = ctrl.holds
    assert not ctrl.replan(back(), sim.t)  # not shifted: its reference is far on
    assert ctrl.holds == holds + 1 and "does not come within" in (ctrl.held or ""), ctrl.held
    assert not ctrl.replan(back(), sim.t)  # sent again: one report
    assert ctrl.holds == holds + 1
    run(ctrl, sim, sim.t + 1.0)
    assert ctrl.mode == Mode.HOLDING


def test_a_mission_whose_every_vehicle_left_waits_for_one_more_try_of_those_that_may_come_back() -> None:
    """Every vehicle held (a soak's first mission, every pose stale at once): the mission does not
    end while a held vehicle that may come back has not been tried since nothing moves any more;
    then it ends without it. (It crashed on the time limit of no vehicle at all.)"""
    tasks = {"cf3": TASKS["cf3"]}
    plan = plan_of(tasks=tasks)
    runner = MissionRunner(MissionSpec(map="town", tasks=tasks), ZenohConfig.client("tcp/127.0.0.1:9"),
                           Keys("rejoin"), progress=False)
    now = time.time()
    runner.plan, runner.t0 = plan, now - 10.0
    runner.left["cf3"] = "cf3: tracking_hold its plan moved on 0.062 m while it was stopped (pose stale)"
    runner._rejoin["cf3"] = Candidate(plan.paths["cf3"], plan.tasks["cf3"], since=now - 1.0)
    assert runner.end_reason(now) is None
    runner._rejoin["cf3"].tries, runner._rejoin["cf3"].last_try = 1, now + 0.1  # tried, not back
    assert runner.end_reason(now + 0.2) == f"every other vehicle arrived; left: {runner.left['cf3']}"
