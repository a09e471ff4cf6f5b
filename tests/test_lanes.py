"""`make test`'s two lanes (tests/lanes.py): the compute lane's process runs at idle priority, and
the suite's exit status is the failing lane's."""

from __future__ import annotations

import os
import subprocess
import sys

from tests.lanes import NO_TESTS, idle, lanes_status


def test_the_compute_lane_runs_idle_in_a_session_of_its_own() -> None:
    probe = "import os; print(os.sched_getscheduler(0) == os.SCHED_IDLE, os.nice(0), os.getsid(0) == os.getpid())"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, cwd=os.getcwd(),
                         start_new_session=True, preexec_fn=idle)
    assert out.stdout.split() == ["True", "19", "True"]


def test_a_failing_lane_fails_the_suite_and_an_empty_one_does_not() -> None:
    assert lanes_status(0, 0) == 0
    assert lanes_status(1, 0) == 1 and lanes_status(0, 2) == 2 and lanes_status(NO_TESTS, 1) == 1
    assert lanes_status(NO_TESTS, 0) == 0 and lanes_status(0, NO_TESTS) == 0
    assert lanes_status(NO_TESTS, NO_TESTS) == NO_TESTS
