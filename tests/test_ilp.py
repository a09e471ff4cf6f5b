"""Multi-commodity flow ILP (paper 000 §V-E, Alg. 3, eq. 6-7; Yu & LaValle 2015) on the
uniform-time-step graph: every plan goes through the independent validator
(services/planner/validate.py), on the shipped maps and on small maps that force a swap in a
corridor, crossing air edges, the battery, and against prioritized SIPP's cost."""

from __future__ import annotations

import importlib.util

import msgspec
import numpy as np
import pytest

from common.domain.mapfile import MAPS_DIR, MapSpec, ParkingSpot, RoadNode, Roads, load_map
from common.domain.planfile import Task, read_plan
from services.cli import main as fleet_main
from services.planner.graph.fleet_graph import FleetGraph, build_graph
from services.planner.ilp.arcs import arc_table
from services.planner.ilp.network import Fleet, carry_over, vehicle_columns
from services.planner.ilp.planner import decode, plan_ilp
from services.planner.ilp.solve import HorizonResult, solve_horizon
from services.planner.maps.loading import GraphProblem, load_graph
from services.planner.maps.tasks import load_scenario, random_tasks
from services.planner.registry import run_planner
from services.planner.result import PlanResult, to_plan
from services.planner.validate import ValidationReport, validate_plan

HAVE_SIPP = importlib.util.find_spec("services.planner.sipp.planner") is not None


def plan_valid(graph: FleetGraph, tasks: dict[str, Task], mu: float = 0.5, time_limit: float = 30.0) -> PlanResult:
    """Plan with the ILP through the planner registry and require the validator's approval; every
    entry is one time step after the previous one (moves and waits alike)."""
    plan, result = run_planner(GraphProblem(graph, graph.name, tasks), "ilp", mu, time_limit, 0)
    assert plan is not None, result.error
    report = validate_plan(plan)
    assert report.ok, report.summary()
    assert result.cost == pytest.approx(report.cost, rel=1e-9)
    for vid, path in result.paths.items():
        assert path[0].node == tasks[vid].start and path[0].t == 0.0
        assert path[-1].node == tasks[vid].goal
        assert np.allclose(np.diff([e.t for e in path]), graph.dt)
    assert result.mip_gap is not None
    return result


def tasks_of(**pairs: tuple[str, str]) -> dict[str, Task]:
    return {vid: Task(start=s, goal=g) for vid, (s, g) in pairs.items()}


def nodes(result: PlanResult, vid: str) -> list[str]:
    return [e.node for e in result.paths[vid]]


def airborne(graph: FleetGraph, path: list[str]) -> bool:
    return any(graph.airborne[graph.index[n]] for n in path)


def validate_paths(graph: FleetGraph, tasks: dict[str, Task], result: PlanResult, mu: float) -> ValidationReport:
    return validate_plan(to_plan(graph, graph.name, "ilp", mu, tasks, result))


# -- the town (§VII-C): 8 vehicles, six of them fly over the gap -----------------------------------


def test_town_8_vehicles_solved_to_the_gap() -> None:
    """On the one-time-step graph (air nodes one fly step apart) the first horizon is solved to the
    gap in about a second; one more step is cheaper, and its plan (optimal: HiGHS proves it in ~7 s)
    comes back within the extension's time budget with an honest gap of about 2 %."""
    graph = load_graph("town", uniform=True)
    tasks = load_scenario(MAPS_DIR / "scenarios" / "town_8.yaml", graph)
    result = plan_valid(graph, tasks)
    crossing = [v for v, t in tasks.items() if t.start[0] != t.goal[0]]
    assert len(crossing) == 6
    for vid in crossing:
        assert airborne(graph, nodes(result, vid)), f"{vid} crossed the gap without flying"
    assert result.mip_gap <= 0.03
    assert result.cost * (1 - result.mip_gap) >= result.stats["lower_bound"] - 1e-9


def test_goals_on_other_vehicles_starts_including_a_cycle() -> None:
    """Three vehicles rotate through three spots while two others swap between the regions: no
    vehicle can wait for a free goal, they must move together. A longer horizon is cheaper here
    than the first feasible one: the horizon extension finds it."""
    graph = load_graph("town", uniform=True)
    tasks = tasks_of(cf1=("WP1", "WP2"), cf2=("WP2", "WP3"), cf3=("WP3", "WP1"), cf4=("EP1", "WP4"), cf5=("WP4", "EP1"))
    result = plan_valid(graph, tasks)
    assert result.stats["horizon"] > result.stats["first_horizon"]


def test_time_limit_returns_the_incumbent_with_its_gap() -> None:
    """A congested town scenario that HiGHS cannot close in 0.3 s: the prioritized first plan (or a
    better incumbent) comes back with an honest gap."""
    graph = load_graph("town", uniform=True)
    result = plan_valid(graph, random_tasks(graph, 8, 1), time_limit=0.3)
    assert result.stats["timed_out"] == 1.0
    assert result.mip_gap > 1e-4
    assert result.cost * (1 - result.mip_gap) >= result.stats["lower_bound"] - 1e-9


# -- a corridor: the vehicles can only swap by one pulling into a side spot ------------------------


def corridor_map(pocket: bool) -> FleetGraph:
    """A road C0-C4 (0.4 m apart) with spots PW and PE beside its ends, optionally a side spot PM
    beside C2, and no air: the only passing place is PM."""
    road = {f"C{i}": RoadNode(0.4 * i, 0.0) for i in range(5)}
    spots = [ParkingSpot(id="PW", x=0.0, y=-0.2, road="C0"), ParkingSpot(id="PE", x=1.6, y=-0.2, road="C4")]
    if pocket:
        spots.append(ParkingSpot(id="PM", x=0.8, y=0.2, road="C2"))
    spec = MapSpec(name="corridor", roads=Roads(nodes=road, two_way=[(f"C{i}", f"C{i + 1}") for i in range(4)]),
                   parking=spots, time_step=2.0)
    return build_graph(spec, spec.time_step)


def test_swap_through_a_corridor_uses_the_side_spot() -> None:
    graph = corridor_map(pocket=True)
    result = plan_valid(graph, tasks_of(east=("PW", "PE"), west=("PE", "PW")))
    assert sum("PM" in nodes(result, v) for v in result.paths) == 1  # one pulls aside, the other passes


def test_swap_without_a_passing_place_fails_clearly() -> None:
    result = plan_ilp(corridor_map(pocket=False), tasks_of(east=("PW", "PE"), west=("PE", "PW")), 0.5, 20.0, 0)
    assert not result.ok
    assert "no collision-free plan within" in result.error


# -- crossing edges ----------------------------------------------------------------------------------


def crossing_map() -> FleetGraph:
    """Two roads crossing in an X without a node where they cross (W-E and S-N, 0.85 m each, split
    into 5 one-step pieces whose middle ones cross), joined by W-N and S-E; a spot beside each end."""
    road = {"W": RoadNode(0.0, 0.0), "E": RoadNode(0.6, 0.6), "S": RoadNode(0.6, 0.0), "N": RoadNode(0.0, 0.6)}
    spots = [ParkingSpot(id="PW", x=-0.2, y=0.0, road="W"), ParkingSpot(id="PE", x=0.8, y=0.6, road="E"),
             ParkingSpot(id="PS", x=0.8, y=0.0, road="S"), ParkingSpot(id="PN", x=-0.2, y=0.6, road="N")]
    spec = MapSpec(name="crossing", roads=Roads(nodes=road, two_way=[("W", "E"), ("S", "N"), ("W", "N"), ("S", "E")]),
                   parking=spots,
                   time_step=2.0)
    return build_graph(spec, spec.time_step)


def test_crossing_edges_without_a_shared_node_are_avoided() -> None:
    """Each vehicle alone drives straight through the X; together they would meet mid-crossing at the
    same step without sharing a node: only the geometric edge-edge constraint separates them."""
    graph = crossing_map()
    tasks = tasks_of(a=("PW", "PE"), c=("PS", "PN"))
    alone = {v: plan_ilp(graph, {v: t}, 0.5, 10.0, 0) for v, t in tasks.items()}
    naive = PlanResult(ok=True, paths={v: r.paths[v] for v, r in alone.items()}, cost=sum(r.cost for r in alone.values()))
    occupied = [{(e.node, e.t) for e in p} for p in naive.paths.values()]
    assert not occupied[0] & occupied[1], "the naive paths must not meet at a node"
    report = validate_paths(graph, tasks, naive, 0.5)
    assert [(c.pos_a[0], c.pos_a[1]) for c in report.contacts] != []
    assert all(abs(c.pos_a[0] - 0.3) < 0.15 and abs(c.pos_a[1] - 0.3) < 0.15 for c in report.contacts)
    result = plan_valid(graph, tasks)
    assert result.cost > naive.cost  # one of them had to wait


# -- the battery (eq. 6) -------------------------------------------------------------------------------


def weak_battery(name: str, capacity_ah: float) -> FleetGraph:
    spec = load_map(name)
    vehicle = msgspec.structs.replace(spec.vehicle, capacity_ah=capacity_ah, reserve_ah=0.0)
    spec = msgspec.structs.replace(spec, vehicle=vehicle)
    return build_graph(spec, spec.time_step)


def test_task_beyond_the_battery_fails_naming_the_vehicle() -> None:
    graph = weak_battery("town", 0.002)
    drive_only = tasks_of(cf1=("WP1", "WP6"))
    plan_valid(graph, drive_only)
    result = plan_ilp(graph, {**drive_only, "cf2": Task(start="WP2", goal="EP4")}, 0.5, 10.0, 0)
    assert not result.ok
    assert result.failed_vehicle == "cf2"
    assert "battery" in result.error and "eq. 6" in result.error


def test_battery_turns_a_flight_into_a_drive() -> None:
    """mu = 0 (time only): the far corner of fig6 is reached fastest through the air; with 0.005 Ah
    not even a hop fits (takeoff and landing alone draw 0.0024 Ah, the drive 0.0034 Ah; eq. 6), so
    the vehicle drives and arrives later."""
    tasks = tasks_of(cf1=("P0_0_0", "P6_6_0"))
    fast = plan_valid(load_graph("fig6", uniform=True), tasks, mu=0.0)
    assert airborne(load_graph("fig6", uniform=True), nodes(fast, "cf1"))
    graph = weak_battery("fig6", 0.005)
    frugal = plan_valid(graph, tasks, mu=0.0)
    assert not airborne(graph, nodes(frugal, "cf1"))
    assert frugal.paths["cf1"][-1].t > fast.paths["cf1"][-1].t
    assert max(validate_paths(graph, tasks, frugal, 0.0).charge_ah.values()) <= graph.model.usable_ah


# -- against prioritized SIPP (§VII-B, Fig. 7) ----------------------------------------------------------


def on_grid(result: PlanResult, dt: float) -> bool:
    times = np.array([e.t for p in result.paths.values() for e in p])
    return bool(np.allclose(times / dt, np.round(times / dt)))


@pytest.mark.skipif(not HAVE_SIPP, reason="services/planner/sipp/planner.py is not there yet")
def test_ilp_costs_no_more_than_sipp_on_grid125() -> None:
    """Both on the uniform graph, costs as the validator recomputes them. The ILP is optimal among
    plans on its time grid; SIPP may wait a fraction of a step (continuous time) and then be a little
    cheaper, so the comparison is asserted on the scenarios where SIPP's plan is on the grid too."""
    graph = load_graph("grid125", uniform=True)
    compared = 0
    for seed in range(8):
        problem = GraphProblem(graph, "grid125", random_tasks(graph, 6, seed))
        costs, results = {}, {}
        for planner in ("ilp", "sipp"):
            plan, results[planner] = run_planner(problem, planner, 0.5, 30.0, 0)
            assert plan is not None, results[planner].error
            report = validate_plan(plan)
            assert report.ok, report.summary()
            costs[planner] = report.cost
        if on_grid(results["sipp"], graph.dt):
            compared += 1
            assert costs["ilp"] <= costs["sipp"] * (1 + 1e-6), f"seed {seed}"
    assert compared >= 4


def test_a_plan_carries_over_to_a_longer_horizon_at_the_same_cost() -> None:
    """A plan for T steps is one for T + k (staying at the goals is free): the horizon extension
    starts from it, so it can only improve."""
    graph = load_graph("grid125", uniform=True)
    tasks = random_tasks(graph, 4, 3)
    vids = list(tasks)
    fleet = Fleet.of(graph, [tasks[v].start for v in vids], [tasks[v].goal for v in vids], 0.5)
    orders = [list(range(len(vids)))]
    short = solve_horizon(graph, arc_table(graph), fleet, 12, 10.0, 0, orders)
    longer = vehicle_columns(graph, fleet, 15)
    carried = carry_over(short.columns, short.chosen, longer, 15, fleet.goals, graph.n_nodes, graph.n_edges)
    assert carried is not None and len(carried) == 15 * len(vids)
    assert longer.cost[carried].sum() == pytest.approx(short.objective)
    as_long = HorizonResult(15, "optimal", longer, carried, short.objective, 0.0, None, 0.0, 0.0)
    assert decode(graph, fleet, vids, as_long) == decode(graph, fleet, vids, short)


def test_fleet_plan_cli_writes_a_valid_ilp_plan(tmp_path) -> None:
    out = tmp_path / "p.json"
    assert fleet_main(["plan", "--map", "grid125", "--random", "5", "--planner", "ilp", "--out", str(out)]) == 0
    plan = read_plan(out)
    assert plan.planner == "ilp" and plan.dt == 4.0 and plan.mip_gap is not None
    assert validate_plan(plan).ok
