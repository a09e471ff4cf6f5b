"""compose.yaml as local processes: parsing, interpolation, replicas, order, errors; up and down."""

from __future__ import annotations

import sys
import time

import pytest

from common.deploy.compose import interpolate, load_compose
from common.deploy.launcher import start, status, stop, wait_ready
from services.cli import main


def test_interpolation_like_compose() -> None:
    env = {"A": "1", "EMPTY": ""}
    assert interpolate("x${A}y ${B:-dflt} ${EMPTY:-e} ${B-z}", env) == "x1y dflt e z"


def test_replicas_order_env_and_local_stand_in(tmp_path) -> None:
    path = tmp_path / "compose.yaml"
    path.write_text("""
services:
  worker:
    image: fleet
    command: ["fleet", "executor", "--connect", "tcp/${ROUTER_HOST:-router}:7447"]
    environment: {FLEET_NAME: lab}
    deploy: {replicas: 3}
    depends_on: [router]
  router:
    image: eclipse/zenoh:1.1.0
    x-fleet-local: ["fleet", "router"]
    ports: ["7447:7447"]
""")
    procs = load_compose(path)
    assert [p.instance for p in procs] == ["router", "worker-1", "worker-2", "worker-3"]
    worker = procs[1]
    assert worker.argv[:3] == [sys.executable, "-m", "services.cli"]
    assert worker.argv[-1] == "tcp/127.0.0.1:7447"
    assert worker.env == {"FLEET_NAME": "lab", "FLEET_INSTANCE": "worker-1"}
    assert procs[0].argv[3:] == ["router"]


@pytest.mark.parametrize(("text", "field"), [
    ("services:\n  a: {command: [x], depends_on: [b]}\n", "services.a.depends_on"),
    ("services:\n  a: {image: foo}\n", "services.a"),
    ("services:\n  a: {command: [x], deploy: {replicas: 0}}\n", "services.a.deploy.replicas"),
    ("services: [\n", "invalid YAML"),
])
def test_bad_compose_files_name_the_field(tmp_path, capsys, text: str, field: str) -> None:
    path = tmp_path / "compose.yaml"
    path.write_text(text)
    assert main(["up", str(path), "--run-dir", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert field in err and str(path) in err and "Traceback" not in err


def _compose(tmp_path, text: str):
    """`text` as tmp_path/compose.yaml; its path."""
    path = tmp_path / "compose.yaml"
    path.write_text(text)
    return path


def test_up_then_down_stops_every_process_cleanly(tmp_path) -> None:
    path = _compose(tmp_path, """
services:
  sleeper:
    command: ["python3", "-c", "import signal, sys, time; signal.signal(signal.SIGTERM, lambda *a: sys.exit(0)); time.sleep(60)"]
    deploy: {replicas: 2}
""")
    run = tmp_path / "run"
    started = start(load_compose(path), run, settle_s=0.1)
    assert len(started) == 2 and all(p["alive"] for p in status(run))
    with pytest.raises(RuntimeError, match="still running"):
        start(load_compose(path), run)
    t = time.monotonic()
    outcome = stop(run, grace_s=5)
    assert [how for _, how in outcome] == ["stopped", "stopped"]
    assert time.monotonic() - t < 5
    assert status(run) == []


def test_wait_ready_names_the_processes_that_never_served(tmp_path) -> None:
    path = _compose(tmp_path, """
services:
  server:
    command: ["python3", "-c", "import os, pathlib, time; time.sleep(0.5); pathlib.Path(os.environ['FLEET_READY_FILE']).touch(); time.sleep(60)"]
  crasher:
    command: ["python3", "-c", "raise SystemExit(3)"]
""")
    run = tmp_path / "run"
    start(load_compose(path), run, settle_s=0.0)
    try:
        t = time.monotonic()
        assert wait_ready(run, timeout_s=20.0) == {"crasher": "exited"}
        assert time.monotonic() - t < 10.0  # returned once the server served, not at the timeout
        assert (run / "ready" / "server").exists()
    finally:
        stop(run, grace_s=2)
