"""Vehicles with capabilities (issue 14, DESIGN.md "Vehicles"): stock Crazyflies only fly, ground
robots only drive, flying cars do both; SIPP and the ILP use only the edge kinds a vehicle can
take, the validator refuses a plan that does not, and tasks a vehicle cannot do are refused naming it."""

from __future__ import annotations

import pytest

from common.domain.planfile import Task
from common.domain.scenario import read_scenario
from common.domain.vehicle_model import CAPABLE_EDGES
from common.errors import InputError
from services.planner.maps.loading import GraphProblem, load_graph
from services.planner.maps.tasks import check_tasks
from services.planner.registry import run_planner
from services.planner.validate import validate_plan

MIXED = {
    "c1": Task(start="WP1", goal="EP4"),                          # a flying car crossing the gap
    "d1": Task(start="Wl2", goal="Ec3", capabilities="fly"),      # a stock Crazyflie
    "d2": Task(start="El3", goal="Wc2", capabilities="fly"),
    "r1": Task(start="WP5", goal="WP8", capabilities="drive"),    # a ground robot in the west
}


def _kinds(plan, vid: str) -> set[str]:
    kinds = {(u, v): k for u, v, k in plan.graph.edges}
    path = plan.paths[vid]
    return {kinds[(a.node, b.node)] for a, b in zip(path, path[1:], strict=False) if a.node != b.node}


@pytest.mark.parametrize("planner", ["sipp", "ilp"])
def test_each_vehicle_uses_only_the_edges_it_can_take(planner: str) -> None:
    graph = load_graph("town", uniform=planner == "ilp")
    check_tasks(MIXED, graph, "test")
    plan, result = run_planner(GraphProblem(graph, "town", MIXED), planner, 0.5, 60.0, 0)
    assert plan is not None, result.error
    report = validate_plan(plan)
    assert report.ok, report.errors
    for vid, task in MIXED.items():
        assert _kinds(plan, vid) <= CAPABLE_EDGES[task.capabilities], (vid, _kinds(plan, vid))
    assert {"takeoff", "fly", "land"} <= _kinds(plan, "d1") and _kinds(plan, "r1") == {"drive"}
    assert plan.tasks["d1"].capabilities == "fly"  # the plan file says what each vehicle is


def test_the_fly_only_scenario_plans() -> None:
    scenario = read_scenario("maps/scenarios/town_fly.yaml")
    graph = load_graph("town")
    check_tasks(dict(scenario.tasks), graph, "town_fly")
    plan, result = run_planner(GraphProblem(graph, "town", dict(scenario.tasks)), "sipp", 0.5, 30.0, 0)
    assert plan is not None and validate_plan(plan).ok, result.error
    assert all(_kinds(plan, vid) <= {"takeoff", "fly", "land"} for vid in plan.paths)


def test_tasks_a_vehicle_cannot_do_are_refused_naming_it() -> None:
    graph = load_graph("town")
    with pytest.raises(InputError) as err:
        check_tasks({"d1": Task(start="WP1", goal="Er4", capabilities="fly")}, graph, "scenario.yaml")
    assert err.value.field == "tasks.d1.start" and "only flies" in err.value.problem
    plan, result = run_planner(GraphProblem(graph, "town", {"r1": Task(start="WP1", goal="EP4", capabilities="drive")}),
                               "sipp", 0.5, 10.0, 0)
    assert plan is None and result.failed_vehicle == "r1" and "only drive edges" in result.error


def test_the_validator_refuses_an_edge_the_vehicle_cannot_take() -> None:
    graph = load_graph("town")
    plan, _ = run_planner(GraphProblem(graph, "town", {"c1": Task(start="WP1", goal="EP4")}), "sipp", 0.5, 10.0, 0)
    assert plan is not None
    as_drone = plan.__class__(**{**{f: getattr(plan, f) for f in plan.__struct_fields__},
                                 "tasks": {"c1": Task(start="WP1", goal="EP4", capabilities="fly")}})
    errors = validate_plan(as_drone).errors
    assert any("a drive edge" in e and "capabilities are fly" in e for e in errors), errors
