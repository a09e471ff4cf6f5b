"""The radios file: which vehicles each Crazyradio serves, over which link, and how the gateways and
the simulator behave. One file serves `fleet gateway --radio <name>` (one process per radio) and
`fleet sim` (every `udp://` vehicle), so both always agree on URIs and link models.

```yaml
radios:
  r0:
    link: {budget_pps: 500, latency_s: 0.002, loss: 0.01}   # optional, docs/radio.md
    vehicles:
      cf1: {uri: "radio://0/80/2M/E7E7E7E7E1"}
      cf2: {uri: "udp://127.0.0.1:19850", start: [0.5, 0.0, 0.0], yaw: 0.0, control: onboard}
gateway: {tick_hz: 100, stale_s: 0.2}                          # optional, GatewayParams
```

Decoded strictly (`common.domain.mapfile.decode_yaml`); every problem is an `InputError(file, field, problem)`.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import urlparse

import msgspec
import yaml

from common.bus.keys import check_chunk
from common.bus.messages import ControlMode
from common.deploy.compose import interpolate
from common.domain.mapfile import decode_yaml, read_text
from common.domain.vehicle_model import Capabilities
from common.errors import InputError

_Strict = {"frozen": True, "forbid_unknown_fields": True}
URI_SCHEMES = ("radio", "udp")

Positive = Annotated[float, msgspec.Meta(gt=0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0)]


class LinkModel(msgspec.Struct, **_Strict):
    """One Crazyradio's link (defaults and their sources: docs/radio.md).

    budget_pps: radio transactions per second shared by all its vehicles (the gateway schedules
    within it; the simulator enforces it); latency_s: one-way delay; loss: probability that a packet
    is lost after the radio's retries (uplink and downlink alike); max_queue_s: longest a packet
    waits for airtime in the simulated radio before it is dropped; seed: the simulated loss draws.
    Only `budget_pps` matters to a real radio; the others are the simulator's model of it.
    """

    budget_pps: Positive = 500.0
    latency_s: NonNegative = 0.002
    loss: Annotated[float, msgspec.Meta(ge=0, lt=1)] = 0.01
    max_queue_s: Positive = 0.05
    seed: int = 0


class LandingParams(msgspec.Struct, **_Strict):
    """The gateway's safety landing (stale commands while flying).

    hover_s: level hover before the descent; speed: descent speed (m/s, the landing speed of
    `common.domain.vehicle_model.Speeds`); accel: open-loop descent acceleration (m/s^2); touchdown_height: the
    descent's reference ends twice this far below the ground (m), and a vehicle resting this far above its
    reference for rest_s (s) has touched down (the ground, or a helipad): motors off;
    pose_timeout_s: a pose older than this is not trusted (open-loop descent instead);
    blind_height: height assumed for an open-loop descent when no pose was ever seen (m);
    mass: vehicle mass (kg, Table I)."""

    hover_s: NonNegative = 0.5
    speed: Positive = 0.2
    accel: Positive = 1.0
    touchdown_height: Positive = 0.03
    rest_s: Positive = 0.3
    pose_timeout_s: Positive = 0.25
    blind_height: Positive = 1.0
    mass: Positive = 0.041


class GatewayParams(msgspec.Struct, **_Strict):
    """How a gateway schedules its radio (paper 000 §VI-C) and guards its vehicles (docs/radio.md).

    tick_hz: scheduling ticks per second: each flying vehicle gets at most one flight setpoint per
    tick, batched; drive_hz: wheel packets per second through the driving command switch, all
    drivers together, at most one a tick (100: one every tick; it was 50, and eight drivers of a
    radio each got a wheel command 6 times a second, 0.1 s late, and their turns at corners
    chattered: the paper's switch served a slower driving protocol, ours is the app channel, which
    the wheel app reads as packets come, firmware/wheels/src/wheels_app.c); wheel_refresh_s: an unchanged wheel command is resent this often (the wheel
    watchdog stops after 0.5 s); status_hz: wheel-app status requests per vehicle per second (flying
    cars only); log_period_s: the period of the log block the firmware streams (battery, supervisor,
    RSSI); link_timeout_s: no log block for this long means the link is lost; reopen_s, reopen_max_s:
    a lost link is closed and reopened after reopen_s, doubling up to reopen_max_s; level_s: an
    attitude setpoint older than this is resent levelled at the hover thrust; stale_s: a cmd
    older than this is stale; resume_s: a flying vehicle taken over for stale commands goes back to
    its owner once the owner's commands have come for this long, none more than stale_s / 2 after
    the one before (`HandBack`); stop_repeats: how many times a stop (motors off, and zero wheels) and
    a notify-setpoint-stop are sent; settle_period_s, settle_max_s: after a flight, stops go out this
    often while the supervisor reports the vehicle flying (at most twice settle_max_s, or settle_max_s
    while it reports nothing); estop_repeats: an emergency stop is sent this many times, one per tick;
    boot_s: a rebooted vehicle is reopened after this long."""

    tick_hz: Positive = 100.0
    drive_hz: Positive = 100.0
    wheel_refresh_s: Positive = 0.1
    status_hz: Positive = 5.0
    log_period_s: Annotated[float, msgspec.Meta(ge=0.01, le=2.5)] = 0.1
    link_timeout_s: Positive = 1.0
    pause_after_s: Positive = 3.0
    connect_timeout_s: Positive = 10.0
    reopen_s: Positive = 1.0
    reopen_max_s: Positive = 8.0
    level_s: Positive = 0.05
    stale_s: Positive = 0.2
    resume_s: NonNegative = 0.1
    stop_repeats: Annotated[int, msgspec.Meta(ge=1)] = 3
    settle_period_s: Annotated[float, msgspec.Meta(gt=0, lt=0.5)] = 0.1
    settle_max_s: Positive = 3.0
    estop_repeats: Annotated[int, msgspec.Meta(ge=1)] = 10
    boot_s: Positive = 2.0
    landing: LandingParams = LandingParams()
    params: dict[str, float] = {}
    """Firmware parameters every vehicle gets on connect (`group.name: value`, as crazyswarm2's
    crazyflies.yaml); a vehicle's own `params` override them."""


class MocapModel(msgspec.Struct, **_Strict):
    """The simulated motion-capture system's imperfections (`fleet sim`, docs/mocap.md): Gaussian
    position (m) and yaw (rad) noise, the delay from capture to publication (s), and dropouts: each
    body starts one at random `dropout_rate_hz` times per second (Poisson), lasting `dropout_s`."""

    pos_std: NonNegative = 0.001
    yaw_std: NonNegative = 0.0087
    latency_s: NonNegative = 0.006
    dropout_rate_hz: NonNegative = 0.0
    dropout_s: NonNegative = 0.2
    seed: int = 0


FirmwarePlatform = Literal["cf21", "cf21-brushless"]
ONBOARD_PARAMS: dict[str, float] = {"stabilizer.estimator": 2, "stabilizer.controller": 2}
"""Onboard control mode's firmware parameters, as crazyswarm2's crazyflies.yaml `firmware_params`:
the Kalman estimator (which fuses external pose) and the Mellinger controller (which follows the
full-state setpoint's velocity and acceleration; the PID's position loop ignores them)."""


class VehicleLink(msgspec.Struct, **_Strict):
    """One vehicle: its cflib link URI; what it can do (`capabilities`: a flying car has the wheel app,
    docs/wheel_protocol.md; "fly" is a stock Crazyflie); how it flies (`control`: `offboard`, the
    executor's LQR sends attitude and thrust, paper 000; `onboard`, the gateway streams its motion
    capture to the vehicle's Kalman estimator and the executor sends full-state setpoints to its own
    controller, with `ONBOARD_PARAMS` written first); parameters written on connect, over the file's
    `gateway.params`; for the simulator, which Crazyflie it is, where it starts (m) and its yaw (rad)."""

    uri: str
    capabilities: Capabilities = "fly+drive"
    control: ControlMode = "offboard"
    params: dict[str, float] = {}
    firmware: FirmwarePlatform = "cf21"
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw: float = 0.0

    @property
    def wheels(self) -> bool:
        """The vehicle has the wheel app (it drives)."""
        return "drive" in self.capabilities

    @property
    def flies(self) -> bool:
        return "fly" in self.capabilities

    @property
    def onboard(self) -> bool:
        """Onboard control mode: motion capture streamed to the vehicle, position setpoints."""
        return self.control == "onboard"

    def firmware_params(self, common: Mapping[str, float], mass: float) -> dict[str, float]:
        """The parameters written on connect: `common` (the file's `gateway.params`), then for
        onboard control `ONBOARD_PARAMS` and `ctrlMel.mass` = `mass`, then the vehicle's own."""
        onboard = {**ONBOARD_PARAMS, "ctrlMel.mass": mass} if self.onboard else {}
        return {**common, **onboard, **self.params}


class RadioSpec(msgspec.Struct, **_Strict):
    vehicles: dict[str, VehicleLink]
    link: LinkModel = LinkModel()


class RadiosFile(msgspec.Struct, **_Strict):
    radios: dict[str, RadioSpec]
    gateway: GatewayParams = GatewayParams()
    mocap: MocapModel = MocapModel()
    """The simulated motion capture of the simulated vehicles (ignored by real ones)."""


def udp_address(uri: str) -> tuple[str, int]:
    """(host, port) of a ``udp://host:port`` URI (ValueError otherwise)."""
    parsed = urlparse(uri)
    if parsed.scheme != "udp" or not parsed.hostname or parsed.port is None:
        raise ValueError(f"{uri!r} is not udp://<host>:<port>")
    return parsed.hostname, parsed.port


def _dongle(uri: str) -> str:
    """The Crazyradio a ``radio://<dongle>/<channel>/<rate>/<address>`` URI uses."""
    parsed = urlparse(uri)
    if not parsed.netloc or not parsed.path.strip("/"):
        raise ValueError(f"{uri!r} is not radio://<dongle>/<channel>[/<rate>[/<address>]]")
    return parsed.netloc


def check_radios(spec: RadiosFile, source: str) -> None:
    """Names are key chunks, URIs are radio:// or udp://, no vehicle or UDP port twice, and one
    radio's radio:// vehicles share one dongle."""
    if not spec.radios:
        raise InputError(source, "radios", "no radio")
    owner: dict[str, str] = {}
    ports: dict[tuple[str, int], str] = {}
    for name, radio in spec.radios.items():
        where = f"radios.{name}"
        try:
            check_chunk(name, "radio name")
        except ValueError as exc:
            raise InputError(source, where, str(exc)) from None
        if not radio.vehicles:
            raise InputError(source, f"{where}.vehicles", "no vehicle")
        dongles: set[str] = set()
        for vid, link in radio.vehicles.items():
            field = f"{where}.vehicles.{vid}"
            try:
                check_chunk(vid, "vehicle id")
                scheme = urlparse(link.uri).scheme
                if scheme not in URI_SCHEMES:
                    raise ValueError(f"URI scheme {scheme!r} is not one of {', '.join(URI_SCHEMES)}")
                if scheme == "udp":
                    addr = udp_address(link.uri)
                    if addr in ports:
                        raise ValueError(f"UDP address {link.uri} already used by {ports[addr]}")
                    ports[addr] = vid
                else:
                    dongles.add(_dongle(link.uri))
            except ValueError as exc:
                raise InputError(source, field, str(exc)) from None
            if vid in owner:
                raise InputError(source, field, f"vehicle already on radio {owner[vid]}")
            if link.onboard and not link.flies:
                raise InputError(source, f"{field}.control", "onboard control needs a vehicle that flies")
            owner[vid] = name
        if len(dongles) > 1:
            raise InputError(source, f"{where}.vehicles", f"radio:// URIs name several dongles {sorted(dongles)}")


def load_radios(path: str | Path) -> RadiosFile:
    """Read and check a radios file. `${VAR:-default}` is taken from the environment as compose does
    (deploy/radios-town.yaml names the simulator's host as ${SIM_HOST:-sim})."""
    path = Path(path)
    text = interpolate(read_text(path), dict(os.environ))
    spec: RadiosFile = decode_yaml(text, RadiosFile, str(path))
    check_radios(spec, str(path))
    return spec


def load_radios_for(path: str | Path, radios: Sequence[str]) -> RadiosFile:
    """`load_radios`, and an InputError (naming `--radio`) for each of `radios` the file lacks."""
    spec = load_radios(path)
    for name in radios:
        if name not in spec.radios:
            raise InputError(str(path), "--radio", f"no radio {name!r} (the file has {', '.join(spec.radios)})")
    return spec


def dump_radios(spec: RadiosFile) -> str:
    """YAML text of `spec` (what `load_radios` reads back)."""
    return yaml.safe_dump(msgspec.to_builtins(spec), sort_keys=False)


def free_udp_ports(n: int, host: str = "127.0.0.1") -> list[int]:
    """`n` distinct UDP ports that were free a moment ago."""
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    try:
        for sock in socks:
            sock.bind((host, 0))
        return [sock.getsockname()[1] for sock in socks]
    finally:
        for sock in socks:
            sock.close()


def simulated_radios(starts: Mapping[str, tuple[float, float, float]], per_radio: int,
                     link: LinkModel | None = None, gateway: GatewayParams | None = None,
                     ports: Sequence[int] | None = None, host: str = "127.0.0.1",
                     yaws: Mapping[str, float] | None = None, prefix: str = "r",
                     control: ControlMode = "offboard") -> RadiosFile:
    """Simulated vehicles (`vid -> start`, facing `yaws[vid]` or +x), `per_radio` to a radio named
    <prefix>0, <prefix>1, ..., on UDP ports `ports` (default: free ones), with the default link model
    and gateway parameters unless given, all in control mode `control`."""
    if per_radio < 1:
        raise ValueError("per_radio must be at least 1")
    vids = list(starts)
    ports = list(ports) if ports is not None else free_udp_ports(len(vids), host)
    if len(ports) < len(vids):
        raise ValueError(f"{len(vids)} vehicles but {len(ports)} ports")
    groups: dict[str, dict[str, VehicleLink]] = {}
    for i, (vid, port) in enumerate(zip(vids, ports, strict=False)):
        groups.setdefault(f"{prefix}{i // per_radio}", {})[vid] = VehicleLink(
            uri=f"udp://{host}:{port}", start=starts[vid], yaw=(yaws or {}).get(vid, 0.0), control=control)
    link = link or LinkModel()
    radios = {name: RadioSpec(vehicles=vehicles, link=link) for name, vehicles in groups.items()}
    spec = RadiosFile(radios=radios, gateway=gateway or GatewayParams())
    check_radios(spec, "simulated_radios")
    return spec
