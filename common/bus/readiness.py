"""Readiness of the processes `fleet up` starts (as `docker compose up --wait`).

The launcher gives each process a file name in ``FLEET_READY_FILE``; the process creates that file
once it serves: a `Service` when its session is open and its liveliness token declared, the router
when it listens. `fleet up` returns when every file exists, so that a mission started right after
it finds its executors and planner (a process importing its dependencies takes 1-3 s, more on a
loaded machine).
"""

from __future__ import annotations

import os
from pathlib import Path

READY_ENV = "FLEET_READY_FILE"


def mark_ready() -> None:
    """Tell the launcher this process serves (nothing when it was not started by one)."""
    path = os.environ.get(READY_ENV)
    if path:
        Path(path).touch()
