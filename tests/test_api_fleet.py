"""The Python API (`services.api`) and the examples against `fleet up` (issue 19): compose.yaml's
simulated town fleet as local processes; the API connects as a user's script would (the endpoint and
`fleet up`'s credentials), and each example in examples/ runs as a process against the same fleet
(the team example brings up its own team). Vehicles are used so that each test starts them from
where the one before left them."""

from __future__ import annotations

import math
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from common.bus.session import free_tcp_endpoint
from services.api import CommandRefused, Fleet, MissionEvent, PlanningError, VehicleBusy
from tests.support.service_logs import service_warnings

pytestmark = pytest.mark.flight

REPO = Path(__file__).resolve().parents[1]
FLEET = [sys.executable, "-m", "services.cli"]
EP1 = (3.0, 0.13)
"""cf4's start in maps/scenarios/town_8.yaml (the town's east parking spot EP1)."""


@pytest.fixture(scope="module")
def fleet_up(tmp_path_factory: pytest.TempPathFactory):
    """`fleet up` (the town's 8 simulated flying cars); yields (run_dir, the environment a client uses)."""
    run_dir = tmp_path_factory.mktemp("api-fleet")
    port = free_tcp_endpoint().rsplit(":", 1)[1]
    up = subprocess.run([*FLEET, "up", "--run-dir", str(run_dir), "--set", f"FLEET_ROUTER_PORT={port}",
                         "--set", "FLEET_NAME=apitest", "--set", f"FLEET_RECORDINGS={run_dir / 'recordings'}"],
                        cwd=REPO, capture_output=True, text=True, timeout=120)
    try:
        assert up.returncode == 0, up.stdout + up.stderr
        yield run_dir, {"FLEET_ZENOH_CONNECT": f"tcp/127.0.0.1:{port}", "FLEET_NAME": "apitest",
                        "FLEET_ZENOH_USER": "mission",
                        "FLEET_ZENOH_PASSWORD_FILE": str(run_dir / "secrets" / "zenoh-mission")}
    finally:
        subprocess.run([*FLEET, "down", "--run-dir", str(run_dir)], cwd=REPO, capture_output=True, timeout=120)


@pytest.mark.timeout(180)
def test_the_api_lists_plans_runs_refuses_a_busy_vehicle_and_aborts(fleet_up) -> None:
    run_dir, env = fleet_up
    with Fleet.connect(env["FLEET_ZENOH_CONNECT"], "apitest", secrets=run_dir / "secrets") as fleet:
        vehicles = fleet.vehicles(8)
        assert sorted(vehicles) == [f"cf{i}" for i in range(1, 9)]
        cf6 = vehicles["cf6"]
        assert abs(cf6.x - 4.07) < 0.05 and abs(cf6.y - 1.55) < 0.05 and cf6.mode == "idle"  # on EP10, no plan yet
        assert cf6.battery_v is not None and cf6.battery_v > 3.7 and not cf6.busy

        plan = fleet.plan("town", {"cf7": ("WP9", "WP2")})
        assert plan.paths["cf7"][0].node == "WP9" and plan.paths["cf7"][-1].node == "WP2"
        with pytest.raises(PlanningError) as bad:
            fleet.plan("town", {"cf7": ("WP9", "nowhere")})
        assert bad.value.vehicle == "cf7" and "nowhere" in bad.value.reason

        events: list[MissionEvent] = []
        # cf6 drives down the east edge (out of the way of the examples' vehicles when it stops)
        with pytest.raises(ValueError, match="rejoins must be 0 or more"):
            fleet.start_mission("town", {"cf6": ("EP10", "EP9")}, rejoins=-1)
        mission = fleet.start_mission("town", {"cf6": ("EP10", "EP9")}, rejoins=1, on_event=events.append)
        for event in mission.events():
            if event.kind == "progress" and event.step >= 2:
                break
        with pytest.raises(VehicleBusy) as busy:  # the single-vehicle command, refused
            fleet.go_to("cf6", "EP5")
        assert busy.value.vehicle == "cf6" and busy.value.mission == mission.id
        assert fleet.vehicle("cf6").busy
        with pytest.raises(VehicleBusy):
            fleet.run_mission("town", {"cf6": ("EP10", "EP5")})
        with pytest.raises(CommandRefused, match="cf8: is not in the air"):  # land: only after a takeoff
            fleet.land("cf8")
        with pytest.raises(CommandRefused, match="take off first"):  # a point in the air: only while it hovers
            fleet.go_to("cf8", (2.7, 1.3, 0.4))
        result = mission.abort("the test aborts")
        assert not result.ok and not result.vehicles["cf6"].arrived
        kinds = [e.kind for e in events]
        for kind in ("planned", "started", "mode", "progress", "aborted", "ended"):
            assert kind in kinds, f"no {kind!r} event: {kinds}"
        assert fleet.vehicle("cf6").mode in ("done", "parked", "holding")  # came to rest
        assert not fleet.vehicle("cf6").busy
    assert service_warnings(run_dir / "logs").count("ERROR") == 0, service_warnings(run_dir / "logs")


def run_example(name: str, *args: str, env: dict[str, str] | None = None, timeout: float = 150) -> str:
    proc = subprocess.run([sys.executable, f"examples/{name}", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **(env or {})})
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


@pytest.mark.timeout(300)
def test_the_examples_plan_fly_one_vehicle_run_a_mission_and_read_its_recording(fleet_up, tmp_path: Path) -> None:
    run_dir, env = fleet_up
    out = run_example("plan_and_plot.py", "--out", str(tmp_path / "plan.png"), env=env)
    assert "sipp on town: 8 vehicles" in out and (tmp_path / "plan.png").stat().st_size > 20_000

    # take off from WP9, the first point of the eight in the air, land on WP9; while
    # the script's mission owns cf7, another client's take-off, go-to and land are refused
    script = subprocess.Popen([sys.executable, "examples/figure_eight.py", "--vehicle", "cf7", "--legs", "1"], cwd=REPO,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env={**os.environ, **env})
    try:
        with Fleet.connect(env["FLEET_ZENOH_CONNECT"], "apitest", secrets=run_dir / "secrets") as fleet:
            deadline = time.monotonic() + 60.0
            while not ((cf7 := fleet.vehicles(["cf7"])["cf7"]).mode == "flying" and cf7.busy):
                assert time.monotonic() < deadline and script.poll() is None, f"cf7 did not take off: {cf7}"
                time.sleep(0.2)
            for command in (lambda: fleet.takeoff("cf7"), lambda: fleet.go_to("cf7", (1.8, 1.05, 0.4)),
                            lambda: fleet.land("cf7")):
                with pytest.raises(VehicleBusy) as busy:
                    command()
                assert busy.value.vehicle == "cf7" and busy.value.mission == cf7.mission
        out, _ = script.communicate(timeout=120)
    finally:
        if script.poll() is None:
            script.kill()
    assert script.returncode == 0 and "took off: hovering at " in out, out
    legs = re.findall(r"-> \(([\d.]+), ([\d.]+)\): at \(([\d.]+), ([\d.]+), ([\d.]+)\)", out)
    assert len(legs) == 1, out
    for px, py, x, y, z in (map(float, leg) for leg in legs):
        assert math.dist((px, py, 0.4), (x, y, z)) < 0.1, out  # the eight's points are air nodes of the corridor
    landed = re.search(r"landed at \(([\d.]+), ([\d.]+)\)", out)
    assert landed and math.dist(tuple(map(float, landed.groups())), (1.67, 0.55)) < 0.05, out  # back on WP9

    with Fleet.connect(env["FLEET_ZENOH_CONNECT"], "apitest", secrets=run_dir / "secrets") as fleet:
        cf4 = fleet.vehicles(["cf4"], timeout=30)["cf4"]
        if math.dist((cf4.x, cf4.y), EP1) > 0.05:  # a rerun after an attempt that moved it: back to its start
            assert fleet.run_mission("town", {"cf4": "EP1"}).ok
    # the example with a scenario of its own: cf4 to the next spot along its road (7 s; the town
    # mission's flights over the gap are flown by tests/test_fleet_up.py, 28 s for cf4's alone)
    short = tmp_path / "short.yaml"
    short.write_text(yaml.safe_dump({"map": "town", "tasks": {"cf4": {"start": "EP1", "goal": "EP2"}}}))
    out = run_example("town_mission.py", "--scenario", str(short), "--only", "cf4", env=env)
    assert "OK (every vehicle arrived)" in out and "contacts: 0" in out, out
    recording = max((run_dir / "recordings").glob("*.rrd"), key=lambda p: p.stat().st_mtime)
    out = run_example("read_recording.py", str(recording))
    # the recorder keeps a mission's file open (buffered) until the next mission: the file of the
    # mission just flown is read whole by tests/test_live_view.py after its demo ended; here the
    # example must read an open file without failing
    assert f"{recording}: " in out and " vehicles" in out, out


@pytest.mark.timeout(200)
def test_the_team_example_runs_a_ground_air_mission(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("FLEET_")}
    proc = subprocess.run([sys.executable, str(REPO / "examples" / "team_mission.py")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=180, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "team plan:" in proc.stdout and "team mission" in proc.stdout and ": OK (" in proc.stdout, proc.stdout


@pytest.mark.timeout(200)
def test_the_lifelong_example_keeps_giving_random_tasks(tmp_path: Path) -> None:
    """On a fleet of its own with two vehicles (the town fleet's parked vehicles would sit on free spots);
    seed 38 draws cf2 a random goal near its first (seed 0: across its region, a 30 s drive)."""
    radios = yaml.safe_load((REPO / "deploy" / "radios-town.yaml").read_text())
    radios["radios"] = {"radio0": radios["radios"]["radio0"]}  # cf1 on WP1, cf2 on WP5
    for vehicle in radios["radios"]["radio0"]["vehicles"].values():  # not the ports of this module's fleet
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as free:
            free.bind(("127.0.0.1", 0))
            vehicle["uri"] = f"udp://${{SIM_HOST:-sim}}:{free.getsockname()[1]}"
    (tmp_path / "radios.yaml").write_text(yaml.safe_dump(radios))
    env = {k: v for k, v in os.environ.items() if not k.startswith("FLEET_")}
    proc = subprocess.run([sys.executable, str(REPO / "examples" / "lifelong.py"), "--minutes", "0.15", "--seed", "38",
                           "--radios", str(tmp_path / "radios.yaml")],
                          cwd=tmp_path, capture_output=True, text=True, timeout=180, env=env)
    out = proc.stdout
    assert proc.returncode == 0, out[-3000:] + proc.stderr[-3000:]
    assert "sent cf1 home to WP1" in out or "redirect refused: cf1: " in out, out
    done = int(out.split(" tasks done in ")[0].rsplit("\n", 1)[-1])
    assert done >= 4, out  # the first two goals, cf1's home or random goals
    assert "minute 1: " in out and "OK (every vehicle arrived)" in out and "contacts: 0" in out, out
