"""Start and stop compose services as local processes (`fleet up`, `fleet down`, `fleet ps`).

State lives in a run directory (default `.fleet/`): `up.json` lists every started process (service,
instance, pid, argv), `logs/<instance>.log` holds its output and `ready/<instance>` appears once it
serves (`common.bus.readiness`). `fleet down` sends SIGTERM to every
service at once (reverse start order), then to the router once they are gone, so that they can
leave cleanly through it; it SIGKILLs what is left after the grace period.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

from common.bus.readiness import READY_ENV
from common.deploy.compose import Process

DEFAULT_RUN_DIR = Path(".fleet")


ROUTER_READY_S = 10.0
"""How long `start` waits for a router to listen before starting the services that connect to it."""


def start(procs: list[Process], run_dir: Path = DEFAULT_RUN_DIR, settle_s: float = 0.3) -> list[dict]:
    """Start every process detached (own session), record it in run_dir/up.json; a router is
    started first and listening (or given up on after `ROUTER_READY_S`) before the others."""
    state_file = run_dir / "up.json"
    if state_file.exists() and any(_alive(p["pid"]) for p in json.loads(state_file.read_text())):
        raise RuntimeError(f"services from {state_file} are still running: run `fleet down` first")
    (run_dir / "logs").mkdir(parents=True, exist_ok=True)
    (run_dir / "ready").mkdir(exist_ok=True)
    started: list[dict] = []
    for proc in sorted(procs, key=lambda p: p.service != "router"):
        ready = _ready_file(run_dir, proc.instance)
        ready.unlink(missing_ok=True)
        log = open(run_dir / "logs" / f"{proc.instance}.log", "wb")  # noqa: SIM115 - handed to the child
        child = subprocess.Popen(
            proc.argv, env={**os.environ, **proc.env, READY_ENV: str(ready)}, stdout=log, stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL, start_new_session=True,
        )
        log.close()
        started.append({"service": proc.service, "instance": proc.instance, "pid": child.pid, "argv": proc.argv})
        state_file.write_text(json.dumps(started, indent=1))
        if proc.service == "router":  # the others connect to it
            _wait_ready(run_dir, started[-1:], ROUTER_READY_S)
    time.sleep(settle_s)
    return started


def wait_ready(run_dir: Path = DEFAULT_RUN_DIR, timeout_s: float = 60.0) -> dict[str, str]:
    """Wait until every started process marked itself ready (`common.bus.readiness`), has exited or
    `timeout_s` passed; the instances not ready, each "exited" or "not ready"."""
    state_file = run_dir / "up.json"
    return _wait_ready(run_dir, json.loads(state_file.read_text()) if state_file.exists() else [], timeout_s)


def _wait_ready(run_dir: Path, procs: list[dict], timeout_s: float) -> dict[str, str]:
    deadline = time.monotonic() + timeout_s
    while True:
        waiting = [p for p in procs if not _ready_file(run_dir, p["instance"]).exists()]
        exited = {p["instance"] for p in waiting if not _alive(p["pid"])}
        if len(exited) == len(waiting) or time.monotonic() > deadline:
            return {p["instance"]: "exited" if p["instance"] in exited else "not ready" for p in waiting}
        time.sleep(0.1)


def _ready_file(run_dir: Path, instance: str) -> Path:
    return run_dir / "ready" / instance


def _alive(pid: int) -> bool:
    """The process exists and has not exited: an exited process waiting to be reaped (a zombie:
    ours, or one `fleet up` left to init, which may reap it a second later) counts as gone."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        done, _ = os.waitpid(pid, os.WNOHANG)
        if done:
            return False
    except ChildProcessError:
        pass
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rpartition(")")[2].split()[0] != "Z"
    except (OSError, IndexError):
        return True  # no procfs: trust the signal


def status(run_dir: Path = DEFAULT_RUN_DIR) -> list[dict]:
    state_file = run_dir / "up.json"
    if not state_file.exists():
        return []
    return [{**p, "alive": _alive(p["pid"])} for p in json.loads(state_file.read_text())]


def stop(run_dir: Path = DEFAULT_RUN_DIR, grace_s: float = 5.0) -> list[tuple[str, str]]:
    """SIGTERM every service, then the router; SIGKILL after `grace_s`. Returns (instance, how it
    ended) in reverse start order."""
    state_file = run_dir / "up.json"
    if not state_file.exists():
        return []
    procs = list(reversed(json.loads(state_file.read_text())))
    ended = {**_stop_all([p for p in procs if p["service"] != "router"], grace_s),
             **_stop_all([p for p in procs if p["service"] == "router"], grace_s)}
    state_file.unlink()
    return [(p["instance"], ended[p["instance"]]) for p in procs]


def _stop_all(procs: list[dict], grace_s: float) -> dict[str, str]:
    """SIGTERM each of `procs`, wait for all of them, SIGKILL the ones left after `grace_s`."""
    ended: dict[str, str] = {}
    for p in procs:
        if _alive(p["pid"]):
            os.kill(p["pid"], signal.SIGTERM)
        else:
            ended[p["instance"]] = "already exited"
    deadline = time.monotonic() + grace_s
    while any(_alive(p["pid"]) for p in procs if p["instance"] not in ended) and time.monotonic() < deadline:
        time.sleep(0.05)
    for p in procs:
        if p["instance"] in ended:
            continue
        if _alive(p["pid"]):
            os.killpg(p["pid"], signal.SIGKILL)
            ended[p["instance"]] = "killed after grace period"
        else:
            ended[p["instance"]] = "stopped"
    return ended
