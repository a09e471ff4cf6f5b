"""compose.yaml exercised as local processes (issue 6): `fleet up`, the 8-vehicle town mission with
`fleet mission run`, `fleet down` stopping every service cleanly."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from common.bus.session import free_tcp_endpoint
from common.deploy.compose import interpolate
from common.deploy.radios import free_udp_ports
from tests.support.service_logs import service_warnings

pytestmark = pytest.mark.flight

REPO = Path(__file__).resolve().parents[1]
FLEET = [sys.executable, "-m", "services.cli"]


@pytest.mark.timeout(300)
def test_fleet_up_mission_down(tmp_path) -> None:
    port = free_tcp_endpoint().rsplit(":", 1)[1]
    run_dir = tmp_path / "run"
    radios = (REPO / "deploy" / "radios-town.yaml").read_text()
    for k in range(8):  # the shipped file's fixed UDP ports may be taken on a shared machine
        radios = radios.replace(f":{19850 + k}\n", f":{free_udp_ports(1)[0]}\n")
    (tmp_path / "radios.yaml").write_text(interpolate(radios, {"SIM_HOST": "127.0.0.1"}))
    sets = ["--set", f"FLEET_ROUTER_PORT={port}", "--set", "FLEET_NAME=uptest",
            "--set", f"FLEET_RECORDINGS={tmp_path / 'recordings'}", "--set", f"FLEET_RADIOS={tmp_path / 'radios.yaml'}"]
    up = subprocess.run([*FLEET, "up", "compose.yaml", "--run-dir", str(run_dir), *sets], cwd=REPO,
                        capture_output=True, text=True, timeout=60)
    try:
        assert up.returncode == 0, up.stdout + up.stderr
        assert up.stdout.count("started") == 11  # router, planner, 2 executors, sim, 4 gateways, mocap, telemetry
        operator = {"FLEET_ZENOH_USER": "mission", "FLEET_ZENOH_PASSWORD_FILE": str(run_dir / "secrets" / "zenoh-mission")}
        mission = subprocess.run(
            [*FLEET, "mission", "run", "maps/scenarios/town_8.yaml", "--connect", f"tcp/127.0.0.1:{port}",
             "--fleet", "uptest"], cwd=REPO, capture_output=True, text=True, timeout=200,
            env={**os.environ, **operator})
    finally:
        down = subprocess.run([*FLEET, "down", "--run-dir", str(run_dir)], cwd=REPO, capture_output=True, text=True,
                              timeout=120)
    print(mission.stdout[-3000:])
    assert mission.returncode == 0, mission.stdout[-3000:] + mission.stderr[-3000:] + service_warnings(run_dir / "logs")
    assert "OK (every vehicle arrived)" in mission.stdout and "contacts: 0" in mission.stdout
    assert down.returncode == 0, down.stdout
    assert down.stdout.count("stopped") == 11, down.stdout
    recordings = list((tmp_path / "recordings").glob("*.rrd"))
    assert recordings, "telemetry wrote no recording"
    printed = subprocess.run([str(Path(sys.executable).parent / "rerun"), "rrd", "print", str(recordings[0])],
                             capture_output=True, text=True, timeout=60).stdout
    for entity in ("/map/nodes", "/map/edges/fly", "/map/no_fly/north", "/plan/cf1", "/vehicles/cf1/body",
                   "/vehicles/cf1/battery_v", "/vehicles/cf1/link_quality", "/truth/cf1"):
        assert entity in printed, f"{entity} missing from the rerun recording"
