"""The services' own warnings from a run directory's logs: the tests that run the fleet as processes
put them into their failure messages (stalls, watchdogs, take-overs say why a mission failed)."""

from __future__ import annotations

from pathlib import Path


def service_warnings(logs: Path, last: int = 80, also: str = "") -> str:
    """The last `last` WARNING/ERROR lines of every `*.log` under `logs`, each named by its file;
    also the lines that contain `also` (e.g. the executors' INFO mode changes), if given."""
    lines = [f"{log.stem}: {line}" for log in sorted(logs.rglob("*.log"))
             for line in log.read_text(errors="replace").splitlines()
             if "WARNING" in line or "ERROR" in line or (also and also in line)]
    return "\nservice warnings:\n" + "\n".join(lines[-last:])
