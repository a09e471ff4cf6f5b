"""compose.yaml as local processes: parsing, interpolation, replicas, order, errors; up and down.
Every compose file validated against the compose specification's JSON schema (check-jsonschema's
vendored copy), compose.yaml with `sim` dropped as the README says, the lab compose files of
`fleet compose lab` (one gateway per radio, USB, host networking, mounted configuration), the
router's zenoh the services' zenoh."""

from __future__ import annotations

import importlib.metadata
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from common.deploy.compose import Process, interpolate, load_compose
from common.deploy.lab import HOST_NETWORK, lab_compose
from common.deploy.launcher import start, status, stop, wait_ready
from common.deploy.radios import simulated_radios
from common.errors import InputError
from services.cli import main
from services.mission.demo import gateways_for_radios

REPO = Path(__file__).resolve().parents[1]
COMPOSE_FILES = [REPO / "compose.yaml", REPO / "deploy" / "compose.lab.yaml"]
"""Every compose file of the repository."""
MOCAP_EXAMPLES = ["vicon", "optitrack", "qualisys", "vrpn"]


def schema_errors(*paths: Path) -> str:
    """check-jsonschema's verdict on `paths` against its vendored compose-spec schema ('' if valid)."""
    run = subprocess.run([sys.executable, "-m", "check_jsonschema", "--builtin-schema", "vendor.compose-spec",
                          *map(str, paths)], capture_output=True, text=True, timeout=60)
    return "" if run.returncode == 0 else run.stdout + run.stderr


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
    image: eclipse/zenoh:1.10.2
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
    ("services:\n  a: {command: [x], depends_on: {b: {condition: service_started}}}\n", "services.a.depends_on"),
    ("services:\n  a: {command: [x], depends_on: [b]}\n  b: {command: [x], profiles: [p]}\n",
     "services.a.depends_on"),
    ("services:\n  a: {command: [x], secrets: [s]}\n", "services.a.secrets"),
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


def test_both_forms_of_depends_on_and_optional_dependencies_on_inactive_profiles(tmp_path) -> None:
    path = _compose(tmp_path, """
services:
  a: {command: [x], depends_on: {b: {condition: service_started}, c: {condition: service_started, required: false}}}
  b: {command: [x], secrets: [{source: s, target: t}]}
  c: {command: [x], profiles: [extra]}
secrets:
  s: {file: ./s}
""")
    assert [p.service for p in load_compose(path)] == ["b", "a"]  # c's profile is off: a starts without it
    assert [p.service for p in load_compose(path, profiles=["extra"])] == ["b", "c", "a"]


def test_every_compose_file_is_valid_against_the_compose_spec() -> None:
    assert not schema_errors(*COMPOSE_FILES)
    for path in COMPOSE_FILES:
        for profiles in ([], ["team"]):
            assert load_compose(path, profiles=profiles)  # what compose would refuse, `fleet up` refuses


def test_the_validator_is_real(tmp_path) -> None:
    """A file that is valid YAML but not a compose file fails: the schema is applied, not just parsed."""
    bad = _compose(tmp_path, "services:\n  a:\n    image: x\n    devices: /dev/bus/usb\n    networkmode: host\n")
    errors = schema_errors(bad)
    assert "devices" in errors and "networkmode" in errors


def test_dropping_sim_as_the_readme_says_leaves_a_valid_file(tmp_path) -> None:
    """README "On real hardware": compose.yaml's `sim` can be dropped. Remove it as a user would, then
    the file must still be a valid compose file, and `fleet up` must take it: everything but the sim."""
    readme = (REPO / "README.md").read_text()
    section = readme[readme.index("## On real hardware"):readme.index("## Benchmarks")]
    assert "`sim` service can be dropped" in section
    compose = yaml.safe_load((REPO / "compose.yaml").read_text())
    del compose["services"]["sim"]
    dropped = tmp_path / "compose.yaml"
    dropped.write_text(yaml.safe_dump(compose, sort_keys=False))
    assert not schema_errors(dropped)
    with_sim = {p.instance for p in load_compose(REPO / "compose.yaml")}
    assert {p.instance for p in load_compose(dropped)} == with_sim - {"sim"}
    assert main(["up", str(dropped), "--run-dir", str(tmp_path / "run"), "--only", "nothing", "--wait", "0"]) == 0


def test_the_router_runs_the_services_zenoh() -> None:
    """The router is `fleet router` from our image, whose eclipse-zenoh the Dockerfile pins to the one
    installed here (the one the tests run); a zenohd image would have to carry the same version."""
    installed = importlib.metadata.version("eclipse-zenoh")
    pin = re.search(r"^ARG ZENOH_VERSION=(\S+)$", (REPO / "Dockerfile").read_text(), re.M)
    assert pin is not None and pin.group(1) == installed
    for path in COMPOSE_FILES:
        services = yaml.safe_load(path.read_text())["services"]
        assert services["router"]["image"] == "fleet:latest" and services["router"]["command"][:2] == ["fleet", "router"]
        for name, service in services.items():
            image = str(service.get("image", ""))
            if image.startswith("eclipse/zenoh"):
                assert image == f"eclipse/zenoh:{installed}", f"{path}: {name}"


def test_shipped_lab_compose_is_what_the_generator_writes(monkeypatch) -> None:
    monkeypatch.chdir(REPO)
    text, warnings = lab_compose("deploy/radios-lab.yaml", "deploy/mocap-optitrack.yaml", "deploy/compose.lab.yaml")
    assert not warnings
    assert (REPO / "deploy" / "compose.lab.yaml").read_text() == text, (
        "deploy/compose.lab.yaml is stale: fleet compose lab --radios deploy/radios-lab.yaml "
        "--mocap deploy/mocap-optitrack.yaml --out deploy/compose.lab.yaml")


def _mounted(service: dict, base: Path) -> dict[str, Path]:
    """Container path -> host path of a service's bind mounts (relative sources from `base`)."""
    mounts = {}
    for volume in service.get("volumes", []):
        source, target = volume.split(":")[:2]
        mounts[target] = (base / source).resolve()
    return mounts


@pytest.mark.parametrize("system", MOCAP_EXAMPLES)
def test_lab_compose_for_each_system(tmp_path, monkeypatch, system: str) -> None:
    """One gateway per radio with the USB bus, no simulator, the mocap bridge on the host's network where
    its protocol needs it, configuration mounted (not baked) where the commands read it; schema-valid
    and taken by `fleet up`."""
    monkeypatch.chdir(REPO)
    out = tmp_path / "compose.lab.yaml"
    text, warnings = lab_compose("deploy/radios-lab.yaml", f"deploy/mocap-{system}.yaml", None)
    assert not warnings
    out.write_text(text)
    assert not schema_errors(out)
    services = yaml.safe_load(text)["services"]
    radios = yaml.safe_load((REPO / "deploy" / "radios-lab.yaml").read_text())["radios"]
    assert sorted(n for n in services if n.startswith("gateway-")) == sorted(f"gateway-{r}" for r in radios)
    assert "sim" not in services and not any("SIM_HOST" in str(s) for s in services.values())
    for name, service in services.items():
        assert service.get("depends_on", ["router"]) == ["router"], name
        if name.startswith("gateway-"):
            assert service["devices"] == ["/dev/bus/usb:/dev/bus/usb"]
        mounts = _mounted(service, REPO)  # written for the repository root
        command = service["command"]
        for flag in ("--config",):
            if flag in command:  # the file the service reads is on the host, under a mounted directory
                read = PurePosix(command[command.index(flag) + 1])
                target = next(t for t in mounts if read.startswith(t.removeprefix("/app/") + "/"))
                assert (mounts[target] / read.split("/", 1)[1]).is_file(), (name, read)
    mocap = services["mocap"]
    assert mocap["command"] == ["fleet", "mocap", "--config", f"deploy/mocap-{system}.yaml"]
    if system in HOST_NETWORK:
        assert mocap["network_mode"] == "host"
        assert mocap["environment"]["FLEET_ZENOH_CONNECT"].startswith("tcp/127.0.0.1:")
    else:
        assert "network_mode" not in mocap
    processes = load_compose(out)
    assert [p.instance for p in processes] == [
        "router", "planner", "executor-1", "executor-2", *(f"gateway-{r}" for r in radios), "mocap", "telemetry"]


def PurePosix(path: str) -> str:  # noqa: N802 - a path as compose and the services see it
    return path.replace("\\", "/")


def test_lab_compose_written_elsewhere_keeps_its_paths(tmp_path, monkeypatch) -> None:
    """Compose paths are relative to the compose file's directory; the services' paths to the repository
    root (the image's /app). A config directory outside deploy/ is mounted too; an absolute one at its path."""
    monkeypatch.chdir(REPO)
    text, _ = lab_compose("deploy/radios-lab.yaml", "deploy/mocap-vicon.yaml", "deploy/compose.lab.yaml")
    router = yaml.safe_load(text)["services"]["router"]
    assert router["build"] == ".." and router["volumes"] == ["../deploy:/app/deploy:ro"]
    lab = tmp_path / "lab"
    lab.mkdir()
    (lab / "radios.yaml").write_text((REPO / "deploy" / "radios-lab.yaml").read_text())
    text, _ = lab_compose(str(lab / "radios.yaml"), "deploy/mocap-vicon.yaml")
    gateway = yaml.safe_load(text)["services"]["gateway-radio0"]
    assert gateway["volumes"] == ["./deploy:/app/deploy:ro", f"{lab}:{lab}:ro"]
    assert gateway["command"][3] == str(lab / "radios.yaml")


def _radios(tmp_path, body: str) -> str:
    path = tmp_path / "cfg" / "radios.yaml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(body)
    return str(path)


def _mocap(tmp_path, body: str) -> str:
    path = tmp_path / "cfg" / "mocap.yaml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(body)
    return str(path)


def test_lab_compose_refuses_what_could_not_fly(tmp_path, capsys) -> None:
    two = "radios:\n  a: {vehicles: {cf1: {uri: 'radio://%s/80/2M/E7E7E7E701'}}}\n  b: {vehicles: {cf2: {uri: 'radio://%s/80/2M/E7E7E7E702'}}}\n"
    vicon = _mocap(tmp_path, "backend: vicon\nbodies: {b1: cf1, b2: cf2}\n")
    with pytest.raises(InputError) as err:  # one dongle for two gateways: serials compared as cflib does
        lab_compose(_radios(tmp_path, two % ("ABCDEF0123", "abcdef0123")), vicon)
    assert err.value.field == "radios.b.vehicles" and "radio a's too" in err.value.problem
    _, warnings = lab_compose(_radios(tmp_path, two % ("0", "1")), vicon)  # by index: works, until replugged
    assert len(warnings) == 1 and "enumeration index" in warnings[0] and "get_serials" in warnings[0]
    radios = _radios(tmp_path, two % ("ABCDEF0123", "ABCDEF0124"))
    for body, field in [("backend: sim\n", "backend"), ("backend: kinect\n", "backend"),
                        ("backend: vicon\nbodies: {b1: cf1}\n", "bodies")]:
        with pytest.raises(InputError) as err:
            lab_compose(radios, _mocap(tmp_path, body))
        assert err.value.field == field and err.value.source.endswith("mocap.yaml"), body
    _, warnings = lab_compose(radios, _mocap(tmp_path, "backend: vicon\nbodies: {b1: cf1, b2: cf2, b9: cf9}\n"))
    assert warnings == [f"{tmp_path / 'cfg' / 'mocap.yaml'}: bodies: cf9 not in {radios} (their poses go unused)"]
    udp = _radios(tmp_path, "radios:\n  a: {vehicles: {cf1: {uri: 'udp://10.0.0.9:19850'}}}\n")
    text, _ = lab_compose(udp, _mocap(tmp_path, "backend: mock\n"))
    assert "devices" not in yaml.safe_load(text)["services"]["gateway-a"]  # no dongle, no USB
    (tmp_path / "radios.yaml").write_text(two % ("ABCDEF0123", "ABCDEF0124"))
    with pytest.raises(InputError) as err:
        lab_compose("radios.yaml", vicon)
    assert err.value.source == "--radios"
    assert main(["compose", "lab", "--radios", radios, "--mocap", _mocap(tmp_path, "backend: sim\n")]) == 2
    assert "mocap.yaml: backend: sim is the simulator's" in capsys.readouterr().err


@pytest.mark.parametrize(("radios_each", "processes"), [
    (1, [["radio0"], ["radio1"], ["radio2"], ["radio3"], ["radio4"]]),
    (2, [["radio0", "radio1"], ["radio2", "radio3"], ["radio4"]]),
])
def test_a_local_fleet_runs_a_gateway_process_per_radio_or_per_group_of_radios(
        tmp_path, radios_each: int, processes: list[list[str]]) -> None:
    """compose's gateway replaced by gateway processes for the simulated radios: one per radio, as
    compose runs them, or one per `radios_each` radios (`fleet gateway --radio a --radio b`)."""
    cli = [sys.executable, "-m", "services.cli"]
    procs = [Process("router", "router", [*cli, "router"]),
             Process("gateway", "gateway-1", [*cli, "gateway", "--config", "deploy/radios.yaml", "--radio", "r0"],
                     {"FLEET_NAME": "lab", "FLEET_INSTANCE": "gateway-1"}),
             Process("executor", "executor-1", [*cli, "executor"])]
    radios = simulated_radios({f"cf{i}": (0.5 * i, 0.0, 0.0) for i in range(5)}, per_radio=1, prefix="radio")
    made = gateways_for_radios(procs, tmp_path / "radios.yaml", radios, radios_each)
    gateways = made[1:-1]
    assert [p.instance for p in (made[0], made[-1])] == ["router", "executor-1"]
    assert [[a for a, flag in zip(p.argv[1:], p.argv[:-1], strict=True) if flag == "--radio"] for p in gateways] == processes
    for p, radios_of in zip(gateways, processes, strict=True):
        assert p.instance == p.env["FLEET_INSTANCE"] == "-".join(dict.fromkeys([radios_of[0], radios_of[-1]]))
        assert p.env["FLEET_NAME"] == "lab" and p.argv[3:6] == ["gateway", "--config", str(tmp_path / "radios.yaml")]
