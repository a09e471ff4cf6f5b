"""A process's CPU priority: the recorder gives way to the control loops, the simulator (the world)
goes before them; each changes its own nice value and, leading its session, its autogroup's."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PROBE = """
import os, sys
from common.bus.process_priority import adjust_priority
adjust_priority(int(sys.argv[1]))
group = open("/proc/self/autogroup").read().split()[-1] if os.path.exists("/proc/self/autogroup") else "none"
print(os.getpriority(os.PRIO_PROCESS, 0), group)
"""


def _probe(nice: int) -> tuple[int, str]:
    out = subprocess.run([sys.executable, "-c", PROBE, str(nice)], cwd=REPO, capture_output=True, text=True,
                         check=True, start_new_session=True, timeout=30)
    value, group = out.stdout.split()
    return int(value), group


def test_a_lowered_process_and_its_own_autogroup_give_way() -> None:
    value, group = _probe(7)
    assert value == os.getpriority(os.PRIO_PROCESS, 0) + 7
    assert group in ("none", str(value))


@pytest.mark.skipif(os.geteuid() != 0, reason="raising a priority needs root (CAP_SYS_NICE)")
def test_a_raised_process_and_its_own_autogroup_go_first() -> None:
    value, group = _probe(-10)
    assert value == os.getpriority(os.PRIO_PROCESS, 0) - 10
    assert group in ("none", str(value))


def test_the_simulator_refuses_a_negative_priority_by_name() -> None:
    out = subprocess.run([sys.executable, "-m", "services.cli", "sim", "--config", "deploy/radios-town.yaml",
                          "--priority", "-3"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--priority" in out.stderr and "Traceback" not in out.stderr, out.stderr
