"""`make test`: the suite in two lanes at once on one machine.

The real-time lane runs every test not marked `compute` (the flights, anything with a service or a
loop on the clock) one after another at normal priority: two flights at once starve each other's
control loops on 2 cores. The compute lane (planners, closed loops in simulated time, the
benchmarks' smoke runs) runs beside it as a second pytest in a session of its own at idle CPU
priority (SCHED_IDLE, nice 19, its autogroup at nice 19): it takes only the CPU the real-time lane
leaves idle, which is most of a core, since a flight mostly waits on real time. A test whose
result depends on a wall-clock budget (the ILP solved to its gap within its time limit, a replan
within 1 s) is not `compute`: at idle priority it may not get the CPU in time. For the same reason
a compute test's time limits only guard against a hang: the lane's per-test limit is
`COMPUTE_TIMEOUT_S` (the CI machine, on a slow hour, ran that lane 3 times slower than it runs
alone, and one benchmark's 120 s subprocess limit ran out), and its tests' subprocess limits are
minutes.

Measured on the 2-core CI machine: one lane, 1176 s of pytest (20 min 45 s in all); two lanes, the
real-time one 1005 s and the compute one 328 s beside it (17 min 46 s in all), no flight slowed or
rerun. (pytest-xdist's `loadgroup` would be the usual tool, but with pytest 9.2 its groups do not
reach its scheduler: one run put flights on both workers at once, five tests failed and eleven
flights reran.)

    python -m tests.lanes [PYTEST_ARGS...]   (extra arguments go to both lanes)

The compute lane's output follows the real-time lane's.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from pytest import ExitCode

from common.bus.process_priority import lower_priority

SELECTION = "not soak and not scale"
REAL_TIME = f"not compute and {SELECTION}"
COMPUTE = f"compute and {SELECTION}"
NO_TESTS = ExitCode.NO_TESTS_COLLECTED
COMPUTE_TIMEOUT_S = 1200
"""pytest-timeout's limit per test in the compute lane (pyproject's 300 s elsewhere)."""


def idle() -> None:
    """In the compute lane's process before it runs pytest (a new session, so its own autogroup):
    the lowest priority there is; its threads and child processes inherit it."""
    lower_priority(19 - os.nice(0))
    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))


def main(argv: list[str]) -> int:
    pytest = [sys.executable, "-m", "pytest"]
    with tempfile.TemporaryDirectory(prefix="fleet-compute-lane-") as tmp:
        log = Path(tmp) / "compute.log"
        with log.open("w") as out:
            compute = subprocess.Popen([*pytest, "-m", COMPUTE, "--basetemp", str(Path(tmp) / "basetemp"),
                                        "-p", "no:cacheprovider",
                                        "-o", f"timeout={COMPUTE_TIMEOUT_S}", *argv], stdout=out, stderr=subprocess.STDOUT,
                                       start_new_session=True, preexec_fn=idle)
            try:
                print(f"real-time lane ({REAL_TIME}); the compute lane ({COMPUTE}) runs beside it", flush=True)
                real_time = subprocess.run([*pytest, "-m", REAL_TIME, *argv]).returncode
                print("\ncompute lane:", flush=True)
                compute_rc = compute.wait()
            finally:
                if compute.poll() is None:
                    compute.terminate()
                    compute.wait()
        sys.stdout.write(log.read_text())
    return lanes_status(real_time, compute_rc)


def lanes_status(*codes: int) -> int:
    """The first failing lane's exit status; a lane whose selection has no test (a path
    given that holds only the other lane's tests) is not a failure unless neither lane had one."""
    failed = [code for code in codes if code not in (0, NO_TESTS)]
    return failed[0] if failed else (NO_TESTS if all(code == NO_TESTS for code in codes) else 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
