"""Paper 000 Table II in the simulator (`bench.endurance`, `bench.results --only table2`): flight
and driving endurance and power measured with the simulator's battery and the executor's control
stack. Benches run as processes (tests do not import bench)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.compute

REPO = Path(__file__).resolve().parents[1]


def bench(module: str, *args: str, timeout: float = 600.0) -> subprocess.CompletedProcess:
    run = subprocess.run([sys.executable, "-m", f"bench.{module}", *args], cwd=REPO, capture_output=True, text=True,
                         timeout=timeout)
    assert run.returncode == 0, run.stderr[-2000:]
    return run


def test_simulated_flight_ends_on_the_voltage_sag_before_the_capacity_and_within_the_reserve(tmp_path) -> None:
    """Table II flying car: 0.3 m/s, 7.83 W, COT 64.9. The capacity holds 5.0 min at 7.83 W; under the
    2.1 A of flight the loaded voltage reaches the executor's 3.3 V earlier, with less charge left than
    the fleet's 10 % reserve (so a plan that keeps the reserve lands first)."""
    out = tmp_path / "endurance.json"
    bench("endurance", "--mode", "fly", "--out", str(out))
    fly = json.loads(out.read_text())["fly"]
    assert fly["ended"] == "voltage"
    assert 4.3 < fly["run_min"] < 4.95
    assert fly["speed"] == pytest.approx(0.3, abs=0.01)
    assert fly["cruise_power_w"] == pytest.approx(7.83, rel=0.02)
    assert fly["cot"] == pytest.approx(64.9, rel=0.03)
    assert 0.0 < fly["soc_left"] < 0.018 / 0.176
    assert fly["vbat_min"] < 3.3


@pytest.mark.scale
def test_only_table2_replaces_its_section_with_the_measured_rows(tmp_path) -> None:
    """`--only table2` measures both runs (about a minute) and rewrites Table II's section alone."""
    report = tmp_path / "results.md"
    report.write_text("# Results\n\n### Fig. 7: before\n\nkept\n\n### Table II: energetics\n\nold pending row\n\n"
                      "### The 934-node map\n\nalso kept\n")
    bench("results", "--only", "table2", "--docs", str(tmp_path), "--data", str(tmp_path / "data"))
    text = report.read_text()
    assert "old pending row" not in text and "kept\n" in text and text.endswith("also kept\n")
    assert text.index("### Fig. 7") < text.index("### Table II") < text.index("### The 934-node map")
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if "simulator (measured)" in line}
    assert set(rows) == {"Flying Car", "Wheels"}
    drive = json.loads((tmp_path / "data" / "table2.json").read_text())["sim"]["drive"]
    assert drive["ended"] == "voltage" and drive["soc_left"] < 0.03
    assert 60 < drive["run_min"] < 65.2 and drive["cot"] == pytest.approx(14.9, rel=0.03)
    assert f"| {drive['run_min']:.1f} |" in rows["Wheels"]
