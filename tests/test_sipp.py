"""Prioritized multimodal SIPP (paper 000 §V-D, Alg. 1-2): every plan goes through the independent
validator (services/planner/validate.py), on the shipped maps and on small hand-built maps that
force the hard cases: a swap through a single lane, crossing air edges, the battery, mu."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import numpy as np
import pytest

from common.domain.mapfile import (
    MAPS_DIR,
    AirRegion,
    Helipad,
    MapSpec,
    ParkingSpot,
    RoadNode,
    Roads,
    load_map,
)
from common.domain.planfile import Task, read_plan
from services.cli import main as fleet_main
from services.planner.graph.fleet_graph import FleetGraph, build_graph
from services.planner.maps.generate import town
from services.planner.maps.loading import load_graph, load_scenario
from services.planner.maps.movingai_graph import load_movingai, load_scen
from services.planner.result import PlanResult, to_plan
from services.planner.sipp.planner import plan_sipp
from services.planner.sipp.safe_intervals import carve
from services.planner.sipp.turns import edge_headings, turn_time
from services.planner.sipp.windows import edge_pair_windows
from services.planner.validate import validate_plan

pytestmark = pytest.mark.compute

MOVINGAI_DIR = Path(__file__).resolve().parents[2] / "shared" / "benchmarks" / "movingai"
MOVINGAI = str(MOVINGAI_DIR / "random-32-32-10")
needs_movingai = pytest.mark.skipif(
    not (Path(MOVINGAI + ".map").is_file() and Path(MOVINGAI + "-random-1.scen").is_file()),
    reason=f"needs the shared MovingAI benchmark files ({MOVINGAI}.map and -random-1.scen), not present here",
)


def plan_valid(graph: FleetGraph, tasks: dict[str, Task], mu: float = 0.5, seed: int = 0) -> PlanResult:
    """Plan with SIPP and require the independent validator's approval."""
    result = plan_sipp(graph, tasks, mu, 20.0, seed)
    assert result.ok, result.error
    report = validate_plan(to_plan(graph, graph.name, "sipp", mu, tasks, result))
    assert report.ok, report.summary()
    return result


def tasks_of(**pairs: tuple[str, str]) -> dict[str, Task]:
    return {vid: Task(start=s, goal=g) for vid, (s, g) in pairs.items()}


def visited(result: PlanResult, vid: str) -> list[str]:
    return [e.node for e in result.paths[vid]]


def airborne(graph: FleetGraph, nodes: list[str]) -> bool:
    return any(graph.airborne[graph.index[n]] for n in nodes)


# -- the town (§VII-C): two road regions joined only through the air ---------------------------------


@pytest.mark.parametrize("uniform", [False, True], ids=["base", "uniform"])
def test_town_8_vehicles_fly_over_the_gap(uniform: bool) -> None:
    graph = load_graph("town", uniform=uniform)
    tasks = load_scenario(MAPS_DIR / "scenarios" / "town_8.yaml", graph)
    result = plan_valid(graph, tasks)
    crossing = [v for v, t in tasks.items() if t.start[0] != t.goal[0]]
    assert len(crossing) == 6
    for vid in crossing:
        assert airborne(graph, visited(result, vid)), f"{vid} crossed the gap without flying"
    for vid, path in result.paths.items():
        assert path[0].node == tasks[vid].start and path[0].t == 0.0
        assert path[-1].node == tasks[vid].goal
    if uniform:  # every traversal takes exactly one time step
        steps = [b.t - a.t for p in result.paths.values() for a, b in zip(p, p[1:], strict=False) if a.node != b.node]
        assert np.allclose(steps, graph.dt)


def test_goals_on_other_vehicles_starts_including_a_cycle() -> None:
    graph = load_graph("town")
    tasks = tasks_of(cf1=("WP1", "WP2"), cf2=("WP2", "WP3"), cf3=("WP3", "WP1"), cf4=("EP1", "WP4"), cf5=("WP4", "EP1"))
    plan_valid(graph, tasks)


@pytest.mark.parametrize("uniform", [False, True], ids=["base", "uniform"])
def test_random_scenarios_on_grid125_validate(uniform: bool) -> None:
    from services.planner.maps.tasks import random_tasks

    graph = load_graph("grid125", uniform=uniform)
    for seed in range(4):
        plan_valid(graph, random_tasks(graph, 6, seed), mu=[0.0, 0.3, 0.7, 1.0][seed], seed=seed)


# -- a single lane: the vehicles must take turns, or pass at a siding ---------------------------------


def lane_map(siding: bool) -> FleetGraph:
    """A road L0-L4 (0.3 m apart) with spots PA, PW beside its west end and PB, PE beside its east
    end, optionally a dead-end siding S 0.25 m north of L3, and no air: nowhere else to pass."""
    nodes = {f"L{i}": RoadNode(0.3 * i, 0.0) for i in range(5)}
    two_way = [(f"L{i}", f"L{i + 1}") for i in range(4)]
    if siding:
        nodes["S"] = RoadNode(0.9, 0.25)
        two_way.append(("L3", "S"))
    parking = [
        ParkingSpot(id="PA", x=0.0, y=-0.17, road="L0"), ParkingSpot(id="PW", x=-0.17, y=0.0, road="L0"),
        ParkingSpot(id="PB", x=1.2, y=-0.17, road="L4"), ParkingSpot(id="PE", x=1.37, y=0.0, road="L4"),
    ]
    return build_graph(MapSpec(name="lane", roads=Roads(nodes=nodes, two_way=two_way), parking=parking))


def test_opposite_directions_on_a_single_lane_take_turns() -> None:
    graph = lane_map(siding=False)
    result = plan_valid(graph, tasks_of(east=("PA", "PE"), west=("PB", "PW")))
    # the second vehicle waits on its spot until the first has passed
    later = max(result.paths, key=lambda v: result.paths[v][1].t)
    assert result.paths[later][1].node == result.paths[later][0].node
    assert result.paths[later][1].t > 10.0


def test_swap_through_a_single_lane_uses_the_siding() -> None:
    graph = lane_map(siding=True)
    result = plan_valid(graph, tasks_of(east=("PA", "PB"), west=("PB", "PA")))
    assert any("S" in visited(result, v) for v in result.paths)


def test_swap_without_a_siding_fails_naming_a_vehicle() -> None:
    result = plan_sipp(lane_map(siding=False), tasks_of(east=("PA", "PB"), west=("PB", "PA")), 0.5, 10.0, 0)
    assert not result.ok
    assert result.failed_vehicle in ("east", "west")
    assert result.error.startswith(result.failed_vehicle)
    assert "every priority order failed" in result.error


# -- crossing air edges ---------------------------------------------------------------------------------


def crossing_map() -> FleetGraph:
    """Four helipads at the corners of a 0.5 m square under one air layer with diagonals: the two
    diagonals cross mid-air without sharing a node."""
    corners = {"H1": (0.0, 0.0), "H2": (0.5, 0.0), "H3": (0.5, 0.5), "H4": (0.0, 0.5)}
    return build_graph(
        MapSpec(
            name="crossing",
            roads=Roads(nodes={}),
            helipads=[Helipad(id=h, x=x, y=y, z=0.2) for h, (x, y) in corners.items()],
            air=AirRegion(bounds=(0.0, 0.0, 0.5, 0.5), layers=[0.4], spacing=0.5, diagonals=True),
        )
    )


def test_crossing_diagonal_air_edges_are_avoided() -> None:
    graph = crossing_map()
    tasks = tasks_of(a=("H1", "H3"), b=("H2", "H4"))
    # each alone flies its diagonal at the same time: together the bodies would meet mid-air
    alone = {v: plan_sipp(graph, {v: t}, 0.5, 5.0, 0) for v, t in tasks.items()}
    naive = PlanResult(ok=True, paths={v: r.paths[v] for v, r in alone.items()}, cost=sum(r.cost for r in alone.values()))
    assert [e.node for e in naive.paths["a"]] == ["H1", "a0_0_0", "a0_1_1", "H3"]
    assert [e.node for e in naive.paths["b"]] == ["H2", "a0_1_0", "a0_0_1", "H4"]
    report = validate_plan(to_plan(graph, "crossing", "sipp", 0.5, tasks, naive))
    assert report.contacts, "the test map must make the naive plan collide"
    result = plan_valid(graph, tasks)
    assert result.cost > naive.cost  # someone waited or went round


# -- battery (§V-C) and failures --------------------------------------------------------------------------


def test_task_beyond_the_battery_fails_naming_the_vehicle() -> None:
    spec = load_map("town")
    weak = msgspec.structs.replace(spec.vehicle, capacity_ah=0.002, reserve_ah=0.0)
    graph = build_graph(msgspec.structs.replace(spec, vehicle=weak))
    drive_only = tasks_of(cf1=("WP1", "WP6"))
    plan_valid(graph, drive_only)  # driving across the west region fits in 0.002 Ah
    result = plan_sipp(graph, {**drive_only, "cf2": Task(start="WP2", goal="EP4")}, 0.5, 5.0, 0)
    assert not result.ok
    assert result.failed_vehicle == "cf2"
    assert "battery" in result.error and "cf2" in result.error


def test_battery_is_tracked_along_the_path() -> None:
    graph = load_graph("town")
    tasks = load_scenario(MAPS_DIR / "scenarios" / "town_8.yaml", graph)
    result = plan_valid(graph, tasks)
    report = validate_plan(to_plan(graph, "town", "sipp", 0.5, tasks, result))
    assert max(report.charge_ah.values()) <= graph.model.usable_ah


# -- mu trades time for energy (eq. 3) --------------------------------------------------------------------


def test_mu_switches_between_flying_and_driving() -> None:
    graph = load_graph("grid125")
    spots = graph.endpoints()
    pos = graph.pos[[graph.index[s] for s in spots]]
    far = np.linalg.norm(pos[:, None, :2] - pos[None, :, :2], axis=2)
    i, j = np.unravel_index(np.argmax(far), far.shape)
    tasks = tasks_of(cf1=(spots[i], spots[j]))
    fast = plan_valid(graph, tasks, mu=0.0)
    frugal = plan_valid(graph, tasks, mu=1.0)
    assert airborne(graph, visited(fast, "cf1"))
    assert not airborne(graph, visited(frugal, "cf1"))
    assert fast.paths["cf1"][-1].t < frugal.paths["cf1"][-1].t


# -- turns at corners (sipp/turns.py) -----------------------------------------------------------------


def test_a_turn_is_budgeted_nose_or_tail_first_above_the_free_angle() -> None:
    assert turn_time(0.0, math.pi / 2, 3.0) == pytest.approx(math.pi / 6)
    assert turn_time(0.0, 0.75 * math.pi, 3.0) == pytest.approx(math.pi / 12)  # 135 deg: 45 tail first
    assert turn_time(0.5, 0.5 - math.pi, 3.0) == 0.0  # doubling back: tail first, no turn
    assert turn_time(0.0, math.radians(25.0), 3.0) == 0.0  # pure pursuit steers through it
    assert turn_time(0.0, math.pi / 2, 0.0) == 0.0  # no turn rate: none budgeted (paper 000)
    assert turn_time(math.nan, math.pi / 2, 3.0) == turn_time(0.0, math.nan, 3.0) == 0.0  # a flight's edge


def corner_waits(graph: FleetGraph, result: PlanResult) -> list[tuple[float, float]]:
    """(planned wait, turn budget) at every node a path passes on drive edges in and out."""
    headings = edge_headings(graph)
    out = []
    for path in result.paths.values():
        moves = [(a, b) for a, b in zip(path, path[1:], strict=False) if a.node != b.node]
        for (a, b), (c, d) in zip(moves, moves[1:], strict=False):
            e_in, e_out = graph.edge_index[graph.index[a.node], graph.index[b.node]], graph.edge_index[graph.index[c.node], graph.index[d.node]]
            out.append((c.t - b.t, turn_time(headings[e_in], headings[e_out], graph.model.speed.turn)))
    return out


@pytest.mark.parametrize("turn", [0.0, 3.0])
def test_a_path_waits_at_each_corner_for_the_turn_onto_its_next_road(turn: float) -> None:
    """town's vehicles cross its roads' corners; with a turn rate every corner a path turns at is a
    wait at least as long as the turn (the executor turns in it), without one none is."""
    spec = town()
    graph = build_graph(msgspec.structs.replace(spec, vehicle=msgspec.structs.replace(
        spec.vehicle, speed=msgspec.structs.replace(spec.vehicle.speed, turn=turn))))
    tasks = load_scenario(MAPS_DIR / "scenarios" / "town_8.yaml", graph)
    waits = corner_waits(graph, plan_valid(graph, tasks))
    turns = [(w, b) for w, b in waits if b > 0.0]
    if turn == 0.0:
        assert not turns
        return
    assert len(turns) >= 4 and all(w >= b - 1e-9 for w, b in turns), turns
    assert {round(b, 3) for _, b in turns} >= {round(math.pi / 6, 3)}  # a right-angle corner: 90 deg at 3 rad/s


# -- MovingAI and the command line ------------------------------------------------------------------------


@needs_movingai
def test_movingai_100_agents_validate() -> None:
    graph = load_movingai(MOVINGAI + ".map")
    tasks = load_scen(MOVINGAI + "-random-1.scen", graph, 100)
    result = plan_valid(graph, tasks, mu=0.0)
    # mu = 0 on unit-speed unit edges: the cost is the sum of arrival times (t_max = 1 s)
    arrivals = sum(p[-1].t for p in result.paths.values())
    assert result.cost == pytest.approx(arrivals, rel=1e-9)


def test_fleet_plan_cli_writes_a_valid_plan(tmp_path) -> None:
    out = tmp_path / "p.json"
    assert fleet_main(["plan", "--map", "town", "--random", "8", "--planner", "sipp", "--out", str(out)]) == 0
    plan = read_plan(out)
    assert plan.planner == "sipp" and len(plan.paths) == 8
    assert validate_plan(plan).ok


# -- the building blocks ----------------------------------------------------------------------------------


def test_carve_removes_open_windows_and_keeps_their_ends() -> None:
    starts, ends = [0.0], [math.inf]
    carve(starts, ends, 2.0, 3.0)
    carve(starts, ends, 5.0, 6.0)
    assert list(zip(starts, ends, strict=True)) == [(0.0, 2.0), (3.0, 5.0), (6.0, math.inf)]
    carve(starts, ends, 3.0, 5.0)  # touching windows merge: no single free instant survives
    assert list(zip(starts, ends, strict=True)) == [(0.0, 2.0), (6.0, math.inf)]
    carve(starts, ends, 1.0, 7.0)
    assert list(zip(starts, ends, strict=True)) == [(0.0, 1.0), (7.0, math.inf)]
    carve(starts, ends, 4.0, 4.0)  # empty window
    assert len(starts) == 2


def test_claims_moving_meanwhile_are_lifted_after_the_block() -> None:
    """`Reservations.moving_meanwhile`: a traversal's claims hold inside the block (the node it
    comes into is claimed over it, and so are departures on the edges it touches) and are gone
    after it, every interval as it was, the claims made before kept."""
    from services.planner.sipp.safe_intervals import Reservations

    graph = load_graph("town")
    res = Reservations(graph)
    res.rest(graph.index["WP10"], 0.0, 5.0)
    before = ([s[:] for s in res.node_start], [e[:] for e in res.node_end],
              [s[:] for s in res.edge_start], [e[:] for e in res.edge_end])
    edge = next(iter(graph.edge_index.values()))
    end = int(graph.edges[edge][1])
    arrive = 10.0 + float(graph.duration[edge])
    assert res.interval_at(end, arrive) is not None
    with res.moving_meanwhile([(edge, 10.0)]):
        assert res.interval_at(end, arrive - 1e-3) is None
        assert any(len(s) > 1 or s[0] != -math.inf for s in res.edge_start)
    assert (res.node_start, res.node_end, res.edge_start, res.edge_end) == before
    assert res.interval_at(graph.index["WP10"], 2.0) is None


def test_edge_pair_windows_are_exact() -> None:
    """Against dense sampling on random segment pairs: every sampled contact lies inside the window,
    and the window is no wider than the sampling resolution allows."""
    rng = np.random.default_rng(7)
    radius, height = 0.06, 0.05
    pos = rng.uniform(0.0, 0.25, (60, 3))
    pos[:30, 2] = 0.0  # half of the segments on the ground
    edges = np.arange(60).reshape(30, 2)
    dur = np.linalg.norm(pos[edges[:, 1]] - pos[edges[:, 0]], axis=1) / 0.3
    e, f = (x[:150] for x in np.triu_indices(30, 1))
    lo, hi = edge_pair_windows(pos, edges, dur, e, f, radius, height)
    assert 30 < np.count_nonzero(lo < hi) < 140  # both kinds of pair are exercised
    both_lo, both_hi = edge_pair_windows(pos, edges, dur, np.r_[e, f], np.r_[f, e], radius, height)
    touch = lo < hi
    assert np.array_equal(both_lo[: len(e)], lo) and np.array_equal(both_hi[: len(e)], hi)
    assert np.array_equal(both_lo[len(e):][touch], -hi[touch]) and np.array_equal(both_hi[len(e):][touch], -lo[touch])
    assert not np.any(both_lo[len(e):][~touch] < both_hi[len(e):][~touch])
    s = np.linspace(0.0, 1.0, 401)
    for k in range(len(e)):
        a0, a1 = pos[edges[e[k]]]
        b0, b1 = pos[edges[f[k]]]
        de, df = dur[e[k]], dur[f[k]]
        deltas = np.linspace(-df, de, 401)
        u = (s[None, :] * de - deltas[:, None]) / df  # f's parameter at the instant e is at s
        d = a0 + s[None, :, None] * (a1 - a0) - (b0 + u[..., None] * (b1 - b0))
        hit = (u >= 0) & (u <= 1) & (np.hypot(d[..., 0], d[..., 1]) < 2 * radius) & (np.abs(d[..., 2]) < height)
        blocked = deltas[hit.any(axis=1)]
        step = (de + df) / 400
        if len(blocked):
            assert lo[k] <= blocked.min() + 1e-9 and hi[k] >= blocked.max() - 1e-9
            assert lo[k] > blocked.min() - 3 * step - 0.01 * (de + df) and hi[k] < blocked.max() + 3 * step + 0.01 * (de + df)
        elif lo[k] < hi[k]:
            assert hi[k] - lo[k] < 0.02 * (de + df)  # a contact too brief for the sampling


def test_cost_to_go_is_exact_and_enters_spots_only_as_the_goal() -> None:
    import networkx as nx

    from services.planner.sipp.heuristic import CostToGo

    graph = load_graph("town")
    cost = graph.edge_cost(0.5)
    goal = "EP4"
    g = nx.DiGraph()
    for e, (u, v) in enumerate(graph.edges.tolist()):
        if graph.kinds[v] not in ("parking", "helipad") or graph.ids[v] == goal:
            g.add_edge(graph.ids[u], graph.ids[v], w=cost[e])
    want = nx.single_source_dijkstra_path_length(g.reverse(), goal, weight="w")
    ctg = CostToGo.of(graph, 0.5)
    ctg.prepare([graph.index[goal]])
    h = ctg.h[graph.index[goal]]
    for node, i in graph.index.items():
        assert h[i] == pytest.approx(want.get(node, math.inf), rel=1e-12)
    assert CostToGo.of(graph, 0.5) is ctg  # cached per graph and mu


@pytest.mark.parametrize("planner", ["sipp", "ilp"])
def test_a_vehicle_with_little_charge_left_is_refused_with_its_shortfall(planner: str) -> None:
    """Issue 16: eq. 6's budget is what the vehicle's battery still holds, at its own voltage."""
    from services.planner.maps.loading import problem_from_request
    from services.planner.registry import run_planner

    full = {"cf1": Task(start="WP10", goal="EP8"), "cf2": Task(start="EP7", goal="WP9")}
    problem = problem_from_request("town", full, planner)
    assert run_planner(problem, planner, 0.5, 20.0, 0)[0] is not None
    model = problem.graph.model
    empty = {**full, "cf2": Task(start="EP7", goal="WP9", charge_used_ah=model.usable_ah - 0.001, voltage=3.5)}
    problem = problem_from_request("town", empty, planner)
    plan, result = run_planner(problem, planner, 0.5, 20.0, 0)
    assert plan is None and result.failed_vehicle == "cf2", result.error
    assert "short by" in result.error and "Ah" in result.error and "3.50 V" in result.error, result.error
    needed = float(result.error.split("needs at least ")[1].split(" Ah")[0])
    short = float(result.error.split("short by ")[1].split(" Ah")[0])
    assert short == pytest.approx(needed - (0.001 * 3.5 / model.voltage), abs=2e-4)


def test_a_node_closed_for_ever_from_time_zero_is_routed_around() -> None:
    """A body at rest on a node from time 0 on for ever (a vehicle held there, or parked and never
    moved) leaves the node and those touching it no safe interval at all: the search goes around
    them (it once indexed the empty interval list and failed with an IndexError)."""
    from services.planner.sipp.heuristic import CostToGo
    from services.planner.sipp.safe_intervals import Reservations
    from services.planner.sipp.search import SearchGraph, sipp

    graph = load_graph("town")
    start, goal = graph.index["WP10"], graph.index["EP8"]
    ctg = CostToGo.of(graph, 0.5)
    ctg.prepare([goal])

    def route(res: Reservations) -> list[int] | None:
        path = sipp(SearchGraph.of(graph, 0.5), res, start, goal, ctg.h[goal], ctg.q[goal], math.inf,
                    float("inf"), t_start=0.0)
        return None if path is None else path.nodes

    free = route(Reservations(graph))
    assert free is not None
    blocked = free[len(free) // 2]
    res = Reservations(graph)
    res.rest(blocked, 0.0, math.inf)
    assert not res.node_start[blocked]  # no safe interval left
    around = route(res)
    assert around is None or blocked not in around
