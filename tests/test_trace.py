"""The soak's flight recorder (`python -m bench.trace`): raw payloads off a real zenoh router, kept in
chunks, and the timeline of chosen vehicles around a moment (run as the commands a user runs)."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.messages import SimTruth, Telemetry, VehicleEvent, VehicleState
from common.bus.pubsub import Publisher

KEYS = Keys("trace")


def trace(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench.trace", *args], capture_output=True, text=True, timeout=60)


@pytest.mark.timeout(90)
def test_a_recording_shows_the_chosen_vehicles_around_the_moment(
        zenoh_router: str, zsession: Callable[..., zenoh.Session], tmp_path: Path) -> None:
    path = tmp_path / "soak.trace"
    recorder = subprocess.Popen([sys.executable, "-m", "bench.trace", "record", str(path), "--connect", zenoh_router,
                                 "--fleet", "trace"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    session = zsession()
    truth = {vid: Publisher(session, KEYS.sim_truth(vid), SimTruth) for vid in ("cf1", "cf2")}
    state = Publisher(session, KEYS.vehicle("cf1", "state"), VehicleState)
    event = Publisher(session, KEYS.vehicle("cf1", "event"), VehicleEvent)
    tel = Publisher(session, KEYS.vehicle("cf1", "telemetry"), Telemetry)
    assert recorder.stdout is not None
    assert recorder.stdout.readline().startswith(f"recording to {path}")  # (its subscriptions declared)
    time.sleep(0.5)  # ... and at the router
    now = time.time()
    truth["cf1"].put(SimTruth(vid="cf1", t=now, x=1.0, y=2.0, z=0.25, yaw=0.0, vz=-0.5, airborne=True, motors=True))
    truth["cf2"].put(SimTruth(vid="cf2", t=now, x=1.0, y=2.0, z=0.0, yaw=0.0))
    time.sleep(1.5)  # (a chunk a second)
    state.put(VehicleState(vid="cf1", t=now, owner="e1", mode="emergency_landing", x=1.0, y=2.0, z=0.3, yaw=0.0,
                           pose_ok=False))
    event.put(VehicleEvent(vid="cf1", t=now, kind="emergency_landing", detail="from flying"))
    tel.put(Telemetry(vid="cf1", t=now, gateway="radio0", vbat=3.9, link_quality=0.5, sent=10, dropped=5,
                      cmd_rate_hz=100.0, link_ok=False))
    time.sleep(0.5)
    out, _ = recorder.communicate("", timeout=30)
    assert recorder.returncode == 0 and f"recorded 5 messages to {path}" in out, out

    at = str(time.time())
    shown = trace("show", str(path), "--vehicles", "cf1", "--at", at, "--before", "30")
    lines = shown.stdout.splitlines()
    by_kind = {ln.split()[2]: ln for ln in lines}  # (the four keys' messages may arrive in any order)
    assert len(lines) == 4 and set(by_kind) == {"truth", "state", "event", "telemetry"}, shown
    assert "(1.000, 2.000, 0.250) v (0.00, 0.00, -0.50) air motors on" in by_kind["truth"]
    assert "emergency_landing" in by_kind["state"] and "pose stale" in by_kind["state"]
    assert "link LOST" in by_kind["telemetry"]
    assert trace("show", str(path), "--vehicles", "cf1,cf2", "--at", at, "--before", "0.01").stdout.strip() == ""

    with path.open("ab") as fh:  # a run killed while writing: what came before stays readable
        fh.write(b"\x10\x00\x00\x00\x93")
    assert "cf2 truth" in trace("show", str(path), "--vehicles", "cf2", "--at", at, "--before", "30").stdout
    listed = trace("show", str(path), "--vehicles", "cf1,cf2").stdout.splitlines()  # no moment: the events
    assert len(listed) == 1 and listed[0].endswith("cf1 emergency_landing from flying"), listed


def test_a_bad_moment_or_a_missing_recording_is_a_clear_error(tmp_path: Path) -> None:
    missing = trace("show", str(tmp_path / "none.trace"), "--vehicles", "cf1", "--at", "1.0")
    assert missing.returncode == 2 and "none.trace: no such recording" in missing.stderr
    noon = trace("show", str(tmp_path / "none.trace"), "--vehicles", "cf1", "--at", "noon")
    assert noon.returncode == 2 and "--at: 'noon' is neither epoch seconds nor HH:MM:SS" in noon.stderr
    assert "Traceback" not in missing.stderr + noon.stderr
