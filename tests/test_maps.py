"""Map format, graph builder and cost model (issue 2): shipped maps, eq. 1-5 by hand, bad input."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
import pytest

from common.domain.mapfile import MAPS_DIR, load_map
from common.domain.vehicle_model import G, VehicleModel
from services.cli import main
from services.planner.graph.fleet_graph import build_graph
from services.planner.maps.generate import GENERATORS, to_yaml
from services.planner.maps.loading import load_graph
from services.planner.maps.tasks import load_scenario, random_tasks

pytestmark = pytest.mark.compute

SHIPPED = ["town", "fig6", "grid125", "city934"]


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_maps_check(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["map", "check", name]) == 0
    out = capsys.readouterr().out
    assert "nodes:" in out and out.strip().endswith("ok")


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_maps_match_their_generator(name: str) -> None:
    assert (MAPS_DIR / f"{name}.yaml").read_text() == to_yaml(GENERATORS[name]())


def test_town_is_two_ground_regions_joined_through_the_air() -> None:
    graph = load_graph("town")
    spec = load_map("town")
    assert spec.size == (4.2, 2.1)
    assert spec.vehicle.radius >= 0.06
    ground = nx.Graph([(u, v) for u, v, k in graph.g.edges(data="kind") if k == "drive"])
    regions = list(nx.connected_components(ground))
    assert len(regions) == 2
    for region in regions:
        assert sum(graph.kinds[graph.index[n]] == "parking" for n in region) >= 8
    assert nx.has_path(graph.g, "WP1", "EP1") and nx.has_path(graph.g, "EP1", "WP1")
    # airspace only over the corridor: no air node outside y in [0.7, 1.4]
    air = graph.pos[np.array(graph.kinds) == "air"]
    assert air[:, 1].min() >= 0.7 + spec.vehicle.radius and air[:, 1].max() <= 1.4 - spec.vehicle.radius


def test_sizes_of_grid125_and_city934() -> None:
    assert load_graph("fig6").n_nodes == 125
    assert 100 <= load_graph("grid125").n_nodes <= 150
    city = load_graph("city934")
    assert 850 <= city.n_nodes <= 1050
    assert len(city.endpoints()) >= 120


def test_uniform_graph_every_edge_one_step_never_faster() -> None:
    graph = load_graph("town", uniform=True)
    assert graph.dt == 2.0
    assert np.allclose(graph.duration, 2.0)
    speeds = np.array([graph.model.edge_speed(k) for k in graph.edge_kinds])
    assert np.all(graph.length / graph.duration <= speeds + 1e-9)
    assert graph.counts()[0]["waypoint"] > 0


@pytest.mark.parametrize("name", SHIPPED)
def test_one_step_graph_spaces_nodes_a_step_apart_at_each_kinds_speed(name: str) -> None:
    """§V-E as the paper builds it: air nodes one fly step apart, every edge split into ceil(d / dt)
    pieces of one step (d its duration at its kind's speed), so a traversal is never faster and at
    most 1 - d / (ceil(d / dt) dt) slower than its kind's speed; flights keep their speed."""
    base, step = load_graph(name), load_graph(name, uniform=True)
    spec = load_map(name)
    dt = step.dt
    nominal = step.nominal_duration()
    assert np.allclose(nominal, step.length / [step.model.edge_speed(k) for k in step.edge_kinds])
    assert np.all(nominal <= dt * (1 + 1e-6))
    slow = step.slowdown()
    assert np.all(slow >= -1e-9) and np.allclose(slow, 1 - nominal / dt)
    # the straight fly edges of the air grid take exactly one step at fly speed
    fly = np.array([k == "fly" for k in step.edge_kinds])
    air = np.array(step.kinds) == "air"
    grid = fly & air[step.edges[:, 0]] & air[step.edges[:, 1]]
    spacing = max(spec.air.spacing, step.model.speed.fly * dt)
    level = np.isclose(step.pos[step.edges[:, 0], 2], step.pos[step.edges[:, 1], 2])
    straight = grid & level & np.isclose(step.length, spacing)
    assert straight.any() and np.allclose(slow[straight], 0.0)
    # no piece of a subdivided edge is shorter than half a step: ceil never splits finer than that
    pieces = step.length / [step.model.edge_speed(k) for k in step.edge_kinds]
    waypoint = np.array(step.kinds) == "waypoint"
    split = waypoint[step.edges[:, 0]] | waypoint[step.edges[:, 1]]
    assert np.all(pieces[split] > dt / 2 - 1e-9)
    # eq. 3's normalisers are the largest edge energy and duration at the vehicle's speeds
    at_speed = np.array([step.model.edge_energy(k, d, dz) for k, d, dz in
                         zip(step.edge_kinds, step.length, step.pos[step.edges[:, 1], 2] - step.pos[step.edges[:, 0], 2],
                             strict=True)])
    assert step.scale.w_max == pytest.approx(at_speed.max())
    assert step.scale.t_max == pytest.approx(nominal.max())
    assert base.scale.t_max == pytest.approx(base.duration.max()) and np.allclose(base.slowdown(), 0.0)


def _edge(graph, u: str, v: str) -> int:
    return graph.edge_index[(graph.index[u], graph.index[v])]


def test_eq_1_to_5_by_hand_for_each_edge_kind() -> None:
    graph = load_graph("town")
    m = VehicleModel()
    w_max, t_max = graph.scale.w_max, graph.scale.t_max
    mu = 0.3
    cases = {
        # kind: (u, v, length, duration, work)
        "drive": ("Wb0", "Wb1", 0.3, 3.0, 0.60 * 3.0),
        "takeoff": ("Wl3", "a0_0_1", 0.4, 2.0, 7.83 * 2.0 + 0.041 * G * 0.4),
        "fly": ("a0_0_1", "a0_1_1", 0.25, 0.25 / 0.3, 7.83 * 0.25 / 0.3),
        "land": ("a0_0_1", "Wl3", 0.4, 2.0, 7.83 * 2.0),
    }
    cost = graph.edge_cost(mu)
    for kind, (u, v, length, duration, work) in cases.items():
        e = _edge(graph, u, v)
        assert graph.edge_kinds[e] == kind
        assert graph.length[e] == pytest.approx(length)
        assert graph.duration[e] == pytest.approx(duration)
        assert graph.energy[e] == pytest.approx(work)  # eq. 1-2
        assert cost[e] == pytest.approx(mu * work / w_max + (1 - mu) * duration / t_max)  # eq. 3
        power = 0.60 if kind == "drive" else 7.83
        assert graph.charge[e] == pytest.approx(power / 3.7 * duration / 3600)  # eq. 4-5
    assert w_max == pytest.approx(graph.energy.max()) and t_max == pytest.approx(3.0)
    assert m.usable_ah == pytest.approx(0.176 - 0.018)


def test_wait_costs_hover_at_fly_power_and_idle_on_the_ground() -> None:
    graph = load_graph("town")
    rate = graph.wait_cost_rate(1.0)
    assert rate[graph.index["a0_0_1"]] == pytest.approx(7.83 / graph.scale.w_max)
    assert rate[graph.index["WP1"]] == pytest.approx(0.15 / graph.scale.w_max)


def test_crossing_air_edges_are_in_contact_without_sharing_a_node() -> None:
    graph = load_graph("town")
    e = _edge(graph, "a0_1_0", "a0_2_1")
    f = _edge(graph, "a0_2_0", "a0_1_1")
    assert not {"a0_1_0", "a0_2_1"} & {"a0_2_0", "a0_1_1"}
    win = graph.conflicts.edge_edges[e]
    k = list(win.other).index(f)
    assert win.self_lo[k] < 0.5 < win.self_hi[k] and win.lo[k] < 0.5 < win.hi[k]
    # parallel air edges one spacing apart are not in contact
    g2 = _edge(graph, "a0_1_2", "a0_2_2")
    assert g2 not in set(graph.conflicts.edge_edges[_edge(graph, "a0_1_0", "a0_2_0")].other)


def test_air_nodes_removed_inside_no_fly_zones_and_obstacles() -> None:
    spec = GENERATORS["grid125"]()
    graph = build_graph(spec)
    air = graph.pos[np.array(graph.kinds) == "air"]
    centre = np.array([1.0, 1.0])
    assert np.all(np.linalg.norm(air[:, :2] - centre, axis=1) > 0.3)


def test_random_scenarios_are_well_formed_and_seeded() -> None:
    graph = load_graph("city934")
    a = random_tasks(graph, 60, seed=4)
    assert a == random_tasks(graph, 60, seed=4) != random_tasks(graph, 60, seed=5)
    spots = [t.start for t in a.values()] + [t.goal for t in a.values()]
    assert len(set(spots)) == 120
    assert all(graph.kinds[graph.index[s]] == "parking" for s in spots)


def test_town_scenario_loads() -> None:
    tasks = load_scenario(MAPS_DIR / "scenarios" / "town_8.yaml", load_graph("town"))
    assert len(tasks) == 8
    assert sum(t.start[0] != t.goal[0] for t in tasks.values()) >= 4


def test_export_writes_the_plan_graph(tmp_path) -> None:
    import json

    out = tmp_path / "g.json"
    assert main(["map", "export", "grid125", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    assert len(data["nodes"]) == load_graph("grid125").n_nodes
    assert {e[2] for e in data["edges"]} == {"drive", "takeoff", "fly", "land"}


def test_show_draws_a_png(tmp_path) -> None:
    out = tmp_path / "town.png"
    assert main(["map", "show", "town", "--out", str(out)]) == 0
    assert out.read_bytes()[:4] == b"\x89PNG" and out.stat().st_size > 20_000


# --- bad input: exit code 2, one line naming file, field and problem ------------------------------

TOWN = (MAPS_DIR / "town.yaml").read_text()


def _check(tmp_path, text: str, capsys) -> str:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    assert main(["map", "check", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err and str(path) in err
    return err


def test_unknown_key(tmp_path, capsys) -> None:
    err = _check(tmp_path, TOWN.replace("spacing: 0.25", "spacing: 0.25\n  colour: red"), capsys)
    assert "air" in err and "colour" in err


def test_wrong_type(tmp_path, capsys) -> None:
    err = _check(tmp_path, TOWN.replace("spacing: 0.25", "spacing: wide"), capsys)
    assert "air.spacing" in err and "float" in err


def test_dangling_edge(tmp_path, capsys) -> None:
    err = _check(tmp_path, TOWN.replace("- [Wb0, Wb1]", "- [Wb0, Nowhere]"), capsys)
    assert "roads.two_way[0]" in err and "Nowhere" in err


def test_unreachable_parking_spot(tmp_path, capsys) -> None:
    text = TOWN.replace("nodes:\n", "nodes:\n    Lonely: {x: 3.0, y: 0.2}\n", 1)
    text = text.replace("parking:\n", "parking:\n- {id: PX, x: 3.0, y: 0.03, road: Lonely}\n", 1)
    err = _check(tmp_path, text, capsys)
    assert "PX" in err and "unreachable" in err


def test_spots_too_close(tmp_path, capsys) -> None:
    text = TOWN.replace("parking:\n", "parking:\n- {id: PX, x: 0.62, y: 0.1, road: Wb1}\n", 1)
    err = _check(tmp_path, text, capsys)
    assert "parking[0]" in err and "too close" in err


def test_invalid_yaml(tmp_path, capsys) -> None:
    err = _check(tmp_path, TOWN.replace("roads:", "roads: [", 1), capsys)
    assert "invalid YAML" in err and "line" in err


def test_negative_vehicle_radius(tmp_path, capsys) -> None:
    err = _check(tmp_path, TOWN.replace("radius: 0.06", "radius: -0.06"), capsys)
    assert "vehicle" in err and "radius" in err


def _plan_with_scenario(tmp_path, tasks: str, capsys) -> str:
    path = tmp_path / "scen.yaml"
    path.write_text(f"tasks:\n{tasks}")
    assert main(["plan", "--map", "town", "--scenario", str(path), "--out", str(tmp_path / "p.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(path) in err
    return err


def test_scenario_start_not_a_parking_spot(tmp_path, capsys) -> None:
    err = _plan_with_scenario(tmp_path, "  cf1: {start: Wb0, goal: EP1}\n", capsys)
    assert "tasks.cf1.start" in err and "not a parking spot" in err


def test_scenario_goals_repeat(tmp_path, capsys) -> None:
    err = _plan_with_scenario(tmp_path, "  cf1: {start: WP1, goal: EP1}\n  cf2: {start: WP2, goal: EP1}\n", capsys)
    assert "tasks.cf2.goal" in err and "cf1" in err


def test_scenario_unknown_field(tmp_path, capsys) -> None:
    err = _plan_with_scenario(tmp_path, "  cf1: {start: WP1, goal: EP1, speed: 3}\n", capsys)
    assert "speed" in err


def test_missing_map_file(capsys) -> None:
    assert main(["map", "check", "no/such/map.yaml"]) == 2
    assert "no/such/map.yaml" in capsys.readouterr().err


def test_time_to_cross_the_town_is_plausible() -> None:
    graph = load_graph("town")
    t = nx.shortest_path_length(graph.g, "WP1", "EP1", weight="duration")
    assert 5 < t < 60 and math.isfinite(t)


# --- MovingAI grids with several connected components (issue 18) ---------------------------------------


def _write_movingai(tmp_path, name: str, free: np.ndarray, pairs: list[tuple[tuple[int, int], tuple[int, int]]]):
    """A `.map` of the free cells [row, col] and a `.scen` of (x, y) start/goal pairs."""
    h, w = free.shape
    rows = ["".join("." if c else "@" for c in row) for row in free]
    (tmp_path / f"{name}.map").write_text(f"type octile\nheight {h}\nwidth {w}\nmap\n" + "\n".join(rows) + "\n")
    lines = [f"0\t{name}.map\t{w}\t{h}\t{sx}\t{sy}\t{gx}\t{gy}\t0" for (sx, sy), (gx, gy) in pairs]
    (tmp_path / f"{name}.scen").write_text("version 1\n" + "\n".join(lines) + "\n")
    return tmp_path / f"{name}.map", tmp_path / f"{name}.scen"


def _components(free: np.ndarray) -> np.ndarray:
    """4-connected component label per cell (-1 blocked), by scipy."""
    from scipy.ndimage import label

    labels, _ = label(free)
    return labels - 1


def _pairs_in_largest(free: np.ndarray, k: int, seed: int) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """k start/goal pairs on distinct cells of the largest component, as a MovingAI .scen pairs them."""
    comp = _components(free)
    largest = np.bincount(comp[comp >= 0]).argmax()
    cells = np.argwhere(comp == largest)
    rng = np.random.default_rng(seed)
    pick = cells[rng.choice(len(cells), 2 * k, replace=False)]
    return [((int(pick[2 * i][1]), int(pick[2 * i][0])), (int(pick[2 * i + 1][1]), int(pick[2 * i + 1][0])))
            for i in range(k)]


def random_32_32_20() -> np.ndarray:
    """Like MovingAI random-32-32-20: 32 x 32, 20 % of the cells blocked at random (here seeded), which
    leaves isolated free cells; one is planted for certain at (1, 1)."""
    rng = np.random.default_rng(20)
    free = np.ones((32, 32), dtype=bool)
    free.flat[rng.choice(32 * 32, 205, replace=False)] = False
    free[0:3, 0:3] = False
    free[1, 1] = True
    return free


def den520d_like() -> np.ndarray:
    """Like MovingAI den520d (257 x 256, a game map of caves, 28k free cells): cellular-automaton
    caves, seeded: 32k free cells, a large cave of 22k, over a hundred closed pockets and isolated
    free cells (one planted for certain)."""
    rng = np.random.default_rng(520)
    free = rng.random((257, 256)) < 0.5
    for _ in range(4):
        p = np.pad(free, 1).astype(int)
        neighbours = sum(np.roll(np.roll(p, dy, 0), dx, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1))[1:-1, 1:-1]
        free = neighbours >= 5
    free[[0, -1], :] = free[:, [0, -1]] = False
    free[5:8, 5:8] = False
    free[6, 6] = True
    return free


def _load_and_plan(tmp_path, name: str, free: np.ndarray, agents: int, plan: bool) -> None:
    from services.planner.maps.movingai_graph import load_movingai, load_scen
    from services.planner.result import to_plan
    from services.planner.sipp.planner import plan_sipp
    from services.planner.validate import validate_plan

    comp = _components(free)
    sizes = np.bincount(comp[comp >= 0])
    assert len(sizes) > 1 and sizes.min() == 1, "the generated grid must have isolated free cells"
    map_path, scen_path = _write_movingai(tmp_path, name, free, _pairs_in_largest(free, agents, 0))
    graph = load_movingai(map_path)
    assert graph.n_nodes == free.sum()
    assert len(np.unique(graph.component)) == len(sizes)
    tasks = load_scen(scen_path, graph, agents)
    assert len(tasks) == agents
    if plan:
        result = plan_sipp(graph, tasks, 0.0, 120.0, 0)
        assert result.ok, result.error
        assert validate_plan(to_plan(graph, name, "sipp", 0.0, tasks, result)).ok


def test_random_32_32_20_with_isolated_cells_loads_and_plans(tmp_path) -> None:
    _load_and_plan(tmp_path, "random-32-32-20", random_32_32_20(), 30, plan=True)


def test_den520d_with_isolated_cells_and_pockets_loads(tmp_path) -> None:
    _load_and_plan(tmp_path, "den520d", den520d_like(), 20, plan=False)


@pytest.mark.scale
def test_den520d_with_isolated_cells_and_pockets_plans(tmp_path) -> None:
    """Planning pays the per-graph contact tables first: about 15 s for 32k cells (`-m scale`)."""
    _load_and_plan(tmp_path, "den520d", den520d_like(), 20, plan=True)


def test_movingai_task_across_components_names_its_scen_line(tmp_path) -> None:
    from common.errors import InputError
    from services.planner.maps.movingai_graph import load_movingai, load_scen

    free = random_32_32_20()
    pairs = _pairs_in_largest(free, 3, 1)
    pairs.insert(2, (pairs[2][0], (1, 1)))  # to the isolated cell planted at x = 1, y = 1
    map_path, scen_path = _write_movingai(tmp_path, "random-32-32-20", free, pairs)
    graph = load_movingai(map_path)
    assert load_scen(scen_path, graph, 2)  # the lines before it are fine
    with pytest.raises(InputError) as err:
        load_scen(scen_path, graph, 4)
    assert err.value.field == "line 4"  # line 1 is `version 1`
    assert "different connected components" in str(err.value) and "1_1" in str(err.value)
    assert str(scen_path) in str(err.value)


def test_a_scenario_across_components_is_refused_naming_the_task(tmp_path) -> None:
    from common.domain.planfile import Task
    from common.errors import InputError
    from services.planner.maps.movingai_graph import load_movingai
    from services.planner.maps.tasks import check_tasks

    free = random_32_32_20()
    map_path, _ = _write_movingai(tmp_path, "r", free, [])
    graph = load_movingai(map_path)
    (sx, sy), _ = _pairs_in_largest(free, 1, 2)[0]
    with pytest.raises(InputError, match="different connected components") as err:
        check_tasks({"v1": Task(start=f"{sx}_{sy}", goal="1_1")}, graph, "request")
    assert err.value.field == "tasks.v1"
