"""`make results` (bench/results.py): Table II as the planner's battery model sees it, Fig. 6 as a
bench, and (under `-m scale`) the whole pipeline in its --quick form. Benches run as processes
(tests do not import bench)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from common.domain.mapfile import load_map

pytestmark = pytest.mark.compute

REPO = Path(__file__).resolve().parents[1]


def bench(module: str, *args: str, timeout: float = 600.0) -> subprocess.CompletedProcess:
    run = subprocess.run([sys.executable, "-m", f"bench.{module}", *args], cwd=REPO, capture_output=True, text=True,
                         timeout=timeout)
    assert run.returncode == 0, run.stderr[-2000:]
    return run


def test_table2_from_the_model_matches_the_papers_flight_and_not_its_driving() -> None:
    """Table II: flying car 0.3 m/s, 5.0 min, 90 m, 7.83 W, COT 64.9; wheels 0.1 m/s, 42 min, 252 m,
    0.60 W, COT 14.9. The capacity is fitted to flight, so driving lasts 65 min in the model."""
    m = load_map("fig6").vehicle
    assert m.run_time_s(m.power.fly) / 60 == pytest.approx(5.0, abs=0.05)
    assert m.run_time_s(m.power.fly) * m.speed.fly == pytest.approx(90, abs=1)
    assert m.cost_of_transport(m.power.fly, m.speed.fly) == pytest.approx(64.9, abs=0.1)
    assert m.cost_of_transport(m.power.drive, m.speed.drive) == pytest.approx(14.9, abs=0.1)
    assert m.run_time_s(m.power.drive) / 60 == pytest.approx(65.1, abs=0.1)
    assert m.run_time_s(m.power.fly, usable=True) < m.run_time_s(m.power.fly)


def test_fig6_bench_keeps_json_and_png(tmp_path) -> None:
    bench("fig6", "--out", str(tmp_path))
    data = json.loads((tmp_path / "fig6.json").read_text())
    sipp, ilp = data["planners"]["sipp"], data["planners"]["ilp"]
    assert sipp["fliers"] == sipp["priority"][-1:] and ilp["fliers"] == []
    assert sipp["valid"] and ilp["valid"] and ilp["cost"] < sipp["cost"]
    assert (tmp_path / "fig6.png").stat().st_size > 10_000


def test_fig7_bench_keeps_json_and_png(tmp_path) -> None:
    bench("fig7", "--sizes", "3", "--trials", "2", "--out", str(tmp_path))
    data = json.loads((tmp_path / "fig7.json").read_text())
    both = data["summary"]["all"]["both_solved"]
    assert both == 2 and len(data["runs"]) == 4 and all(r["valid"] for r in data["runs"])
    assert data["ilp_mu"] != data["mu"] and data["summary"]["all"]["ilp"]["mean_cost"] is not None
    assert (tmp_path / "fig7.png").stat().st_size > 10_000


@pytest.mark.scale
def test_quick_pipeline_writes_the_report_and_figures(tmp_path) -> None:
    bench("results", "--quick", "--docs", str(tmp_path), "--data", str(tmp_path / "data"), timeout=600.0)
    report = (tmp_path / "results.md").read_text()
    for heading in ("Fig. 6", "Fig. 7", "Table II", "934-node", "MovingAI", "Paper 002"):
        assert heading in report
    assert "simulator (measured)" in report and "pending" not in report
    assert "64 %" in report and "cores" in report and "commit" in report
    for png in ("fig6", "fig7", "scale_city", "collab_experiment"):
        assert (tmp_path / "results" / f"{png}.png").stat().st_size > 10_000
