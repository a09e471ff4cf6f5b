"""The soak (issue 8; `make soak`, excluded from `make test`): 80 simulated vehicles through back to
back missions on city934 for FLEET_SOAK_MINUTES (default 5) minutes, run as `python -m bench.soak`,
which prints the tables (dropped messages, missed control deadlines, pose-to-command latency,
memory per process) and saves out/soak.png. It passes when every mission arrived without contact
and no process grew more than 5 MB a minute after the first third of the run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

MAX_GROWTH_MB_PER_MIN = 5.0
ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.soak
@pytest.mark.timeout(0)
def test_soak(tmp_path) -> None:
    minutes = os.environ.get("FLEET_SOAK_MINUTES", "5")
    vehicles = os.environ.get("FLEET_SOAK_VEHICLES", "80")
    out = tmp_path / "summary.json"
    subprocess.run([sys.executable, "-m", "bench.soak", "--minutes", minutes, "--vehicles", vehicles,
                    "--run-dir", str(tmp_path / "run"), "--summary", str(out)], cwd=ROOT, check=True)
    summary = json.loads(out.read_text())
    failed = [m["reason"] for m in summary["missions"] if not m["ok"]]
    assert summary["missions"] and not failed, failed
    growth = summary["growth_mb_per_min"]
    assert all(g < MAX_GROWTH_MB_PER_MIN for g in growth.values()), growth
