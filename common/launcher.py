"""Start and stop compose services as local processes (`fleet up`, `fleet down`, `fleet ps`).

State lives in a run directory (default `.fleet/`): `up.json` lists every started process (service,
instance, pid, argv) and `logs/<instance>.log` holds its output. `fleet down` sends SIGTERM in
reverse start order, waits for clean exits, and SIGKILLs what is left after the grace period.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

from common.compose import Process

DEFAULT_RUN_DIR = Path(".fleet")


def start(procs: list[Process], run_dir: Path = DEFAULT_RUN_DIR, settle_s: float = 0.3) -> list[dict]:
    """Start every process detached (own session), record it in run_dir/up.json."""
    state_file = run_dir / "up.json"
    if state_file.exists() and any(_alive(p["pid"]) for p in json.loads(state_file.read_text())):
        raise RuntimeError(f"services from {state_file} are still running: run `fleet down` first")
    (run_dir / "logs").mkdir(parents=True, exist_ok=True)
    started: list[dict] = []
    for proc in procs:
        log = open(run_dir / "logs" / f"{proc.instance}.log", "wb")  # noqa: SIM115 - handed to the child
        child = subprocess.Popen(
            proc.argv, env={**os.environ, **proc.env}, stdout=log, stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL, start_new_session=True,
        )
        log.close()
        started.append({"service": proc.service, "instance": proc.instance, "pid": child.pid, "argv": proc.argv})
        state_file.write_text(json.dumps(started, indent=1))
        if proc.service == "router":
            time.sleep(settle_s * 3)  # the others connect to it
    time.sleep(settle_s)
    return started


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # a zombie child of ours counts as gone
    try:
        done, _ = os.waitpid(pid, os.WNOHANG)
        return done == 0
    except ChildProcessError:
        return True


def status(run_dir: Path = DEFAULT_RUN_DIR) -> list[dict]:
    state_file = run_dir / "up.json"
    if not state_file.exists():
        return []
    return [{**p, "alive": _alive(p["pid"])} for p in json.loads(state_file.read_text())]


def stop(run_dir: Path = DEFAULT_RUN_DIR, grace_s: float = 5.0) -> list[tuple[str, str]]:
    """SIGTERM in reverse order, then SIGKILL after `grace_s`. Returns (instance, how it ended)."""
    state_file = run_dir / "up.json"
    if not state_file.exists():
        return []
    procs = json.loads(state_file.read_text())
    outcome: list[tuple[str, str]] = []
    for p in reversed(procs):
        if not _alive(p["pid"]):
            outcome.append((p["instance"], "already exited"))
            continue
        os.kill(p["pid"], signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        while _alive(p["pid"]) and time.monotonic() < deadline:
            time.sleep(0.05)
        if _alive(p["pid"]):
            os.killpg(p["pid"], signal.SIGKILL)
            outcome.append((p["instance"], "killed after grace period"))
        else:
            outcome.append((p["instance"], "stopped"))
    state_file.unlink()
    return outcome
