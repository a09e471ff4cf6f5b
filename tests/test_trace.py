"""The soak's flight recorder (`bench/trace.py`): raw payloads off a real zenoh router, kept in
chunks, and the timeline of chosen vehicles around a moment."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from bench import trace
from common.bus.keys import Keys
from common.bus.messages import SimTruth, Telemetry, VehicleEvent, VehicleState
from common.bus.pubsub import Publisher
from common.bus.session import ZenohConfig

KEYS = Keys("trace")


def wait_for(recorder: trace.Recorder, n: int) -> None:
    deadline = time.time() + 5.0
    while len(recorder._rows) < n and time.time() < deadline:
        time.sleep(0.02)


@pytest.mark.timeout(30)
def test_a_recording_shows_the_chosen_vehicles_around_the_moment(
        zenoh_router: str, zsession: Callable[..., zenoh.Session], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "soak.trace"
    recorder = trace.Recorder(ZenohConfig.client(zenoh_router), KEYS, path)
    session = zsession()
    truth = {vid: Publisher(session, KEYS.sim_truth(vid), SimTruth) for vid in ("cf1", "cf2")}
    state = Publisher(session, KEYS.vehicle("cf1", "state"), VehicleState)
    event = Publisher(session, KEYS.vehicle("cf1", "event"), VehicleEvent)
    tel = Publisher(session, KEYS.vehicle("cf1", "telemetry"), Telemetry)
    time.sleep(0.5)  # (the subscriptions reach the router)
    now = time.time()
    truth["cf1"].put(SimTruth(vid="cf1", t=now, x=1.0, y=2.0, z=0.25, yaw=0.0, vz=-0.5, airborne=True, motors=True))
    truth["cf2"].put(SimTruth(vid="cf2", t=now, x=1.0, y=2.0, z=0.0, yaw=0.0))
    wait_for(recorder, 2)
    recorder.flush()  # two chunks
    state.put(VehicleState(vid="cf1", t=now, owner="e1", mode="emergency_landing", x=1.0, y=2.0, z=0.3, yaw=0.0,
                           pose_ok=False))
    event.put(VehicleEvent(vid="cf1", t=now, kind="emergency_landing", detail="from flying"))
    tel.put(Telemetry(vid="cf1", t=now, gateway="radio0", vbat=3.9, link_quality=0.5, sent=10, dropped=5,
                      cmd_rate_hz=100.0, link_ok=False))
    wait_for(recorder, 3)
    recorder.close()
    assert recorder.count == 5

    at = str(time.time())
    lines = trace.show(path, {"cf1"}, at, before=10.0, after=1.0, every=0.1)
    by_kind = {ln.split()[2]: ln for ln in lines}  # (the four keys' messages may arrive in any order)
    assert len(lines) == 4 and set(by_kind) == {"truth", "state", "event", "telemetry"}, lines
    assert "(1.000, 2.000, 0.250) v (0.00, 0.00, -0.50) air motors on" in by_kind["truth"]
    assert "emergency_landing" in by_kind["state"] and "pose stale" in by_kind["state"]
    assert "link LOST" in by_kind["telemetry"]
    assert trace.show(path, {"cf1", "cf2"}, at, before=0.01, after=1.0, every=0.1) == []  # all before the window

    with path.open("ab") as fh:  # a run killed while writing: what came before stays readable
        fh.write(b"\x10\x00\x00\x00\x93")
    assert len(list(trace.read(path))) == 5
    assert trace.main(["show", str(path), "--vehicles", "cf2", "--at", at, "--before", "10"]) == 0
    assert "cf2 truth" in capsys.readouterr().out
    assert trace.main(["show", str(path), "--vehicles", "cf1,cf2"]) == 0  # no moment: the events
    listed = capsys.readouterr().out.splitlines()
    assert len(listed) == 1 and listed[0].endswith("cf1 emergency_landing from flying"), listed


def test_a_bad_moment_or_a_missing_recording_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert trace.main(["show", str(tmp_path / "none.trace"), "--vehicles", "cf1", "--at", "1.0"]) == 2
    assert "none.trace: no such recording" in capsys.readouterr().err
    assert trace.main(["show", str(tmp_path / "none.trace"), "--vehicles", "cf1", "--at", "noon"]) == 2
    assert "--at: 'noon' is neither epoch seconds nor HH:MM:SS" in capsys.readouterr().err
