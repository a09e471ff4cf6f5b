"""The `fleet` command's parser: every service process builds all of it, so it must not import the
services' dependencies (they took 3 s of CPU per process: 33 s for `fleet up`'s 11 services)."""

from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY = ("filterpy", "scipy", "rerun", "networkx", "highspy", "numpy", "cflib")


def test_building_the_parser_imports_no_service_dependency() -> None:
    probe = ("import sys; from services.cli import build_parser; build_parser(); "
             f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.split() == []


def test_a_lazy_handler_runs_its_command() -> None:
    out = subprocess.run([sys.executable, "-m", "services.cli", "demo", "--scenario", "no/such.yaml"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "no/such.yaml" in out.stderr and "Traceback" not in out.stderr


@pytest.mark.parametrize("lead", ["0", "nan"])
def test_a_demo_with_no_positive_lead_is_refused_before_any_process_starts(lead: str) -> None:
    out = subprocess.run([sys.executable, "-m", "services.cli", "demo", "--lead", lead, "--out", "/nonexistent/demo"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and f"--lead: {lead}: must be positive" in out.stderr and "Traceback" not in out.stderr


def test_a_mission_with_a_negative_rejoin_count_is_refused_before_it_connects() -> None:
    out = subprocess.run([sys.executable, "-m", "services.cli", "mission", "run", "maps/scenarios/town_8.yaml",
                          "--rejoins", "-1", "--connect", "tcp/127.0.0.1:9"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--rejoins: -1: must be 0 or more" in out.stderr and "Traceback" not in out.stderr
