"""The independent plan checker (services/planner/validate.py) on hand-made plans, each invalid one
with exactly one defect; costs against hand-computed eq. 1-3 numbers (paper 000 §V-B)."""

from __future__ import annotations

import math
import time

import msgspec
import numpy as np
import pytest

from common.domain.geometry import contact_intervals
from common.domain.planfile import GraphNode, PathEntry, Plan, PlanGraph, PlanModel, Task, write_plan
from services.cli import main as fleet_main
from services.planner import validate
from services.planner.validate import closest_horizontal, validate_plan

MU = 0.25
MODEL = PlanModel(w_max=10.0, t_max=10.0)  # Table II defaults: r 0.06, h 0.05, m 0.041, P 0.6 / 7.83 / 0.15 W
FLY_1M = 1.0 / 0.3  # s to fly 1 m
TAKEOFF = 0.5 / 0.2  # s to rise 0.5 m

# A road L0-L1-L2-L3 (1 m apart) with parking P0, P3 beside its ends, air nodes A1, A2 0.5 m above
# L1, L2, and four air nodes whose fly edges X1->X2 and X3->X4 cross at (0.5, 1.5, 0.5).
NODES = {
    "P0": ((0.0, -0.5, 0.0), "parking"), "P3": ((3.0, -0.5, 0.0), "parking"),
    "L0": ((0.0, 0.0, 0.0), "land"), "L1": ((1.0, 0.0, 0.0), "land"),
    "L2": ((2.0, 0.0, 0.0), "land"), "L3": ((3.0, 0.0, 0.0), "land"),
    "A1": ((1.0, 0.0, 0.5), "air"), "A2": ((2.0, 0.0, 0.5), "air"),
    "X1": ((0.0, 1.0, 0.5), "air"), "X2": ((1.0, 2.0, 0.5), "air"),
    "X3": ((1.0, 1.0, 0.5), "air"), "X4": ((0.0, 2.0, 0.5), "air"),
}
TWO_WAY = [("P0", "L0", "drive"), ("L0", "L1", "drive"), ("L1", "L2", "drive"), ("L2", "L3", "drive"),
           ("L3", "P3", "drive"), ("A1", "A2", "fly")]
ONE_WAY = [("L1", "A1", "takeoff"), ("A1", "L1", "land"), ("L2", "A2", "takeoff"), ("A2", "L2", "land"),
           ("X1", "X2", "fly"), ("X3", "X4", "fly")]
EDGES = TWO_WAY + [(v, u, k) for u, v, k in TWO_WAY] + ONE_WAY


def make_plan(
    paths: dict[str, list[tuple[str, float]]],
    tasks: dict[str, tuple[str, str]] | None = None,
    cost: float | None = None,
    model: PlanModel = MODEL,
    nodes: dict = NODES,
    edges: list = EDGES,
) -> Plan:
    """A plan on the test graph. Tasks default to each path's ends; cost defaults to the checker's own
    recomputation, so that a defect under test is the only error."""
    tasks = tasks or {v: (p[0][0], p[-1][0]) for v, p in paths.items()}
    plan = Plan(
        map="test", planner="hand", mu=MU, model=model,
        graph=PlanGraph(nodes={n: GraphNode(pos=p, kind=k) for n, (p, k) in nodes.items()}, edges=edges),
        tasks={v: Task(start=s, goal=g) for v, (s, g) in tasks.items()},
        paths={v: [PathEntry(node=n, t=t) for n, t in p] for v, p in paths.items()},
        cost=0.0, planning_time_s=0.0,
    )
    if cost is None:
        cost = validate_plan(plan).cost
    return msgspec.structs.replace(plan, cost=cost)


def only_error(plan: Plan, *fragments: str) -> str:
    """The plan has exactly one error, and it mentions every fragment."""
    report = validate_plan(plan)
    assert not report.ok
    assert len(report.errors) == 1, report.errors
    for f in fragments:
        assert f in report.errors[0], report.errors[0]
    return report.errors[0]


# a flies over while b drives the other way underneath; each ends on the other's start spot
VALID = {
    "a": [("P0", 0.0), ("L0", 5.0), ("L1", 15.0), ("A1", 15.0 + TAKEOFF), ("A2", 15.0 + TAKEOFF + FLY_1M),
          ("L2", 15.0 + 2 * TAKEOFF + FLY_1M), ("L3", 25.0 + 2 * TAKEOFF + FLY_1M), ("P3", 30.0 + 2 * TAKEOFF + FLY_1M)],
    "b": [("P3", 0.0), ("L3", 5.0), ("L2", 15.0), ("L1", 25.0), ("L0", 35.0), ("P0", 40.0)],
}


# -- valid plans ------------------------------------------------------------------------------------------


def test_valid_plan_passes_with_its_numbers():
    report = validate_plan(make_plan(VALID))
    assert report.ok, report.errors
    assert report.makespan == pytest.approx(40.0)
    assert report.arrival == pytest.approx({"a": 30.0 + 2 * TAKEOFF + FLY_1M, "b": 40.0})
    # b drives 40 s: eq. 4-5 charge 0.6 W / 3.7 V * 40 s; energy 0.6 W * 40 s
    assert report.charge_ah["b"] == pytest.approx(0.6 / 3.7 * 40 / 3600)
    assert report.vehicles["b"].energy_j == pytest.approx(24.0)
    # a drives 30 s and flies 2 * 2.5 + 3.33 s, lifting 0.041 kg by 0.5 m
    energy_a = 0.6 * 30 + 7.83 * (2 * TAKEOFF + FLY_1M) + 0.041 * 9.81 * 0.5
    assert report.energy == pytest.approx(24.0 + energy_a)
    assert report.contacts == [] and math.isinf(report.min_separation)
    assert "plan: valid" in report.summary()


def test_wait_then_pass_behind_is_valid_and_measures_separation():
    """b hovers 0.2 T before crossing a's path: 0.2 m apart at the crossing, no contact."""
    delay = 0.2 * math.sqrt(2) / 0.3
    cross = math.sqrt(2) / 0.3
    plan = make_plan({"a": [("X1", 0.0), ("X2", cross)], "b": [("X3", 0.0), ("X3", delay), ("X4", delay + cross)]})
    report = validate_plan(plan)
    assert report.ok, report.errors
    assert report.min_separation == pytest.approx(0.2)


def test_vehicles_may_share_a_node_at_different_times():
    plan = make_plan({"a": [("L0", 0.0), ("L1", 10.0), ("L2", 20.0)], "b": [("P0", 25.0), ("L0", 30.0), ("L1", 40.0)]})
    assert validate_plan(plan).ok


# -- one defect each ----------------------------------------------------------------------------------------


def test_wrong_start():
    plan = make_plan({"a": [("L1", 0.0), ("L2", 10.0)]}, tasks={"a": ("L0", "L2")})
    only_error(plan, "a:", "starts at 'L1'", "'L0'")


def test_wrong_goal():
    plan = make_plan({"a": [("L1", 0.0), ("L2", 10.0)]}, tasks={"a": ("L1", "L3")})
    only_error(plan, "a:", "ends at 'L2'", "'L3'")


def test_task_without_path():
    plan = make_plan({"a": [("L1", 0.0), ("L2", 10.0)]}, tasks={"a": ("L1", "L2"), "b": ("L0", "L3")})
    only_error(plan, "b: has a task but no path")


def test_unknown_node():
    plan = make_plan({"a": [("L1", 0.0), ("Q9", 10.0)]}, tasks={"a": ("L1", "L2")})
    report = validate_plan(plan)
    assert any("unknown node 'Q9'" in e for e in report.errors) and report.unchecked == ["a"]


def test_jump_between_non_adjacent_nodes():
    plan = make_plan({"a": [("L0", 0.0), ("L2", 20.0)]})
    only_error(plan, "jumps from 'L0' to 'L2'", "no such edge")


def test_move_against_a_one_way_edge():
    plan = make_plan({"a": [("X2", 0.0), ("X1", 10.0)]})
    only_error(plan, "jumps from 'X2' to 'X1'", "only the reverse edge")


def test_too_fast_on_an_edge():
    plan = make_plan({"a": [("L0", 0.0), ("L1", 9.0)]})
    only_error(plan, "too fast on drive edge 'L0'->'L1'", "needs at least 10 s")


def test_speed_tolerance_is_relative_1e_6():
    assert validate_plan(make_plan({"a": [("L0", 0.0), ("L1", 10.0 * (1 - 1e-7))]})).ok
    only_error(make_plan({"a": [("L0", 0.0), ("L1", 10.0 * (1 - 1e-5))]}), "too fast")


def test_time_going_backwards_on_a_move():
    plan = make_plan({"a": [("L0", 10.0), ("L1", 5.0)]})
    error = only_error(plan, "time goes backwards from 'L0' to 'L1'")
    assert "10 s -> 5 s" in error
    assert validate_plan(plan).unchecked == ["a"]


def test_negative_wait():
    plan = make_plan({"a": [("L0", 0.0), ("L0", 5.0), ("L0", 3.0), ("L1", 13.0)]})
    only_error(plan, "waits a negative time at 'L0'")


def test_head_on_swap():
    plan = make_plan({"a": [("L1", 0.0), ("L2", 10.0)], "b": [("L2", 0.0), ("L1", 10.0)]})
    report = validate_plan(plan)
    assert len(report.errors) == 1 and len(report.contacts) == 1
    c = report.contacts[0]
    assert (c.a, c.b) == ("a", "b")
    assert c.t == pytest.approx(5.0)
    assert c.pos_a == pytest.approx((1.5, 0.0, 0.0)) and c.pos_b == pytest.approx((1.5, 0.0, 0.0))
    assert c.separation == pytest.approx(0.0, abs=1e-9)
    assert report.errors[0].startswith("contact: a and b at t=5.000 s")


def test_crossing_fly_edges_without_a_shared_node():
    cross = math.sqrt(2) / 0.3
    plan = make_plan({"a": [("X1", 0.0), ("X2", cross)], "b": [("X3", 0.0), ("X4", cross)]})
    report = validate_plan(plan)
    assert len(report.errors) == 1 and len(report.contacts) == 1
    c = report.contacts[0]
    assert c.t == pytest.approx(cross / 2)
    assert c.pos_a == pytest.approx((0.5, 1.5, 0.5)) and c.pos_b == pytest.approx((0.5, 1.5, 0.5))


def test_passing_through_a_vehicle_parked_at_its_goal():
    plan = make_plan({"a": [("L1", 0.0), ("L2", 10.0)], "b": [("L0", 10.0), ("L1", 20.0), ("L2", 30.0), ("L3", 40.0)]})
    report = validate_plan(plan)
    assert len(report.errors) == 1 and len(report.contacts) == 1
    c = report.contacts[0]
    assert {c.a, c.b} == {"a", "b"} and c.t == pytest.approx(30.0)


def test_hit_while_parked_at_start_before_leaving():
    plan = make_plan({"a": [("L2", 30.0), ("L3", 40.0)], "b": [("L0", 0.0), ("L1", 10.0), ("L2", 20.0), ("A2", 20.0 + TAKEOFF)]})
    report = validate_plan(plan)
    assert len(report.errors) == 1 and len(report.contacts) == 1
    assert report.contacts[0].t == pytest.approx(20.0)


def test_parked_too_close_without_moving():
    nodes = {"S": ((0.0, 0.0, 0.0), "parking"), "T": ((0.1, 0.0, 0.0), "parking")}
    plan = make_plan({"a": [("S", 0.0)], "b": [("T", 0.0)]}, nodes=nodes, edges=[])
    report = validate_plan(plan)
    assert len(report.errors) == 1 and len(report.contacts) == 1
    assert report.contacts[0].separation == pytest.approx(0.1) and report.min_separation == pytest.approx(0.1)


def test_battery_over_capacity_minus_reserve():
    hover = {"a": [("A1", 0.0), ("A1", 10.0)]}  # 7.83 W / 3.7 V * 10 s = 5.878e-3 Ah
    used = 7.83 / 3.7 * 10 / 3600
    tight = msgspec.structs.replace(MODEL, capacity_ah=0.01, reserve_ah=0.005)
    only_error(make_plan(hover, model=tight), "a: battery", "usable 0.005000 Ah")
    roomy = msgspec.structs.replace(MODEL, capacity_ah=0.01, reserve_ah=0.004)
    report = validate_plan(make_plan(hover, model=roomy))
    assert report.ok and report.charge_ah["a"] == pytest.approx(used)


def test_wrong_reported_cost():
    right = validate_plan(make_plan(VALID)).cost
    only_error(make_plan(VALID, cost=right + 1e-3), "cost: the plan reports")
    assert validate_plan(make_plan(VALID, cost=right * (1 + 1e-8))).ok
    unpriced = validate_plan(make_plan(VALID, cost=0.0), check_cost=False)  # a replan before it is priced
    assert unpriced.ok and unpriced.cost == pytest.approx(right)


# -- eq. 1-3 by hand (mu 0.25, W_max 10 J, t_max 10 s) ---------------------------------------------------------

G_LIFT = 0.041 * 9.81 * 0.5  # m g dz of a 0.5 m climb
PIECES = {
    "drive 1 m at 0.1 m/s": ([("L0", 0.0), ("L1", 10.0)], 0.25 * (0.6 * 10) / 10 + 0.75 * 10 / 10),
    "drive slower than nominal": ([("L0", 0.0), ("L1", 25.0)], 0.25 * (0.6 * 25) / 10 + 0.75 * 25 / 10),
    "takeoff 0.5 m": ([("L1", 0.0), ("A1", 2.5)], 0.25 * (7.83 * 2.5 + G_LIFT) / 10 + 0.75 * 2.5 / 10),
    "fly 1 m": ([("A1", 0.0), ("A2", FLY_1M)], 0.25 * (7.83 * FLY_1M) / 10 + 0.75 * FLY_1M / 10),
    "land 0.5 m": ([("A2", 0.0), ("L2", 2.5)], 0.25 * (7.83 * 2.5) / 10 + 0.75 * 2.5 / 10),
    "wait 4 s on the ground": ([("L0", 0.0), ("L0", 4.0)], 0.25 * (0.15 * 4) / 10 + 0.75 * 4 / 10),
    "hover 4 s": ([("A1", 0.0), ("A1", 4.0)], 0.25 * (7.83 * 4) / 10 + 0.75 * 4 / 10),
}
HAND = {"drive 1 m at 0.1 m/s": 0.9, "drive slower than nominal": 2.25, "takeoff 0.5 m": 0.681902625,
        "fly 1 m": 0.9025, "land 0.5 m": 0.676875, "wait 4 s on the ground": 0.315, "hover 4 s": 1.083}


@pytest.mark.parametrize("name", list(PIECES))
def test_cost_of_one_piece_by_hand(name):
    path, expected = PIECES[name]
    assert expected == pytest.approx(HAND[name], abs=1e-12)
    report = validate_plan(make_plan({"a": path}, cost=HAND[name]))
    assert report.ok, report.errors
    assert report.cost == pytest.approx(HAND[name], rel=1e-12)


def test_cost_sums_over_a_mixed_path_and_vehicles():
    t = [0.0, 4.0, 14.0, 16.5, 20.5, 20.5 + FLY_1M, 23.0 + FLY_1M]
    path = list(zip(["L0", "L0", "L1", "A1", "A1", "A2", "L2"], t, strict=True))
    pieces = ["wait 4 s on the ground", "drive 1 m at 0.1 m/s", "takeoff 0.5 m", "hover 4 s", "fly 1 m", "land 0.5 m"]
    other = [("P3", 0.0), ("P3", 4.0)]  # a second vehicle waiting on the ground until t = 4
    total = sum(HAND[p] for p in pieces) + HAND["wait 4 s on the ground"]
    report = validate_plan(make_plan({"a": path, "b": other}, cost=total))
    assert report.ok, report.errors
    assert report.vehicles["b"].cost == pytest.approx(0.315)


def test_waypoint_hovers_unless_on_a_road():
    """§V-E waypoints: one on fly edges is airborne (hover power), one on a drive edge is not."""
    nodes = {"A": ((0.0, 0.0, 1.0), "air"), "WA": ((0.5, 0.0, 1.0), "waypoint"),
             "G": ((0.0, 0.0, 0.0), "land"), "WG": ((0.5, 0.0, 0.0), "waypoint")}
    edges = [("A", "WA", "fly"), ("WA", "A", "fly"), ("G", "WG", "drive"), ("WG", "G", "drive")]
    paths = {"a": [("WA", 0.0), ("WA", 4.0)], "g": [("WG", 0.0), ("WG", 4.0)]}
    report = validate_plan(make_plan(paths, nodes=nodes, edges=edges, cost=HAND["hover 4 s"] + HAND["wait 4 s on the ground"]))
    assert report.ok, report.errors
    assert report.vehicles["a"].cost == pytest.approx(HAND["hover 4 s"])
    assert report.vehicles["g"].cost == pytest.approx(HAND["wait 4 s on the ground"])


# -- the analytic contact test -----------------------------------------------------------------------------


def test_closest_approach_agrees_with_contact_intervals():
    rng = np.random.default_rng(3)
    d0 = rng.uniform(-0.25, 0.25, (20000, 3))
    d1 = rng.uniform(-0.25, 0.25, (20000, 3))
    d1[:2000] = d0[:2000]  # some relative rests
    d1[2000:4000, 2] = d0[2000:4000, 2]  # some level relative motions
    _, sep = closest_horizontal(d0, d1, 0.05)
    lo, hi = contact_intervals(d0, d1, 0.12, 0.05)
    clear = np.abs(sep - 0.12) > 1e-6
    assert np.array_equal((sep < 0.12)[clear], (lo < hi)[clear])
    assert 500 < np.count_nonzero(lo < hi) < 19000


def walks(n: int, steps: int, side: int = 8, seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Random walks on a side x side grid (0.25 m) whose nodes sit at heights within and beyond h of
    each other, with waits (some of zero length) and speeds 1-1.5x nominal: many contacts."""
    rng = np.random.default_rng(seed)
    z = rng.choice([1.0, 1.03, 1.2], size=(side, side))
    times, points = [], []
    for _ in range(n):
        ij, t, ts, ps = rng.integers(side, size=2), float(rng.uniform(0, 2)), [], []
        for _ in range(steps):
            ts.append(t)
            ps.append((0.25 * ij[0], 0.25 * ij[1], z[ij[0], ij[1]]))
            if rng.random() < 0.3:
                t += float(rng.choice([0.0, rng.uniform(0.1, 2.0)]))
            else:
                ij = np.clip(ij + rng.choice([-1, 1]) * np.eye(2, dtype=int)[rng.integers(2)], 0, side - 1)
                t += float(rng.uniform(1.0, 1.5))
        times.append(np.array(ts))
        points.append(np.array(ps))
    return times, points


def brute_force_episodes(times, points, radius, height) -> dict[tuple[int, int], int]:
    """Oracle: every pair on every interval of the union of entry times, by common.domain.geometry."""
    grid = np.unique(np.concatenate(times))
    grid = np.append(grid, grid[-1] + 1.0)
    pos = np.stack([np.stack([np.interp(grid, t, p[:, c]) for c in range(3)], axis=1) for t, p in zip(times, points, strict=True)])
    episodes = {}
    for a in range(len(times)):
        for b in range(a + 1, len(times)):
            d = pos[a] - pos[b]
            lo, hi = contact_intervals(d[:-1], d[1:], 2 * radius, height)
            runs = np.count_nonzero(np.diff(np.concatenate([[0], (lo < hi).astype(int)])) == 1)
            if runs:
                episodes[(a, b)] = runs
    return episodes


@pytest.mark.parametrize(("seed", "settings"), [
    (0, {}),
    (1, {"POSITION_BUDGET": 1, "ROW_BUDGET": 40}),  # one slab per batch, two pairs per row chunk
    (3, {"SLAB": 1, "SEPARATION_HORIZON": 1.0}),  # pruning boxes with no margin to spare
])
def test_contacts_match_a_brute_force_oracle(monkeypatch, seed, settings):
    """Sweep-and-prune finds exactly the contact episodes of an all-pairs, all-intervals check."""
    for name, value in settings.items():
        monkeypatch.setattr(validate, name, value)
    times, points = walks(24, 40, seed=seed)
    names = [f"v{i:02d}" for i in range(24)]
    contacts, _ = validate.find_contacts(names, times, points, 0.06, 0.05)
    found: dict[tuple[int, int], int] = {}
    for c in contacts:
        key = (names.index(c.a), names.index(c.b))
        found[key] = found.get(key, 0) + 1
    expected = brute_force_episodes(times, points, 0.06, 0.05)
    assert len(expected) > 10
    assert found == expected


# -- scale -----------------------------------------------------------------------------------------------------


def lanes_plan(n: int = 120, cols: int = 13, entries: int = 100, collide: bool = False, seed: int = 0) -> Plan:
    """n vehicles each shuttling along its own row of air nodes (rows 0.15 m apart, just over 2r) with
    random waits and speeds; with `collide`, vehicle 1 repeats vehicle 0's path 0.1 s later."""
    rng = np.random.default_rng(seed)
    nodes = {f"n{r}_{c}": ((0.5 * c, 0.15 * r, 1.0), "air") for r in range(n) for c in range(cols)}
    edges = [(f"n{r}_{c}", f"n{r}_{c + d}", "fly") for r in range(n) for c in range(cols) for d in (-1, 1) if 0 <= c + d < cols]
    paths = {}
    for r in range(n):
        col, t, path = int(rng.integers(cols)), float(rng.uniform(0, 2)), []
        for _ in range(entries):
            path.append((f"n{r}_{col}", t))
            if rng.random() < 0.3:
                t += float(rng.uniform(0.1, 3.0))
            else:
                col = col + 1 if col == 0 or (col < cols - 1 and rng.random() < 0.5) else col - 1
                t += 0.5 / 0.3 * float(rng.uniform(1.0, 1.5))
        paths[f"v{r}"] = path
    if collide:
        paths["v1"] = [(node, t + 0.1) for node, t in paths["v0"]]
    return make_plan(paths, nodes=nodes, edges=edges, cost=0.0)


def test_large_plan_validates_fast_and_finds_a_planted_contact():
    plan = lanes_plan()
    t0 = time.perf_counter()
    report = validate_plan(plan)
    elapsed = time.perf_counter() - t0
    assert [e for e in report.errors if not e.startswith("cost:")] == []
    assert report.min_separation == pytest.approx(0.15)
    assert elapsed < 5.0
    bad = validate_plan(lanes_plan(collide=True))
    assert [(c.a, c.b) for c in bad.contacts] == [("v0", "v1")]


# -- the command line ----------------------------------------------------------------------------------------


def test_fleet_validate_exit_codes(tmp_path, capsys):
    good, bad = tmp_path / "good.json", tmp_path / "bad.json"
    write_plan(make_plan(VALID), good)
    write_plan(make_plan({"a": [("L0", 0.0), ("L1", 9.0)]}), bad)
    assert fleet_main(["validate", str(good)]) == 0
    assert "plan: valid" in capsys.readouterr().out
    assert fleet_main(["validate", str(bad)]) == 1
    out = capsys.readouterr().out
    assert "INVALID (1 error)" in out and "too fast" in out


@pytest.mark.parametrize("content", ['{"format": "fleet-plan/1", "map": ', '{"format": "fleet-plan/1"}', "[]"])
def test_fleet_validate_malformed_file_exits_2_with_one_line(tmp_path, capsys, content):
    path = tmp_path / "broken.json"
    path.write_text(content)
    assert fleet_main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("fleet validate: error: ") and str(path) in err
    assert "\n" not in err
