"""An independent checker's view of plan files (issue 18): from the JSON file alone and the vehicle
model's eq. 1-5 (common/domain/vehicle_model.py), nothing of the planner. It recomputes eq. 3's
normalisers, W_max the largest edge energy and t_max the largest edge duration at the vehicle's
speeds, over the plan's own graph, and checks that no traversal is faster than its kind's speed and
that the ILP's flights on its one-time-step graph (§V-E) keep their speed where the air grid allows."""

from __future__ import annotations

import json
import math
from pathlib import Path

import msgspec
import pytest

from common.domain.vehicle_model import VehicleModel
from services.cli import main as fleet_main

CASES = [
    ("ilp", ["--map", "fig6", "--scenario", "maps/scenarios/fig6.yaml"]),
    ("ilp", ["--map", "grid125", "--random", "4"]),
    ("ilp", ["--map", "town", "--random", "3", "--seed", "2"]),
    ("sipp", ["--map", "town", "--random", "6"]),
    ("sipp", ["--map", "fig6", "--scenario", "maps/scenarios/fig6.yaml"]),
]


def write_plan_file(tmp_path: Path, planner: str, args: list[str]) -> dict:
    out = tmp_path / "plan.json"
    repo = Path(__file__).resolve().parents[1]
    args = [str(repo / a) if a.endswith(".yaml") else a for a in args]
    assert fleet_main(["plan", "--planner", planner, *args, "--out", str(out)]) == 0
    return json.loads(out.read_text())


def vehicle(doc: dict) -> VehicleModel:
    fields = {k: v for k, v in doc["model"].items() if k not in ("w_max", "t_max")}
    return msgspec.convert(fields, VehicleModel)


def edge_figures(doc: dict) -> list[tuple[str, float, float, float]]:
    """(kind, length, duration, energy) per edge of the plan's graph at the vehicle's speeds (eq. 1-2)."""
    model, nodes = vehicle(doc), doc["graph"]["nodes"]
    out = []
    for u, v, kind in doc["graph"]["edges"]:
        a, b = nodes[u]["pos"], nodes[v]["pos"]
        length = math.dist(a, b)
        duration = length / getattr(model.speed, kind)
        energy = (model.power.drive * duration if kind == "drive"
                  else model.power.fly * duration + model.mass * 9.81 * max(b[2] - a[2], 0.0))
        out.append((kind, length, duration, energy))
    return out


@pytest.mark.parametrize(("planner", "args"), CASES, ids=[f"{p}-{a[1]}" for p, a in CASES])
def test_plan_names_its_format_and_its_normalisers_are_the_graphs_at_speed(tmp_path, planner, args) -> None:
    doc = write_plan_file(tmp_path, planner, args)
    assert doc["format"] == "fleet-plan/1"
    figures = edge_figures(doc)
    assert doc["model"]["w_max"] == pytest.approx(max(f[3] for f in figures), rel=1e-9)
    assert doc["model"]["t_max"] == pytest.approx(max(f[2] for f in figures), rel=1e-9)
    if planner == "ilp":
        assert doc["model"]["t_max"] <= doc["dt"] * (1 + 1e-9)  # every edge fits one step

    # no traversal faster than its kind's speed; on the ILP's graph straight fly edges keep it
    kinds = {(u, v): k for u, v, k in doc["graph"]["edges"]}
    nodes, model = doc["graph"]["nodes"], vehicle(doc)
    flights = []
    for path in doc["paths"].values():
        for a, b in zip(path, path[1:], strict=False):
            if a["node"] == b["node"]:
                continue
            kind = kinds[(a["node"], b["node"])]
            length = math.dist(nodes[a["node"]]["pos"], nodes[b["node"]]["pos"])
            speed = length / (b["t"] - a["t"])
            assert speed <= getattr(model.speed, kind) * (1 + 1e-6)
            if kind == "fly":
                flights.append(speed / model.speed.fly)
    if planner == "ilp" and flights:
        assert max(flights) == pytest.approx(1.0)  # a grid fly edge takes exactly one step at fly speed


def test_fig6_ilp_plan_moves_at_every_kinds_speed(tmp_path) -> None:
    """fig6 is laid out on its step: every traversal of its ILP plan is at its kind's speed."""
    doc = write_plan_file(tmp_path, "ilp", CASES[0][1])
    kinds = {(u, v): k for u, v, k in doc["graph"]["edges"]}
    nodes, model = doc["graph"]["nodes"], vehicle(doc)
    for path in doc["paths"].values():
        for a, b in zip(path, path[1:], strict=False):
            if a["node"] != b["node"]:
                length = math.dist(nodes[a["node"]]["pos"], nodes[b["node"]]["pos"])
                kind = kinds[(a["node"], b["node"])]
                assert length / (b["t"] - a["t"]) == pytest.approx(getattr(model.speed, kind))
