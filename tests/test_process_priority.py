"""`common/bus/process_priority.py`: the simulator raises its priority where the system allows it."""

from __future__ import annotations

import os
import subprocess
import sys

PROBE = """
import os, sys
from common.bus.process_priority import raise_priority, lower_priority
os.setsid()  # its own session, as `fleet up` starts each service: its autogroup is its own
before = os.nice(0)
raised = raise_priority(3)
after_raise = os.nice(0)
lower_priority(4)
print(before, raised, after_raise, os.nice(0))
"""


def test_raising_takes_from_the_nice_value_where_allowed_and_lowering_adds() -> None:
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, check=True,
                         cwd=os.getcwd()).stdout.split()
    before, raised, after_raise, after_lower = int(out[0]), out[1] == "True", int(out[2]), int(out[3])
    if raised:  # root or CAP_SYS_NICE
        assert after_raise == before - 3
    else:  # refused: a log line, the process runs on at its value
        assert after_raise == before
    assert after_lower == after_raise + 4
