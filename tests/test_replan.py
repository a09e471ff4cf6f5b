"""Replanning a running mission (issue 16): the remaining vehicles keep their paths up to the first
node at or after the switch time and are planned on from there, around a body that left the plan;
a vehicle that arrived gets a new goal while the others move. Judged by the validator on the whole
(spliced) plan and by sampling the paths against the left body's sweep."""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.messages import PlanRequest, Replan, Sweep, VehiclePlan
from common.bus.session import ZenohConfig
from common.domain.planfile import Plan, Task
from services.mission.runner import MissionRunner, MissionSpec, plan_end
from services.mission.sweeps import DESCENT_S_PER_M, REST_S, descent, held
from services.planner.failed_requests import read_request
from services.planner.maps.loading import load_graph
from services.planner.registry import _replan_with, solve
from services.planner.replanning import Leg, split, touched_by_segment
from services.planner.sipp.replan import priority
from services.planner.validate import validate_plan

TASKS = {
    "cf1": Task(start="WP10", goal="EP8"),
    "cf2": Task(start="EP7", goal="WP9"),
    "cf3": Task(start="WP7", goal="WP3"),
    "cf4": Task(start="WP1", goal="WP6"),
}


def plan_of(planner: str = "sipp", tasks: dict[str, Task] = TASKS) -> Plan:
    reply = solve(PlanRequest(map="town", tasks=tasks, planner=planner, time_limit=30))
    assert reply.ok and reply.plan is not None, reply.error
    return reply.plan


def airborne_at(plan: Plan, vid: str) -> float:
    """A time at which `vid` is in the air (mid-path)."""
    path = plan.paths[vid]
    air = [e.t for e in path if plan.graph.nodes[e.node].kind == "air"]
    assert air, f"{vid} never flies"
    return 0.5 * (air[0] + air[-1])


@pytest.mark.parametrize("planner", ["sipp", "ilp"])
def test_the_others_are_planned_on_around_a_vehicle_landing_after_a_fault(planner: str) -> None:
    """Both planners replan from the current state: mid-edge, in the air, waiting (the ILP on its
    own time steps, from the node each vehicle is at on the first step after the switch time)."""
    base = plan_of(planner)
    at = airborne_at(base, "cf2")
    here = base.position("cf2", at)
    below = (here[0], here[1], 0.0)
    sweeps = [Sweep("cf2", here, below, at, at + 4.0, rest=True)]
    t = time.perf_counter()
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, planner=planner,
                              replan=Replan(base=base, at=at + 1.0, left=["cf2"], sweeps=sweeps)))
    took = time.perf_counter() - t
    assert reply.ok and reply.plan is not None, reply.error
    assert reply.planner == planner
    plan = reply.plan
    assert set(plan.paths) == {"cf1", "cf3", "cf4"}
    report = validate_plan(plan)
    assert report.ok, report.errors
    for vid, path in plan.paths.items():
        old = base.paths[vid]
        kept = [e for e in old if e.t <= at + 1.0]
        assert path[:len(kept)] == kept, vid  # the prefix is flown unchanged
        assert path[-1].node == TASKS[vid].goal
        # never near cf2's body while it comes down and rests (envelopes: 2 x radius apart)
        for k in range(400):
            s = at + 1.0 + k * 0.1
            p = plan.position(vid, s)
            z_lo = below[2] if s >= at + 4.0 else min(here[2], below[2])
            horizontal = math.hypot(p[0] - here[0], p[1] - here[1])
            if z_lo - plan.model.height < p[2] < here[2] + plan.model.height:
                assert horizontal >= 2 * plan.model.radius - 1e-6, (vid, s, p)
    print(f"{planner}: replanned 3 vehicles in {1e3 * took:.0f} ms")
    if planner == "ilp":  # optimal on its network: no dearer than SIPP's replan of the same state
        sipp = solve(PlanRequest(map="town", tasks={}, time_limit=10,
                                 replan=Replan(base=base, at=at + 1.0, left=["cf2"], sweeps=sweeps)))
        assert sipp.ok and sipp.plan is not None and sipp.planner == "sipp"
        assert validate_plan(plan).cost <= validate_plan(sipp.plan).cost * (1 + 1e-6)


def test_an_arrived_vehicle_gets_a_new_goal_while_the_others_move() -> None:
    base = plan_of()
    cf3_done = base.paths["cf3"][-1].t
    at = cf3_done + 0.5
    assert any(p[-1].t > at for p in base.paths.values()), "someone must still be moving"
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10,
                              replan=Replan(base=base, at=at, goals={"cf3": "WP7"})))
    assert reply.ok and reply.plan is not None, reply.error
    path = reply.plan.paths["cf3"]
    assert path[-1].node == "WP7" and reply.plan.tasks["cf3"].goal == "WP7"
    assert min(e.t for e in path if e.t > cf3_done) >= at
    assert validate_plan(reply.plan).ok


def test_a_vehicle_whose_goal_a_fault_closed_stops_short_of_it_when_stranding_is_allowed() -> None:
    """cf4 comes down on cf1's goal and rests there: cf1 cannot arrive. Without `strand` the replan
    fails naming cf1; with it cf1 is given the nearest node it can still reach, the others keep
    their goals, and the spliced plan is valid and keeps clear of the resting body."""
    base = plan_of()
    at = 1.0
    goal = base.graph.nodes["EP8"].pos
    sweeps = [Sweep("cf4", goal, goal, at, at, rest=True)]
    failed = solve(PlanRequest(map="town", tasks={}, time_limit=10,
                               replan=Replan(base=base, at=at, left=["cf4"], sweeps=sweeps)))
    assert not failed.ok and "could not place cf1" in failed.error, failed.error
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10,
                              replan=Replan(base=base, at=at, left=["cf4"], sweeps=sweeps, strand=True)))
    assert reply.ok and reply.plan is not None, reply.error
    plan = reply.plan
    assert validate_plan(plan).ok
    short = plan.tasks["cf1"].goal
    assert short != "EP8" and plan.paths["cf1"][-1].node == short
    print(f"cf1 stops short at {short} ({plan.graph.nodes[short].kind})")
    assert {v: plan.tasks[v].goal for v in ("cf2", "cf3")} == {v: TASKS[v].goal for v in ("cf2", "cf3")}
    end = plan.paths["cf1"][-1].t
    for k in range(int((end + 5.0 - at) / 0.1)):
        p = plan.position("cf1", at + 0.1 * k)
        assert math.dist(p, goal) >= 2 * plan.model.radius - 1e-6
    # the stranded plan is planned on again (its goal for cf1 need not be a parking spot)
    again = solve(PlanRequest(map="town", tasks={}, time_limit=10,
                              replan=Replan(base=plan, at=at + 2.0, sweeps=sweeps, strand=True)))
    assert again.ok and again.plan is not None, again.error
    assert again.plan.tasks["cf1"].goal == short


def test_a_vehicle_at_rest_whose_node_a_fault_closed_holds_there_and_one_moving_in_does_not() -> None:
    """cf4 comes down right next to cf3's goal. cf3, at rest there with a new goal, can go nowhere
    (its node is closed): with `strand` it is held there, unplanned, the others planned around it.
    cf3 still driving into that goal is not held: it would drive on into cf4's body; the replan
    fails naming it (as it does without `strand`)."""
    base = plan_of()
    path = base.paths["cf3"]
    goal = base.graph.nodes[path[-1].node].pos
    for at, goals in ((path[-1].t - 0.5, {}), (path[-1].t + 0.5, {"cf3": "WP7"})):
        sweeps = [Sweep("cf4", goal, goal, at, at, rest=True)]
        failed = solve(PlanRequest(map="town", tasks={}, time_limit=10,
                                   replan=Replan(base=base, at=at, left=["cf4"], sweeps=sweeps, goals=goals)))
        assert not failed.ok and "could not place cf3" in failed.error, failed.error
        reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, replan=Replan(
            base=base, at=at, left=["cf4"], sweeps=sweeps, goals=goals, strand=True)))
        if not goals:  # moving in
            assert not reply.ok and "could not place cf3" in reply.error, reply.error
            continue
        assert reply.ok and reply.plan is not None, reply.error
        assert reply.plan.paths["cf3"][:len(path)] == path and reply.plan.paths["cf3"][-1].node == path[-1].node
        assert reply.plan.tasks["cf3"].goal == path[-1].node  # it stays: stopped short of WP7
        assert validate_plan(reply.plan).ok


def test_a_vehicle_waiting_on_the_ground_whose_node_a_fault_closed_holds_there() -> None:
    """cf4 waits at Wb4, a road node, from 11.2 to 15.2 s: the switch at 12 s falls in that wait,
    so its prefix ends with it (at 15.2 s). cf1 comes down 15 cm beside Wb4 and rests there: Wb4
    and every way out of it are closed, and cf4 can go nowhere. With `strand` it is held there, as a
    vehicle whose path ended there would be, and the others are planned around it. (Its wait
    counted as moving: in an 80-vehicle soak's replan such a car, 22 cm beside a held flyer, was
    neither placed nor held, and the replan failed naming it.)"""
    base = plan_of()
    wait = [(a.t, b.t) for a, b in itertools.pairwise(base.paths["cf4"]) if a.node == b.node == "Wb4"]
    assert wait and wait[0][0] < 12.0 < wait[0][1], base.paths["cf4"]
    x, y, z = base.graph.nodes["Wb4"].pos
    beside = (x + 0.15, y, z)
    sweeps = [Sweep("cf1", beside, beside, 12.0, 12.0, rest=True)]
    replan = Replan(base=base, at=12.0, left=["cf1"], sweeps=sweeps, strand=True)
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, replan=replan))
    assert reply.ok and reply.plan is not None, reply.error
    path = reply.plan.paths["cf4"]
    assert path[-1].node == "Wb4" and reply.plan.tasks["cf4"].goal == "Wb4", path
    assert validate_plan(reply.plan).ok


def test_a_replan_names_every_vehicle_whose_switch_node_a_body_claims_at_once() -> None:
    """At 4 s cf1 and cf2 are each on their way to a road node (Wr4, El2); cf3 and cf4 left and
    rest 15 cm beside those nodes. Neither cf1 nor cf2 can be placed in any order: the replan fails
    at once naming both (`PlanReply.unplaceable`), without trying orders, for the mission to stop
    both where they are in one go. (Named one a replan, an 80-vehicle soak's mission stopped one
    vehicle a replan, 21 replans in 15 s, while up to 13 were so at once.)"""
    base = plan_of()
    at = 4.0
    sweeps = []
    for vid, left in (("cf1", "cf3"), ("cf2", "cf4")):
        before, switch = next((a, b) for a, b in itertools.pairwise(base.paths[vid]) if b.t >= at)
        assert before.node != switch.node and base.graph.nodes[switch.node].kind != "air", (vid, before, switch)
        x, y, z = base.graph.nodes[switch.node].pos
        sweeps.append(Sweep(left, (x + 0.15, y, z), (x + 0.15, y, z), at, at, rest=True))
    started = time.perf_counter()
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, replan=Replan(
        base=base, at=at, left=["cf3", "cf4"], sweeps=sweeps, strand=True)))
    assert not reply.ok and set(reply.unplaceable) == {"cf1", "cf2"}, reply
    assert reply.failed_vehicle == reply.unplaceable[0] and "no priority order can place it" in reply.error
    assert time.perf_counter() - started < 1.0


def test_a_stranded_vehicle_whose_stop_a_body_will_come_down_on_drives_on_to_the_next_nearest() -> None:
    """cf4 comes down on cf1's goal, and cf2 is coming down 3 s after cf1 reaches its switch node
    (Wr5, a road node): cf1 cannot stop there for ever either. It is given the next nearest goal it
    can reach and keeps clear of both bodies; it was left unplanned (the mission then stops such a
    vehicle where it is: under cf2's descent)."""
    base = plan_of()
    at = 1.0
    switch = next(e for e in base.paths["cf1"] if e.t >= at)
    assert switch.node == "Wr5" and base.graph.nodes["Wr5"].kind != "air"
    goal, stop = base.graph.nodes["EP8"].pos, base.graph.nodes["Wr5"].pos
    sweeps = [Sweep("cf4", goal, goal, at, at, rest=True),
              Sweep("cf2", stop, stop, switch.t + 3.0, switch.t + 3.0, rest=True)]
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, replan=Replan(
        base=base, at=at, left=["cf4", "cf2"], sweeps=sweeps, strand=True)))
    assert reply.ok and reply.plan is not None, reply.error
    plan = reply.plan
    assert validate_plan(plan).ok
    short = plan.tasks["cf1"].goal
    assert short not in ("EP8", "Wr5") and plan.paths["cf1"][-1].node == short, short
    for k in range(int((plan.paths["cf1"][-1].t + 5.0 - at) / 0.1)):
        t = at + 0.1 * k
        p = plan.position("cf1", t)
        assert math.dist(p, goal) >= 2 * plan.model.radius - 1e-6
        if t >= switch.t + 3.0:
            assert math.dist(p, stop) >= 2 * plan.model.radius - 1e-6


def test_a_replan_the_battery_cannot_serve_names_the_vehicle() -> None:
    base = plan_of()
    # the battery, read again, holds less than it did: all the usable charge is used up
    base = msgspec.structs.replace(base, tasks={**base.tasks, "cf4": Task(
        start="WP1", goal="WP6", charge_used_ah=base.model.usable_ah)})
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10,
                              replan=Replan(base=base, at=1.0, goals={"cf4": "EP4"})))
    assert not reply.ok and "cf4" in reply.error and "short by" in reply.error, reply.error
    assert not reply.timed_out  # no time would serve it: not to be asked again


def test_a_replan_its_time_limit_ended_says_so(monkeypatch) -> None:
    """`PlanReply.timed_out`: the mission asks such a replan again, with more time
    (`tests/test_replan_burst.py`). Here the search looks at the clock at every expansion."""
    from services.planner.sipp import search

    monkeypatch.setattr(search, "DEADLINE_EVERY", 1)
    base = plan_of()
    replan = Replan(base=base, at=1.0, goals={"cf4": "EP4"})
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=1e-6, replan=replan))
    assert not reply.ok and reply.timed_out and "time limit reached" in reply.error, reply.error
    assert solve(PlanRequest(map="town", tasks={}, time_limit=10, replan=replan)).ok


def test_a_replan_naming_an_unknown_vehicle_or_node_is_refused() -> None:
    base = plan_of()
    for rp, what in ((Replan(base=base, at=1.0, left=["cf9"]), "cf9"),
                     (Replan(base=base, at=1.0, goals={"cf1": "NOPE"}), "NOPE")):
        reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, replan=rp))
        assert not reply.ok and what in reply.error, reply.error


@pytest.mark.parametrize("replanner", ["sipp", "ilp"])
def test_a_plan_of_the_ilp_is_replanned_on_its_graph_twice(replanner: str) -> None:
    """With SIPP, or with the ILP again (its answer stays on its time steps: it can be replanned
    again by the ILP: a vehicle that arrived gets a new goal while the others move)."""
    base = plan_of("ilp")
    at = airborne_at(base, "cf1")
    here = base.position("cf1", at)
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, planner=replanner, replan=Replan(
        base=base, at=at + 1.0, left=["cf1"], sweeps=[Sweep("cf1", here, (here[0], here[1], 0.0), at, at + 4.0, True)])))
    assert reply.ok and reply.plan is not None, reply.error
    assert validate_plan(reply.plan).ok and reply.planner == replanner
    first = reply.plan
    done = first.paths["cf3"][-1].t
    again = solve(PlanRequest(map="town", tasks={}, time_limit=10, planner=replanner,
                              replan=Replan(base=first, at=done + 0.3, goals={"cf3": "WP7"})))
    if replanner == "sipp":
        assert again.ok, again.error
    else:  # the ILP plans on its steps only
        assert again.ok and again.planner == "ilp", again.error
        assert all(abs(e.t / first.dt - round(e.t / first.dt)) < 1e-6 for p in again.plan.paths.values() for e in p)
    assert again.plan is not None and again.plan.paths["cf3"][-1].node == "WP7"
    assert validate_plan(again.plan).ok


def test_the_ilp_does_not_replan_a_plan_off_its_time_steps() -> None:
    reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, planner="ilp",
                              replan=Replan(base=plan_of(), at=1.0, goals={"cf3": "WP7"})))
    assert not reply.ok and "replan with sipp" in reply.error, reply.error


def test_the_road_beneath_a_held_flyer_stays_open_until_the_plan_ends() -> None:
    """cf1 is held at 7 s flying out over Wr4 (0.4 m up, 13 cm beside the road node), which cf4
    drives through at 25 s. A held flyer hovers where it is until its mission ends (`sweeps.held`):
    its spot is closed for ever, the column below it from the plan's end on (then it lands, and no
    vehicle may rest beneath it), so cf4 keeps its way beneath it. (Its whole column for ever sent
    cf4 round the town, arriving 8.5 s later; in a 10-minute 80-vehicle soak such a replan could not
    place a car at all, and the cars stopped for it stopped 35 more.) With the column closed from
    20 s on, cf4 goes round it."""
    base = plan_of()
    t, end = 7.0, plan_end(base)
    here = base.position("cf1", t)
    assert here[2] > 0.3 and math.dist(here[:2], base.graph.nodes["Wr4"].pos[:2]) < 0.15

    def way(plan: Plan) -> list[tuple[str, float]]:
        return [(e.node, round(e.t, 3)) for e in plan.paths["cf4"]]

    for closed_from in (end, 20.0):
        spot, column = held("cf1", here, t, 0.0, closed_from)
        assert spot.rest and spot.p0 == spot.p1 == here and spot.t0 == t
        assert column.rest and column.p0 == here and column.p1 == (here[0], here[1], 0.0) and column.t0 == closed_from
        reply = solve(PlanRequest(map="town", tasks={}, time_limit=10, replan=Replan(
            base=base, at=t + 1.0, left=["cf1"], sweeps=[spot, column], strand=True)))
        assert reply.ok and reply.plan is not None, reply.error
        assert validate_plan(reply.plan).ok and reply.plan.tasks["cf4"].goal == "WP6"
        if closed_from == end:
            assert way(reply.plan) == way(base)
        else:
            assert "Wr4" not in [node for node, _ in way(reply.plan)], way(reply.plan)


def test_a_descents_column_frees_from_the_top_as_the_body_comes_down() -> None:
    """`sweeps.descent`: the whole column while the descent may not have begun, then below the
    highest the body may be (the slowest descent assumed), down to its foot, where it rests."""
    top, foot = (1.0, 2.0, 1.0), (1.0, 2.0, 0.0)
    pieces = descent("cf9", top, foot, 10.0)
    moving, rest = pieces[:-1], pieces[-1]
    assert rest.rest and rest.p0 == rest.p1 == foot and rest.t0 == 10.0
    assert moving[0].t0 == 10.0 and moving[-1].t1 == pytest.approx(10.0 + DESCENT_S_PER_M + REST_S)
    assert all(a.t1 == b.t0 for a, b in itertools.pairwise(moving))  # no gap in time
    for s in moving:
        assert s.p1 == foot  # it may fall: always down to the ground
        highest = 1.0 - max(0.0, s.t0 - 10.0 - REST_S) / DESCENT_S_PER_M
        assert s.p0[2] == pytest.approx(max(highest, 0.0))
    assert moving[-1].p0[2] < 0.1 < moving[len(moving) // 2].p0[2] < 1.0


CITY_32 = ("cf01:P2_3_0>P7_8_0 cf02:P9_6_1>P9_7_0 cf03:P1_0_1>P3_7_0 cf04:P4_3_1>P9_8_0 cf05:P2_0_0>P1_6_1 "
           "cf06:P8_4_0>P2_1_0 cf07:P7_6_1>P8_1_0 cf08:P8_0_0>P8_9_1 cf09:P6_5_0>P5_0_1 cf10:P3_5_0>P0_9_1 "
           "cf11:P1_6_0>P6_4_0 cf12:P8_3_0>P8_9_0 cf13:P0_5_0>P7_0_1 cf14:P6_6_0>P0_7_0 cf15:P7_3_0>P6_5_1 "
           "cf16:P0_0_0>P6_2_0 cf17:P7_6_0>P5_9_0 cf18:P4_5_1>P1_4_1 cf19:P3_8_1>P5_6_1 cf20:P1_7_0>P0_8_0 "
           "cf21:P5_4_0>P4_2_0 cf22:P9_1_0>P2_9_1 cf23:P0_3_1>P2_5_1 cf24:P0_2_0>P0_7_1 cf25:P5_5_0>P3_4_1 "
           "cf26:P4_6_0>P0_9_0 cf27:P0_1_0>P2_5_0 cf28:P9_4_1>P5_8_1 cf29:P7_4_1>P8_7_1 cf30:P3_2_0>P4_9_1 "
           "cf31:P5_8_0>P5_2_1 cf32:P1_8_0>P7_7_0")
"""32 tasks on city934 (a soak's draw, seed 1) whose fifth replan, after four drives were held and
one flight came down, hit the crossing of a prefix's last step."""


def test_a_replan_whose_vehicles_cross_a_prefix_is_planned_again_in_another_order(tmp_path: Path, monkeypatch) -> None:
    """SIPP reserves a prefix's last step only once its vehicle is placed, so one placed earlier
    may cross it; the validator finds the contact and SIPP plans again with the later of the two
    first (a 32-vehicle soak's replan failed this way). In the last replan cf21's and cf25's
    prefixes end at g4_4 (8.9 s, 12.4 s): the first order now places cf25 first (`priority`) and is
    valid; cf21 first, as that order did, it now plans against cf25's last step into g4_4
    (`replan._coming_near`) and is valid too; without that, it crossed cf25's last step, which is
    what the validation and the next order are for."""
    from services.mission.sweeps import left_vehicle
    from services.planner.maps.generate import VEHICLE, city934, to_yaml
    from services.planner.maps.loading import load_graph
    from services.planner.registry import _replan_with
    from services.planner.sipp import replan

    city = tmp_path / "city934.yaml"  # as the soak planned it: no turns budgeted at corners (sipp/turns.py)
    city.write_text(to_yaml(msgspec.structs.replace(city934(), vehicle=VEHICLE)))
    tasks = {v: Task(start=a, goal=b) for v, a, b in (x.replace(">", ":").split(":") for x in CITY_32.split())}
    reply = solve(PlanRequest(map=str(city), tasks=tasks, time_limit=60))
    assert reply.ok and reply.plan is not None, reply.error
    plan, sweeps = reply.plan, []
    for vid, t, kind in (("cf19", 3.367, "tracking_hold"), ("cf11", 4.385, "tracking_hold"),
                         ("cf04", 5.479, "emergency_landing"), ("cf15", 5.721, "tracking_hold"),
                         ("cf30", 6.539, "tracking_hold")):
        sweeps += left_vehicle(vid, kind, plan.position(vid, t), t, 0.0, None, plan_end(plan))
        req = PlanRequest(map=str(city), tasks={}, time_limit=1.0,
                          replan=Replan(base=plan, at=t + 1.0, left=[vid], sweeps=sweeps, strand=True))
        first, _ = _replan_with(load_graph(city), req, "sipp", 1.0)
        once, _ = _replan_with(load_graph(city), req, "sipp", 1.0, ["cf21"])
        with monkeypatch.context() as m:
            m.setattr(replan, "_coming_near", lambda graph, order: {})
            blind, later = _replan_with(load_graph(city), req, "sipp", 1.0, ["cf21"])
        reply = solve(req)
        assert reply.ok and reply.plan is not None, reply.error
        assert validate_plan(reply.plan).ok
        plan = reply.plan
    assert first.ok, first.error
    assert once.ok, once.error
    assert not blind.ok and "contact" in blind.error and later == "cf25", blind.error


@pytest.mark.compute
def test_a_columns_nodes_and_edges_are_those_its_samples_touch() -> None:
    """`touched_by_segment` tests a column (a held vehicle's, a descent's: most sweeps) in closed
    form: the same nodes and edges as its sampled test of any other segment finds for a column
    leaning by a picometre."""
    graph = load_graph("city934")
    pos = np.asarray(graph.pos)
    for p in pos[np.random.default_rng(1).choice(len(pos), 20)]:
        top, foot, leaning = (p[0], p[1], p[2] + 0.3), (p[0], p[1], 0.0), (p[0] + 1e-12, p[1], 0.0)
        for extra in (0.0, 0.1):
            nodes, edges = touched_by_segment(graph, top, foot, extra)
            sampled_nodes, sampled_edges = touched_by_segment(graph, top, leaning, extra)
            assert len(nodes) and len(edges)
            assert nodes.tolist() == sampled_nodes.tolist() and edges.tolist() == sampled_edges.tolist()


DATA = Path(__file__).parent / "data"


def test_vehicles_whose_prefixes_end_at_one_node_are_placed_the_last_to_arrive_first() -> None:
    """The first priority order: earliest switch first, but the vehicles whose prefixes end at one
    node together, at the earliest one's place, the one arriving last first."""
    task = Task(start="s", goal="g")

    def leg(vid: str, start: int, depart: float) -> Leg:
        return Leg(vid, [], start, depart, 0, 1.0, task)

    legs = [leg("a", 1, 10.0), leg("b", 2, 11.0), leg("c", 1, 12.6), leg("d", 3, 13.0), leg("e", 1, 11.5)]
    assert [x.vid for x in priority(legs)] == ["c", "e", "a", "b", "d"]
    assert [x.vid for x in priority(legs, first=["d"])] == ["d", "c", "e", "a", "b"]


@pytest.mark.compute
def test_a_soaks_replan_whose_first_order_met_head_on_is_valid_on_its_first_order() -> None:
    """An 80-vehicle soak's replan, kept by its planner (`fleet planner --keep-failed`; 80 vehicles
    on city934 around cf71, from 8.7 s): cf73's and cf21's prefixes end at g4_7 (10.07 s, 12.67 s),
    cf38's and cf04's at a0_8_10 (8.93 s, 9.62 s). In the order of their switches cf73 left g4_7
    down the road cf21 was coming up (0 m apart at 11.37 s) and cf38 met cf04 in the air; the
    validation refused the plan, and on the loaded machine no time was left for another order.
    Placed the last to arrive first, the first order's plan is valid."""
    req = read_request(DATA / "replan_head_on.msgpack")
    assert req.replan is not None
    graph = load_graph(req.map)
    reply, later = _replan_with(graph, msgspec.structs.replace(req, time_limit=60.0), "sipp", 60.0)
    assert reply.ok and later is None, reply.error
    order = [leg.vid for leg in priority(split(graph, req.replan)[1])]
    assert order.index("cf21") < order.index("cf73") and order.index("cf04") < order.index("cf38")


@pytest.mark.compute
def test_a_vehicle_placed_before_another_plans_against_its_last_step() -> None:
    """An 80-vehicle soak's replan (city934 around cf71 and cf17, from 10.6 s): cf29 waits at g2_0
    until 10.59 s while cf49 comes up the road into it (there at 12.37 s). Placed before cf49, cf29
    searched without cf49's last step and took off at g2_0 with cf49 12.8 cm away; the validation
    refused the plan, the other order could not place cf29, and the mission aborted. Now a vehicle
    plans against the last steps coming near its switch node (`replan._coming_near`): in either
    order cf29 drives on along the road first and the plan is valid on its first order."""
    req = read_request(DATA / "replan_last_step.msgpack")
    assert req.replan is not None
    graph = load_graph(req.map)
    req = msgspec.structs.replace(req, time_limit=60.0)
    for first in ([], ["cf29"]):
        reply, later = _replan_with(graph, req, "sipp", 60.0, first)
        assert reply.ok and reply.plan is not None and later is None, (first, reply.error)
        after = [e.node for e in reply.plan.paths["cf29"] if e.t > req.replan.at]
        assert next(n for n in after if n != "g2_0") == "g3_0", after[:3]
        assert validate_plan(reply.plan, check_cost=False).ok


def test_a_stranded_vehicle_goes_on_to_its_goal_once_a_later_replan_finds_it_in_reach(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    """cf4 comes down on cf1's goal: the mission's replan strands cf1 short of it. Once cf4 is gone
    (its body no longer in the way), the next replan, asked for anything, asks for cf1's goal again
    (`MissionRunner._stranded_goals`): cf1 goes on to it, stranded no more, and the mission says so.
    (Without it a replan around two held vehicles stranded one in an 80-vehicle soak; both came
    back, every vehicle arrived, and the mission failed for the stranded one's goal.)"""
    keys = Keys("strand")
    runner = MissionRunner(MissionSpec(map="town", tasks=TASKS, planner="sipp"), ZenohConfig.client(zenoh_router),
                           keys, progress=False)
    runner._session = zsession()  # (its plans handed out on a real session; nobody listens)
    runner._plans = runner.publishers(lambda vid: keys.vehicle(vid, "plan"), VehiclePlan)
    runner.plan, runner.t0 = plan_of(), time.time()
    goal = runner.plan.graph.nodes["EP8"].pos

    def replan(at: float, left: list[str], sweeps: list[Sweep]) -> None:
        request = PlanRequest(map="town", tasks={}, time_limit=10, replan=Replan(
            base=runner.plan, at=at, left=left, sweeps=sweeps, goals=runner._stranded_goals(left), strand=True))
        reply = solve(request)
        assert reply.ok, reply.error
        assert runner._apply_replan(reply, at, 0.1, left, {}) is None

    replan(1.0, ["cf4"], [Sweep("cf4", goal, goal, 1.0, 1.0, rest=True)])
    assert runner.stranded == {"cf1": "EP8"} and runner.plan.tasks["cf1"].goal != "EP8"
    assert any(e.startswith("cf1: 'EP8' out of reach now") for e in runner.events), runner.events
    replan(3.0, [], [])  # cf4's body gone
    assert runner.stranded == {} and runner.plan.tasks["cf1"].goal == "EP8", runner.plan.tasks["cf1"]
    assert runner.plan.paths["cf1"][-1].node == "EP8" and not runner.reports["cf1"].arrived
    assert "cf1: 'EP8' in reach again: it goes on to it" in runner.events, runner.events
    assert validate_plan(runner.plan).ok
