"""`fleet compose lab`: a compose file for real vehicles, written from a lab's radios file and mocap file.

    fleet compose lab --radios deploy/radios-lab.yaml --mocap deploy/mocap-vicon.yaml --out compose.lab.yaml

The file has the router (`fleet router` from our image), the planner, the executors, **one gateway per
radio of the radios file** (`gateway-<radio>`; a lab with N Crazyradios gets N gateways), the
motion-capture bridge with the mocap file, and the telemetry recorder; no simulator. Compared with
compose.yaml:

- each gateway whose radio has `radio://` vehicles gets the host's USB bus (`devices:
  /dev/bus/usb`). Every gateway sees every dongle, so each radio must name its own: by serial number,
  `radio://<serial>/<channel>/<rate>/<address>`, which cflib (0.1.34, `RadioDriver.parse_uri`) looks up
  among the Crazyradios it finds; `radio://<n>/...` (n < 10 digits) is the n-th dongle in USB
  enumeration order, which can change when dongles are replugged or the host reboots. Two radios on
  one dongle are an error; index URIs with several dongles a warning. A container gets the device
  nodes present when it starts: after replugging a dongle, restart its gateway;
- the radios and mocap files stay on the host: their directories are mounted read-only at the same
  path under /app (the image's working directory), so the same relative path works in a container
  and under `fleet up`; edit them and restart, nothing to rebuild;
- the mocap bridge runs on the host's network for the systems whose protocol needs it
  (`HOST_NETWORK`: OptiTrack's NatNet multicast, Qualisys' UDP stream, VRPN's connection back to the
  client) and reaches the router through the host's published port; Vicon's DataStream (a TCP client)
  and the library's mock stay on the compose network.

Checked when writing: the radios file as `fleet gateway` checks it; the mocap file's backend is a real
system (or the mock), and every vehicle of the radios file has a rigid body in its `bodies` (a mapped
vehicle that is not in the radios file is a warning). The mocap file is read leniently here (backend
and bodies); `fleet mocap` checks all of it when it starts.
"""

from __future__ import annotations

import os
from pathlib import Path, PurePosixPath
from urllib.parse import urlparse

import msgspec
import yaml

from common.deploy.radios import RadiosFile, load_radios
from common.domain.mapfile import decode_yaml, read_text
from common.errors import InputError

HOST_NETWORK = {
    "optitrack": "NatNet streams frames by UDP multicast (Motive's default) or unicast to the client's port",
    "qualisys": "QTM streams frames by UDP to the client's port 6734",
    "vrpn": "a VRPN server connects back to the client (a TCP connection it opens to the client's address)",
}
"""Motion-capture backends whose protocol does not pass a compose network's NAT: host networking."""

BRIDGE_NETWORK = ("vicon", "mock")
"""Backends that work from the compose network (a TCP client; the library's mock)."""

ROLES = ("planner", "executor", "gateway", "mocap", "telemetry")


class _MocapHead(msgspec.Struct):
    """What the deployment needs of a mocap file (the rest is `fleet mocap`'s to check)."""

    backend: str = "sim"
    bodies: dict[str, str] = {}


def _relative_dir(path: str, field: str) -> str:
    """The directory of a config file to mount; refused where mounting it would hide the image's code."""
    p = PurePosixPath(path)
    if ".." in p.parts:
        raise InputError(field, path, "give a path inside the repository (no '..') or an absolute one")
    parent = str(p.parent)
    if not p.is_absolute() and parent == ".":
        raise InputError(field, path, "put it in a directory (deploy/, for example): the repository root "
                                      "cannot be mounted over the image's /app")
    return parent


def _dongles(spec: RadiosFile, source: str) -> tuple[dict[str, str], list[str]]:
    """radio name -> the dongle its radio:// vehicles name (radios with only udp:// vehicles have
    none), and warnings. Two radios naming one dongle are an InputError."""
    dongles: dict[str, str] = {}
    owner: dict[str, str] = {}
    for name, radio in spec.radios.items():
        for link in radio.vehicles.values():
            parsed = urlparse(link.uri)
            if parsed.scheme == "radio":
                dongles[name] = parsed.netloc  # check_radios: one dongle per radio
        if name in dongles:
            key = dongles[name].upper()  # cflib compares serials upper-cased
            if key in owner:
                raise InputError(source, f"radios.{name}.vehicles",
                                 f"dongle {dongles[name]} is radio {owner[key]}'s too: every gateway sees every "
                                 "Crazyradio, so each radio needs a dongle of its own (radio://<serial>/...)")
            owner[key] = name
    warnings = []
    by_index = sorted(name for name, d in dongles.items() if len(d) < 10 and d.isdigit())
    if by_index and len(dongles) > 1:
        warnings.append(
            f"{source}: radios {', '.join(by_index)} pick their Crazyradio by USB enumeration index "
            "(radio://<n>/...), which can change when dongles are replugged or the host reboots: name each "
            "by its serial number, radio://<serial>/... (list them: python -c \"from cflib.drivers import "
            "crazyradio; print(crazyradio.get_serials())\")")
    return dongles, warnings


def _check_bodies(spec: RadiosFile, mocap: _MocapHead, radios_path: str, mocap_path: str) -> list[str]:
    if mocap.backend == "sim":
        raise InputError(mocap_path, "backend", "sim is the simulator's motion capture; a lab needs its system's "
                                                "(vicon, optitrack, qualisys, vrpn; mock to try the path)")
    if mocap.backend not in (*HOST_NETWORK, *BRIDGE_NETWORK):
        raise InputError(mocap_path, "backend", f"{mocap.backend!r} is not one of "
                                                f"{', '.join((*BRIDGE_NETWORK, *HOST_NETWORK))}")
    vehicles = {vid for radio in spec.radios.values() for vid in radio.vehicles}
    if not mocap.bodies:
        return []  # each body's name is its vehicle id: nothing to compare before the system runs
    mapped = set(mocap.bodies.values())
    if vehicles - mapped:
        raise InputError(mocap_path, "bodies", f"no rigid body for {', '.join(sorted(vehicles - mapped))} "
                                               f"of {radios_path}: they could not fly")
    extra = sorted(mapped - vehicles)
    return [f"{mocap_path}: bodies: {', '.join(extra)} not in {radios_path} (their poses go unused)"] if extra else []


class _Dumper(yaml.SafeDumper):
    """Block mappings, flow lists of scalars (commands on one line), no anchors."""

    def ignore_aliases(self, data: object) -> bool:
        return True


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(isinstance(item, str | int | float) for item in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def _service(role: str, command: list[str], mounts: list[str], base: str, connect_host: str = "${ROUTER_HOST:-router}",
             **extra: object) -> dict[str, object]:
    service: dict[str, object] = {
        "image": "fleet:latest", "build": base, "restart": "unless-stopped", "command": command,
        "depends_on": ["router"], "volumes": mounts, "secrets": [f"zenoh-{role}"],
        "environment": {
            "FLEET_ZENOH_CONNECT": f"tcp/{connect_host}:${{FLEET_ROUTER_PORT:-7447}}",
            "FLEET_NAME": "${FLEET_NAME:-default}",
            "FLEET_ZENOH_USER": role,
            "FLEET_ZENOH_PASSWORD_FILE": f"${{SECRETS_DIR:-/run/secrets}}/zenoh-{role}",
        },
    }
    service.update(extra)
    return service


def lab_compose(radios_path: str, mocap_path: str, out: str | None = None, executors: int = 2,
                name: str = "fleet-lab") -> tuple[str, list[str]]:
    """The compose file (YAML text) for `radios_path` and `mocap_path` (paths as the services will
    see them: relative to the repository root, or absolute), to be written at `out` (None: the
    repository root; compose paths are relative to the file's directory), and warnings."""
    if executors < 1:
        raise InputError("--executors", str(executors), "must be at least 1")
    dirs = ["deploy"]
    for path, field in ((radios_path, "--radios"), (mocap_path, "--mocap")):
        d = _relative_dir(path, field)
        if d != "deploy" and not d.startswith("deploy/") and d not in dirs:
            dirs.append(d)
    spec = load_radios(radios_path)
    mocap: _MocapHead = decode_yaml(read_text(Path(mocap_path)), _MocapHead, mocap_path)
    dongles, warnings = _dongles(spec, radios_path)
    warnings += _check_bodies(spec, mocap, radios_path, mocap_path)

    base = os.path.relpath(".", Path(out).parent) if out else "."

    def mount(directory: str) -> str:
        if PurePosixPath(directory).is_absolute():
            return f"{directory}:{directory}:ro"
        return f"{base}/{directory}:/app/{directory}:ro"

    mounts = [mount(d) for d in dirs]

    services: dict[str, object] = {
        "router": {
            "image": "fleet:latest", "build": base, "restart": "unless-stopped",
            "command": ["fleet", "router", "--config", "deploy/router.json5",
                        "--listen", "tcp/${LISTEN_HOST:-0.0.0.0}:${FLEET_ROUTER_PORT:-7447}",
                        "--users", "${SECRETS_DIR:-/run/secrets}/zenoh-users"],
            "ports": ["${FLEET_ROUTER_PORT:-7447}:${FLEET_ROUTER_PORT:-7447}"],
            "volumes": [mount("deploy")], "secrets": ["zenoh-users"],
        },
        "planner": _service("planner", ["fleet", "planner"], mounts, base),
        "executor": _service("executor", ["fleet", "executor"], mounts, base,
                             deploy={"replicas": f"${{FLEET_EXECUTORS:-{executors}}}"}),
    }
    for radio in spec.radios:
        usb = {"devices": ["/dev/bus/usb:/dev/bus/usb"]} if radio in dongles else {}
        services[f"gateway-{radio}"] = _service(
            "gateway", ["fleet", "gateway", "--config", radios_path, "--radio", radio, "--subscribe-each"],
            mounts, base, **usb)
    if mocap.backend in HOST_NETWORK:
        services["mocap"] = _service("mocap", ["fleet", "mocap", "--config", mocap_path], mounts, base,
                                     connect_host="127.0.0.1", network_mode="host")
    else:
        services["mocap"] = _service("mocap", ["fleet", "mocap", "--config", mocap_path], mounts, base)
    services["telemetry"] = _service("telemetry", ["fleet", "telemetry", "--out", "${FLEET_RECORDINGS:-out/recordings}"],
                                     [*mounts, f"{base}/out:/app/out"], base)
    secrets_dir = "${FLEET_SECRETS:-" + f"{base}/secrets" + "}"
    document = {
        "name": name,
        "services": services,
        "secrets": {f"zenoh-{role}": {"file": f"{secrets_dir}/zenoh-{role}"} for role in ("users", *ROLES)},
    }
    command = f"fleet compose lab --radios {radios_path} --mocap {mocap_path}" + (
        f" --executors {executors}" if executors != 2 else "") + (f" --out {out}" if out else "")
    network = (f"host networking: {HOST_NETWORK[mocap.backend]}" if mocap.backend in HOST_NETWORK
               else "the compose network")
    header = "\n".join([
        f"# Written by `{command}`",
        "# (common/deploy/lab.py); write it again when the radios of the radios file change.",
        f"# Real vehicles: one gateway per radio of {radios_path} ({', '.join(spec.radios)}) with the",
        "# Crazyradios passed through (each radio names its dongle by serial number: radio://<serial>/...);",
        f"# motion capture: {mocap.backend} ({mocap_path}) on {network.split(':')[0]}.",
        "# From the repository root: `fleet credentials ./secrets` once, then",
        f"# `docker compose -f {out or 'compose.lab.yaml'} up -d --build` (or `fleet up {out or 'compose.lab.yaml'}`:"
        " local processes).",
        "",
    ])
    body = yaml.dump(document, Dumper=_Dumper, sort_keys=False, width=110)
    return header + body, warnings
