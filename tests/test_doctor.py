"""`fleet doctor` (issue 17 item 5) run as a process against a simulated fleet brought up as `fleet
demo` and the fault tests bring it up (compose.yaml's services as processes, the router in this
process, the shipped access control): every check passes on the healthy fleet; a vehicle switched
off (`fleet sim fault ... power_off`) fails its vehicle line, and a mission of it is refused before
planning, naming it; a body hidden from motion capture (`mocap_dropout`) fails its mocap line; both
exit non-zero. The tests share one fleet, in order."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from common.bus.messages import Pose, Telemetry
from common.bus.pubsub import subscribe
from common.bus.session import open_session
from common.deploy.radios import simulated_radios
from common.domain.scenario import read_scenario
from services.mission.client import MissionTiming
from services.mission.demo import LocalFleet, local_fleet
from services.mission.doctor import Heard, Limits, Parking, check_clocks, check_mocap, check_vehicle
from services.mission.runner import MissionRunner, MissionSpec

REPO = Path(__file__).resolve().parents[1]
VIDS = ("cf1", "cf2", "cf3", "cf4")
"""Four of the town mission's vehicles (two radios), parked on their start spots."""


@dataclass
class Doctor:
    fleet: LocalFleet
    scenario: Path

    def run(self, *args: str) -> subprocess.CompletedProcess[str]:
        env = {**os.environ, **self.fleet.credentials.env("mission")}
        return subprocess.run([sys.executable, "-m", "services.cli", *args, "--connect", self.fleet.endpoint,
                               "--fleet", self.fleet.keys.fleet], cwd=REPO, env=env, capture_output=True,
                              text=True, timeout=60)

    def doctor(self) -> subprocess.CompletedProcess[str]:
        return self.run("doctor", "--radios", str(self.fleet.run_dir / "radios.yaml"),
                        "--scenario", str(self.scenario))


def lines(out: str) -> dict[str, str]:
    """Check name ("vehicle cf2") -> its line."""
    return {line[6:20].strip(): line for line in out.splitlines() if line[:4] in ("PASS", "FAIL")}


@pytest.fixture(scope="module")
def doctor(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Doctor]:
    tmp = tmp_path_factory.mktemp("doctor")
    tasks = {vid: task for vid, task in read_scenario(REPO / "maps/scenarios/town_8.yaml").tasks.items()
             if vid in VIDS}
    scenario = tmp / "scenario.yaml"
    scenario.write_text("map: town\ntasks:\n" + "".join(f"  {vid}: {{start: {t.start}, goal: {t.goal}}}\n"
                                                       for vid, t in tasks.items()))
    with local_fleet("town", tasks, tmp / "run", executors=1, fleet="doctor", without=["telemetry"]) as fleet:
        yield Doctor(fleet, scenario)


async def _until_link_lost(fleet: LocalFleet, vid: str, timeout_s: float) -> None:
    lost = asyncio.Event()
    session = open_session(fleet.client_config())
    try:
        subscribe(session, fleet.keys.vehicle(vid, "telemetry"), Telemetry,
                  lambda m, _k: None if m.link_ok else lost.set())
        await asyncio.wait_for(lost.wait(), timeout_s)
    finally:
        session.close()


@pytest.mark.timeout(60)
def test_every_check_passes_on_a_healthy_fleet(doctor: Doctor) -> None:
    out = doctor.doctor()
    print(out.stdout)
    assert out.returncode == 0, out.stdout + out.stderr
    checks = lines(out.stdout)
    expected = {"router", "services", "radio radio0", "radio radio1", "clocks",
                *(f"vehicle {v}" for v in VIDS), *(f"mocap {v}" for v in VIDS)}
    assert set(checks) == expected and all(line.startswith("PASS") for line in checks.values()), out.stdout
    assert "ready to fly" in out.stdout


@pytest.mark.timeout(60)
def test_a_switched_off_vehicle_fails_its_line(doctor: Doctor) -> None:
    off = doctor.run("sim", "fault", "cf2", "power_off")
    assert off.returncode == 0, off.stderr
    try:
        asyncio.run(_until_link_lost(doctor.fleet, "cf2", 10.0))
        out = doctor.doctor()
    finally:
        doctor.run("sim", "fault", "cf2", "power_on")
    print(out.stdout)
    checks = lines(out.stdout)
    assert out.returncode == 1
    assert checks["vehicle cf2"].startswith("FAIL") and "does not answer" in checks["vehicle cf2"]
    assert all(checks[f"vehicle {v}"].startswith("PASS") for v in VIDS if v != "cf2"), out.stdout
    assert checks["mocap cf2"].startswith("PASS")  # switched off, it is still there to be seen
    assert "1 failed" in out.stdout


@pytest.mark.timeout(60)
def test_a_mission_of_a_switched_off_vehicle_is_refused_naming_it(doctor: Doctor) -> None:
    """A vehicle whose gateway has no link knows neither its battery nor its state: the mission
    waits `link_wait_s` for it, then refuses before planning (before this, its executor took the
    unknown 0 V for a low battery and the mission failed in flight)."""
    fleet = doctor.fleet
    tasks = dict(read_scenario(doctor.scenario).tasks)
    assert doctor.run("sim", "fault", "cf2", "power_off").returncode == 0
    try:
        asyncio.run(_until_link_lost(fleet, "cf2", 10.0))
        spec = MissionSpec(map="town", tasks=tasks, timing=MissionTiming(link_wait_s=2.0))
        runner = MissionRunner(spec, fleet.client_config(), fleet.keys, progress=False)
        t = time.monotonic()
        asyncio.run(runner.run())
        waited = time.monotonic() - t
    finally:
        doctor.run("sim", "fault", "cf2", "power_on")
    result = runner.result
    assert result is not None and not result.ok and result.plan is None
    assert result.reason.startswith("no radio link to cf2 (gateway radio0) after 2 s"), result.reason
    assert 2.0 <= waited < 6.0


@pytest.mark.timeout(60)
def test_a_hidden_body_fails_its_mocap_line(doctor: Doctor) -> None:
    hidden = doctor.run("sim", "fault", "cf3", "mocap_dropout", "--duration", "30")
    assert hidden.returncode == 0, hidden.stderr
    time.sleep(0.5)
    out = doctor.doctor()
    print(out.stdout)
    checks = lines(out.stdout)
    assert out.returncode == 1
    assert checks["mocap cf3"].startswith("FAIL") and "not seen" in checks["mocap cf3"]
    assert all(checks[f"mocap {v}"].startswith("PASS") for v in VIDS if v != "cf3"), out.stdout
    assert checks["vehicle cf3"].startswith("PASS")


def test_checks_name_what_is_wrong_with_the_numbers() -> None:
    spec = simulated_radios({"cf1": (0.0, 0.0, 0.0)}, per_radio=1)
    heard = Heard(started=100.0, ended=103.0)
    heard.telemetry["cf1"] = Telemetry(vid="cf1", t=103.0, gateway="r0", vbat=3.55, link_quality=0.5, sent=0,
                                       dropped=0, cmd_rate_hz=0.0, supervisor=0x40, firmware="2026.08")
    heard.poses["cf1"] = [(100.0 + i / 100, Pose(vid="cf1", t=0.0, x=0.3, y=0.0, z=0.0, yaw=0.0)) for i in range(300)]
    heard.offsets.update({"gateway/r0": 0.002, "executor/e1": -1.5})
    limits = Limits()
    vehicle = check_vehicle("cf1", spec, heard, limits)
    assert not vehicle.ok and "supervisor locked" in vehicle.detail and "battery 3.55 V below 3.80 V" in vehicle.detail
    assert "link quality 0.50 below 0.80" in vehicle.detail
    mocap = check_mocap("cf1", Parking((0.0, 0.0, 0.0), "its start"), heard, limits)
    assert not mocap.ok and "0.30 m from its start" in mocap.line()
    spots = Parking(None, "the map's spots", (("spot A", (5.0, 5.0, 0.0)), ("spot B", (0.25, 0.0, 0.0))))
    assert check_mocap("cf1", spots, heard, limits).ok  # 5 cm from the nearest spot
    (clock,) = check_clocks(heard, limits)
    assert not clock.ok and clock.line().startswith("FAIL  clocks") and "executor/e1: -1500 ms" in clock.detail
