"""`fleet doctor`: the pre-flight check a lab runs before every session (docs/hardware.md).

It opens a session as the operator and listens for `--timeout` seconds, then prints one line per
check, PASS or FAIL with what was seen, and exits 1 if any failed:

- router: reachable with the configured credentials (FLEET_ZENOH_USER / _PASSWORD_FILE, or
  `--user` / `--password-file`), as a role that may watch the fleet (the operator, `mission`);
- services: the planner, an executor and the mocap bridge alive (tokens `alive/<service>/<instance>`);
- radio <name>, for each radio of the radios file: its gateway alive and publishing telemetry, and
  at least one of its vehicles answering;
- vehicle <vid>: telemetry from its gateway with the link up, the firmware version read, the
  supervisor neither locked, crashed nor tumbled, no emergency stop held, the battery and the link
  quality above `--min-battery` and `--min-link`, a flying car's wheel app answering;
- mocap <vid>: poses arriving in the motion-capture frames (`mocap/frame`, the executors' input,
  at least `--min-pose-rate`) and the body
  within `--position-tolerance` of where it should be parked: its task's start spot in `--scenario`
  (on the scenario's map or `--map`), else its `start` in the radios file for a simulated vehicle,
  else the map's nearest parking spot or helipad (`--map`), else not checked;
- clocks: every service's timestamps (its `stats/...` and a gateway's telemetry) against this
  host's clock: the smallest arrival-minus-stamp per service, within `--clock-tolerance`.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import math
import os
import statistics
import sys
import time
from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from common.bus.args import add_zenoh_args, keys_from_args, zconfig_from_args
from common.bus.keys import Keys
from common.bus.messages import Pose, PoseFrame, ServiceStats, Telemetry
from common.bus.pubsub import subscribe
from common.bus.session import ZenohConfig, open_session
from common.deploy.acl import ROLES
from common.deploy.radios import RadiosFile, load_radios
from common.domain.mapfile import MapSpec, load_map, spot_pose
from common.domain.scenario import read_scenario
from common.errors import InputError

OPERATOR = "mission"
"""The role that may watch everything (common/deploy/acl.py)."""
NEEDED_SERVICES = ("planner", "executor", "mocap")
# supervisor.info bits (crazyflie-firmware supervisor.c; docs/firmware_model.md)
TUMBLED, LOCKED, CRASHED = 1 << 5, 1 << 6, 1 << 7
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Limits:
    """The thresholds of the checks (command-line options)."""

    min_battery_v: float = 3.8
    min_link: float = 0.8
    position_tolerance_m: float = 0.10
    clock_tolerance_s: float = 0.05
    min_pose_hz: float = 30.0
    listen_s: float = 3.0


@dataclass(frozen=True)
class Check:
    ok: bool
    what: str
    detail: str

    def line(self) -> str:
        return f"{'PASS' if self.ok else 'FAIL'}  {self.what:<14} {self.detail}"


@dataclass(frozen=True)
class Parking:
    """Where a body should be at rest, and what says so."""

    pos: Vec3 | None
    source: str
    spots: tuple[tuple[str, Vec3], ...] = ()
    """With no single position: any of these (the map's parking spots and helipads)."""


@dataclass
class Heard:
    """What arrived while the doctor listened, stamped with this host's clock on arrival."""

    started: float = field(default_factory=time.time)
    ended: float = 0.0
    telemetry: dict[str, Telemetry] = field(default_factory=dict)
    poses: dict[str, list[tuple[float, Pose]]] = field(default_factory=lambda: defaultdict(list))
    offsets: dict[str, float] = field(default_factory=dict)
    """source ("<service>/<instance>") -> smallest (arrival - its stamp) seen, s."""
    alive: dict[str, set[str]] = field(default_factory=lambda: defaultdict(set))

    def stamp(self, source: str, t: float) -> None:
        lag = time.time() - t
        self.offsets[source] = min(lag, self.offsets.get(source, math.inf))

    def on_telemetry(self, msg: Telemetry, _key: str) -> None:
        self.telemetry[msg.vid] = msg
        self.stamp(f"gateway/{msg.gateway}", msg.t)

    def on_frame(self, frame: PoseFrame, _key: str) -> None:
        now = time.time()
        for p in frame.poses:
            self.poses[p.vid].append((now, frame.pose(p)))

    def on_stats(self, msg: ServiceStats, _key: str) -> None:
        self.stamp(f"{msg.service}/{msg.instance}", msg.t)


# ---- listening ------------------------------------------------------------------------------------

async def listen(zconfig: ZenohConfig, keys: Keys, listen_s: float) -> tuple[Heard, float]:
    """Open a session, listen `listen_s` s; what was heard and the seconds the session took to open
    (zenoh.ZError if the router refused or could not be reached)."""
    t0 = time.monotonic()
    session = await asyncio.to_thread(open_session, zconfig)
    opened_s = time.monotonic() - t0
    heard = Heard()
    try:
        if not session.info.routers_zid():
            raise zenoh.ZError("connected to no router")

        def on_token(sample: zenoh.Sample) -> None:
            parsed = keys.parse_alive(str(sample.key_expr))
            if parsed is not None:
                (heard.alive[parsed[0]].add if sample.kind == zenoh.SampleKind.PUT
                 else heard.alive[parsed[0]].discard)(parsed[1])

        tokens = session.liveliness().declare_subscriber(keys.all_alive("*"), on_token, history=True)
        subs = [subscribe(session, keys.all_vehicles("telemetry"), Telemetry, heard.on_telemetry),
                subscribe(session, keys.mocap_frame, PoseFrame, heard.on_frame, maxlen=65536),
                # one per service: the router passes a subscription only as narrow as a publisher's grant
                *(subscribe(session, keys.all_stats(role), ServiceStats, heard.on_stats) for role in ROLES)]
        await asyncio.sleep(listen_s)
        heard.ended = time.time()
        for sub in subs:
            sub.close()
        tokens.undeclare()
    finally:
        session.close()
    return heard, opened_s


# ---- checks ------------------------------------------------------------------------------------------

def check_router(zconfig: ZenohConfig, opened_s: float) -> Check:
    where = ",".join(zconfig.connect) or "(scouting)"
    user = zconfig.user or "no user"
    if zconfig.user is not None and zconfig.user != OPERATOR:
        return Check(False, "router", f"{where} reachable as {user!r}, but only the operator role ({OPERATOR!r}) "
                                      "may watch the fleet: FLEET_ZENOH_USER=mission")
    return Check(True, "router", f"{where} reachable as {user!r} (session open in {opened_s:.2f} s)")


def check_services(heard: Heard) -> Check:
    counts = {svc: len(inst) for svc, inst in sorted(heard.alive.items()) if inst}
    missing = [svc for svc in NEEDED_SERVICES if not counts.get(svc)]
    seen = ", ".join(f"{svc} x{n}" for svc, n in counts.items()) or "none"
    if missing:
        return Check(False, "services", f"no {', '.join(missing)} alive (alive: {seen})")
    return Check(True, "services", f"alive: {seen}")


def check_radio(name: str, spec: RadiosFile, heard: Heard) -> Check:
    radio = spec.radios[name]
    vids = list(radio.vehicles)
    gateways = heard.alive.get("gateway", set())
    named = {t.gateway for vid in vids if (t := heard.telemetry.get(vid)) is not None}
    instance = next(iter(sorted(named)), None) or next(
        (g for g in sorted(gateways) if g == name or g.endswith(f"-{name}")), None)
    what = f"radio {name}"
    if instance is None:
        return Check(False, what, f"no gateway alive for it (alive gateways: {', '.join(sorted(gateways)) or 'none'})")
    if instance not in gateways:
        return Check(False, what, f"gateway {instance} sent telemetry but holds no liveliness token")
    told = [vid for vid in vids if vid in heard.telemetry]
    up = [vid for vid in told if heard.telemetry[vid].link_ok]
    links = f"{len(up)}/{len(vids)} links up"
    if not told:
        return Check(False, what, f"gateway {instance} alive but no telemetry from it")
    if not up:
        uri = next(iter(radio.vehicles.values())).uri
        return Check(False, what, f"gateway {instance}: {links}: no vehicle answers ({uri}: dongle plugged in, "
                                  "right serial and channel, vehicles switched on?)")
    return Check(True, what, f"gateway {instance} alive, telemetry for {len(told)}/{len(vids)} vehicles, {links}")


def check_vehicle(vid: str, spec: RadiosFile, heard: Heard, limits: Limits) -> Check:
    what = f"vehicle {vid}"
    t = heard.telemetry.get(vid)
    platform = next(r.vehicles[vid].firmware for r in spec.radios.values() if vid in r.vehicles)
    if t is None:
        return Check(False, what, f"no telemetry within {limits.listen_s:g} s: is its gateway up?")
    numbers = (f"firmware {t.firmware or '?'} ({platform}), supervisor 0x{max(t.supervisor, 0):02x}, "
               f"battery {t.vbat:.2f} V, link {t.link_quality:.2f}")
    problems = []
    if not t.link_ok:
        problems.append("does not answer: link lost (switched off? out of range?)")
    else:
        if not t.firmware:
            problems.append("firmware version not read")
        if t.supervisor < 0:
            problems.append("supervisor state unknown")
        for bit, text in ((LOCKED, "supervisor locked (reboot it)"), (CRASHED, "crashed (crash recovery needed)"),
                          (TUMBLED, "tumbled")):
            if t.supervisor >= 0 and t.supervisor & bit:
                problems.append(text)
        if t.vbat < limits.min_battery_v:
            problems.append(f"battery {t.vbat:.2f} V below {limits.min_battery_v:.2f} V")
        if t.link_quality < limits.min_link:
            problems.append(f"link quality {t.link_quality:.2f} below {limits.min_link:.2f}")
        if "drive" in t.capabilities and not t.wheel_app_ok:
            problems.append("wheel app silent (firmware/wheels flashed?)")
    if t.estopped:
        problems.append("held by the emergency stop (fleet estop --release)")
    if problems:
        return Check(False, what, "; ".join(problems) + f" [{numbers}]")
    return Check(True, what, f"{numbers}, via {t.gateway}")


def check_mocap(vid: str, parking: Parking, heard: Heard, limits: Limits) -> Check:
    what = f"mocap {vid}"
    poses = heard.poses.get(vid, [])
    window = max(heard.ended - heard.started, 1e-6)
    if not poses:
        return Check(False, what, f"body not seen in {window:.1f} s (not in mocap/frame: hidden, or its rigid "
                                  "body not named in the mocap file?)")
    rate = len(poses) / window
    quiet = heard.ended - poses[-1][0]
    if rate < limits.min_pose_hz or quiet > 0.5:
        return Check(False, what, f"{rate:.0f} Hz, the last pose {quiet:.1f} s ago (want {limits.min_pose_hz:g} Hz)")
    recent = [p for _, p in poses[-20:]]
    at = (statistics.median(p.x for p in recent), statistics.median(p.y for p in recent),
          statistics.median(p.z for p in recent))
    where = f"at ({at[0]:.2f}, {at[1]:.2f}, {at[2]:.2f}), {rate:.0f} Hz"
    if parking.pos is None and not parking.spots:
        return Check(True, what, f"{where} (position not checked: give --scenario or --map)")
    candidates = [(parking.source, parking.pos)] if parking.pos is not None else list(parking.spots)
    name, pos = min(candidates, key=lambda c: math.dist(at, c[1]))
    off = math.dist(at, pos)
    detail = f"{where}, {off:.2f} m from {name} ({pos[0]:.2f}, {pos[1]:.2f}, {pos[2]:.2f})"
    if off > limits.position_tolerance_m:
        return Check(False, what, f"{detail}: more than {limits.position_tolerance_m:g} m")
    return Check(True, what, detail)


def check_clocks(heard: Heard, limits: Limits) -> list[Check]:
    if not heard.offsets:
        return [Check(False, "clocks", "no timestamped message from any service")]
    far = {src: off for src, off in heard.offsets.items() if abs(off) > limits.clock_tolerance_s}
    if far:
        return [Check(False, "clocks", f"{src}: {off * 1000:+.0f} ms from this host (arrival minus its stamp; "
                                       f"tolerance {limits.clock_tolerance_s * 1000:.0f} ms): sync its host's clock")
                for src, off in sorted(far.items())]
    worst = max(heard.offsets, key=lambda s: abs(heard.offsets[s]))
    return [Check(True, "clocks", f"{len(heard.offsets)} services within {limits.clock_tolerance_s * 1000:.0f} ms "
                                  f"of this host (worst {worst} {heard.offsets[worst] * 1000:+.0f} ms)")]


# ---- where bodies should be ---------------------------------------------------------------------------

def parking_places(spec: RadiosFile, scenario: str | None, map_name: str | None) -> dict[str, Parking]:
    """Where each vehicle of the radios file should be parked (module docstring's order)."""
    tasks = {}
    mapspec: MapSpec | None = None
    if scenario:
        scen = read_scenario(scenario)
        tasks = dict(scen.tasks)
        if not (map_name or scen.map):
            raise InputError(scenario, "map", "the scenario names no map: give --map")
        mapspec = load_map(map_name or scen.map or "")
    elif map_name:
        mapspec = load_map(map_name)
    spots: tuple[tuple[str, Vec3], ...] = ()
    if mapspec is not None:
        spots = (*((f"spot {p.id}", (p.x, p.y, 0.0)) for p in mapspec.parking),
                 *((f"helipad {h.id}", (h.x, h.y, h.z)) for h in mapspec.helipads))
    places = {}
    for radio in spec.radios.values():
        for vid, link in radio.vehicles.items():
            if vid in tasks and mapspec is not None:
                x, y, z, _yaw = spot_pose(mapspec, tasks[vid].start, scenario or "")
                places[vid] = Parking((x, y, z), f"its start {tasks[vid].start}")
            elif link.uri.startswith("udp://"):
                places[vid] = Parking(link.start, "its start in the radios file")
            else:
                places[vid] = Parking(None, "the map's spots", spots)
    return places


# ---- the command --------------------------------------------------------------------------------------

def run_checks(spec: RadiosFile, places: Mapping[str, Parking], zconfig: ZenohConfig, keys: Keys,
               limits: Limits) -> list[Check]:
    """Every check, in the order printed; only the router's if the router cannot be reached."""
    try:
        heard, opened_s = asyncio.run(listen(zconfig, keys, limits.listen_s))
    except zenoh.ZError as exc:
        where = ",".join(zconfig.connect) or "(scouting)"
        return [Check(False, "router", f"{where} not reachable as {zconfig.user or 'no user'!r}: "
                                       f"{str(exc).split(' at ')[0]}")]
    checks = [check_router(zconfig, opened_s), check_services(heard)]
    checks += [check_radio(name, spec, heard) for name in spec.radios]
    vids = [vid for radio in spec.radios.values() for vid in radio.vehicles]
    checks += [check_vehicle(vid, spec, heard, limits) for vid in vids]
    checks += [check_mocap(vid, places[vid], heard, limits) for vid in vids]
    return checks + check_clocks(heard, limits)


def _limits(args: argparse.Namespace) -> Limits:
    limits = Limits(args.min_battery, args.min_link, args.position_tolerance, args.clock_tolerance,
                    args.min_pose_rate, args.timeout)
    for f in dataclasses.fields(limits):
        value = getattr(limits, f.name)
        if not math.isfinite(value) or value < 0 or (f.name == "listen_s" and value == 0):
            option = {"min_battery_v": "--min-battery", "min_link": "--min-link", "listen_s": "--timeout",
                      "position_tolerance_m": "--position-tolerance", "clock_tolerance_s": "--clock-tolerance",
                      "min_pose_hz": "--min-pose-rate"}[f.name]
            raise InputError(option, "", f"{value:g}: must be {'positive' if f.name == 'listen_s' else 'non-negative'}")
    return limits


def _zconfig(args: argparse.Namespace) -> ZenohConfig:
    zconfig = zconfig_from_args(args)
    if args.user is not None or args.password_file is not None:
        if args.user is None or args.password_file is None:
            raise InputError("--user/--password-file", "", "give both, or neither (then FLEET_ZENOH_USER ...)")
        try:
            password = Path(args.password_file).read_text().strip()
        except OSError as exc:
            raise InputError(args.password_file, "--password-file", f"cannot read ({exc.strerror})") from None
        zconfig = dataclasses.replace(zconfig, user=args.user, password=password)
    return zconfig


def cmd_doctor(args: argparse.Namespace) -> int:
    limits = _limits(args)
    spec = load_radios(args.radios)
    places = parking_places(spec, args.scenario, args.map)
    checks = run_checks(spec, places, _zconfig(args), keys_from_args(args), limits)
    for check in checks:
        print(check.line())
    failed = sum(not c.ok for c in checks)
    print(f"doctor: {len(checks) - failed} passed, {failed} failed" + ("" if failed else ": ready to fly"))
    sys.stdout.flush()
    return 1 if failed else 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("doctor", help="pre-flight check: router, gateways, vehicles, motion capture, clocks "
                                      "(one line each; exit 1 on any failure)")
    p.add_argument("--radios", default=os.environ.get("FLEET_RADIOS", "deploy/radios-town.yaml"),
                   help="the radios file (env FLEET_RADIOS; default deploy/radios-town.yaml)")
    p.add_argument("--scenario", help="where each vehicle should be parked: its task's start spot")
    p.add_argument("--map", help="the scenario's map (default: the scenario's `map`); without --scenario, "
                                 "real vehicles should stand on one of its parking spots or helipads")
    p.add_argument("--user", help="zenoh user (default env FLEET_ZENOH_USER; the operator is 'mission')")
    p.add_argument("--password-file", help="its password file (default env FLEET_ZENOH_PASSWORD_FILE)")
    d = Limits()
    p.add_argument("--min-battery", type=float, default=d.min_battery_v, metavar="V", help="lowest battery voltage")
    p.add_argument("--min-link", type=float, default=d.min_link, metavar="Q",
                   help="lowest link quality (fraction of log blocks that arrived)")
    p.add_argument("--position-tolerance", type=float, default=d.position_tolerance_m, metavar="M",
                   help="largest distance of a body from where it should be parked")
    p.add_argument("--clock-tolerance", type=float, default=d.clock_tolerance_s, metavar="S",
                   help="largest clock offset of a service from this host")
    p.add_argument("--min-pose-rate", type=float, default=d.min_pose_hz, metavar="HZ", help="lowest pose rate per body")
    p.add_argument("--timeout", type=float, default=d.listen_s, metavar="S",
                   help="how long to listen (services publish their stats every 2 s)")
    add_zenoh_args(p, default_instance="doctor")
    p.set_defaults(handler=cmd_doctor)
