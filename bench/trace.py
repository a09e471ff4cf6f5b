"""A soak's flight recorder (issue 15): every vehicle's ground truth, state, events and telemetry as
they crossed the bus, and the timeline of a few vehicles around a moment (a contact's, a hold's).

The recorder is a process of its own that keeps the raw payloads with their arrival time and
decodes nothing: decoding the 2000 messages a second of a 32-vehicle fleet in the soak's process
(which runs the router) stalled the fleet before its first take-off. It writes a chunk a second,
so memory stays flat and a killed run keeps what came before.

    python -m bench.trace record FILE [--connect ENDPOINT] [--fleet NAME]   (until stdin closes;
        credentials as every fleet process: FLEET_ZENOH_USER, FLEET_ZENOH_PASSWORD[_FILE])
    python -m bench.trace show FILE --vehicles cf08,cf19 [--at 13:56:47.8] [--before 3] [--after 1] [--every 0.1]

`bench.soak --trace FILE` records its run; `show` reads the moment as a local time of the
recording's day (a soak's `contact: ... at 13:56:47,846` line) or as epoch seconds; without one it
lists the vehicles' events with their times, to choose a moment from. The recorder costs the fleet:
the router forwards every vehicle's ground truth, state and telemetry to it too (a traced 2-minute
32-vehicle soak on the 2-core machine: pose->command p50/p99 36/234 ms, an untraced one the same
hour 24-26/100-105).
"""

from __future__ import annotations

import argparse
import datetime
import struct
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import msgspec
import zenoh

from common.bus.args import add_zenoh_args, keys_from_args, zconfig_from_args
from common.bus.keys import Keys
from common.bus.messages import SimTruth, Telemetry, VehicleEvent, VehicleState
from common.bus.session import ZenohConfig, open_session
from common.errors import InputError

KINDS: dict[str, type] = {"truth": SimTruth, "state": VehicleState, "event": VehicleEvent, "tel": Telemetry}
"""What is recorded, by the short name `show` prints."""
FLUSH_S = 1.0
"""s between the chunks written."""
_LENGTH = struct.Struct("<I")

Row = tuple[float, str, bytes]


def topics(keys: Keys) -> list[str]:
    """The key expressions recorded."""
    return [keys.all_sim_truth, keys.all_vehicles("state"), keys.all_vehicles("event"),
            keys.all_vehicles("telemetry")]


def kind_of(key: str) -> str:
    """The short name of what a key carries (`KINDS`)."""
    if "/sim/truth/" in key:
        return "truth"
    return {"state": "state", "event": "event", "telemetry": "tel"}[key.rsplit("/", 1)[-1]]


class Recorder:
    """Raw payloads of `topics(keys)` to `out`, a length-prefixed msgpack chunk per flush."""

    def __init__(self, config: ZenohConfig, keys: Keys, out: Path) -> None:
        self._rows: list[Row] = []
        self._lock = threading.Lock()
        self.count = 0
        self._file = out.open("wb")
        self._session = open_session(config)
        self._subs = [self._session.declare_subscriber(key, self._on_sample) for key in topics(keys)]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        row = (time.time(), str(sample.key_expr), sample.payload.to_bytes())
        with self._lock:
            self._rows.append(row)

    def flush(self) -> None:
        with self._lock:
            rows, self._rows = self._rows, []
        if rows:
            chunk = msgspec.msgpack.encode(rows)
            self._file.write(_LENGTH.pack(len(chunk)) + chunk)
            self._file.flush()
            self.count += len(rows)

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self._session.close()
        self.flush()
        self._file.close()


def read(path: Path) -> Iterator[Row]:
    """The rows of a recording, in arrival order (a chunk cut short by a killed run ends it)."""
    with path.open("rb") as fh:
        while len(head := fh.read(_LENGTH.size)) == _LENGTH.size:
            chunk = fh.read(_LENGTH.unpack(head)[0])
            try:
                rows = msgspec.msgpack.decode(chunk, type=list[tuple[float, str, bytes]])
            except msgspec.DecodeError:
                return
            yield from rows


def decoded(path: Path, kinds: Iterable[str] = KINDS) -> Iterator[tuple[float, str, Any]]:
    """(arrival time, kind, message) of the recording's rows of `kinds`; an undecodable one is skipped."""
    decoders = {kind: msgspec.msgpack.Decoder(KINDS[kind]) for kind in kinds}
    for t, key, payload in read(path):
        decoder = decoders.get(kind := kind_of(key))
        if decoder is not None:
            try:
                yield t, kind, decoder.decode(payload)
            except msgspec.DecodeError:
                continue


def moment(text: str, day: float) -> float:
    """Epoch seconds of `text`: epoch seconds, or HH:MM:SS[.fff] (a comma too) local time on the day of `day`."""
    try:
        return float(text)
    except ValueError:
        pass
    try:
        h, m, s = text.replace(",", ".").split(":")
        base = datetime.datetime.fromtimestamp(day).replace(hour=int(h), minute=int(m), second=0, microsecond=0)
        return base.timestamp() + float(s)
    except ValueError:
        raise InputError("--at", "", f"{text!r} is neither epoch seconds nor HH:MM:SS[.fff]") from None


def line(dt: float, kind: str, msg: Any, t: float) -> str:
    """One timeline row: seconds from the moment, the vehicle, what it says."""
    head = f"{dt:+7.2f} {msg.vid:>5}"
    if kind == "truth":
        return (f"{head} truth ({msg.x:.3f}, {msg.y:.3f}, {msg.z:.3f}) v ({msg.vx:.2f}, {msg.vy:.2f}, {msg.vz:.2f})"
                f" {'air' if msg.airborne else 'ground'} motors {'on' if msg.motors else 'off'}, {t - msg.t:.2f} s old")
    if kind == "state":
        return (f"{head} state {msg.mode} est ({msg.x:.3f}, {msg.y:.3f}, {msg.z:.3f}) v ({msg.vx:.2f}, {msg.vy:.2f},"
                f" {msg.vz:.2f}) pose {'ok' if msg.pose_ok else 'stale'} error {msg.tracking_error:.3f}")
    if kind == "event":
        return f"{head} event {msg.kind} {msg.detail}" + (f" (node {msg.node})" if msg.node else "")
    return f"{head} telemetry link {'ok' if msg.link_ok else 'LOST'} quality {msg.link_quality:.2f} vbat {msg.vbat:.2f}"


def events(path: Path, vehicles: set[str]) -> list[str]:
    """Every event of `vehicles` in the recording, with its local time of arrival."""
    return [f"{datetime.datetime.fromtimestamp(t).strftime('%H:%M:%S.%f')[:-3]} {msg.vid:>5} {msg.kind} {msg.detail}"
            for t, _kind, msg in decoded(path, ["event"]) if msg.vid in vehicles]


def show(path: Path, vehicles: set[str], at: str, before: float, after: float, every: float) -> list[str]:
    """The timeline of `vehicles` from `before` s before the moment `at` to `after` s after it:
    events at once, truth, states and telemetry at most one per `every` s each (a mode change at once)."""
    out: list[str] = []
    when: float | None = None
    last: dict[tuple[str, str], tuple[float, str]] = {}
    for t, kind, msg in decoded(path):
        when = moment(at, t) if when is None else when
        if t < when - before:
            continue
        if t > when + after:
            break
        if msg.vid not in vehicles:
            continue
        mode = msg.mode if kind == "state" else ""
        seen = last.get((msg.vid, kind))
        if kind != "event" and seen is not None and t - seen[0] < every and seen[1] == mode:
            continue
        last[(msg.vid, kind)] = (t, mode)
        out.append(line(t - when, kind, msg, t))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.trace", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="record until stdin closes")
    rec.add_argument("file", type=Path)
    add_zenoh_args(rec)
    sh = sub.add_parser("show", help="a few vehicles' timeline around a moment")
    sh.add_argument("file", type=Path)
    sh.add_argument("--vehicles", required=True, help="comma-separated vehicle ids")
    sh.add_argument("--at", help="HH:MM:SS[.fff] local time of the recording's day, or epoch s "
                                 "(none: the vehicles' events, with their times)")
    sh.add_argument("--before", type=float, default=3.0)
    sh.add_argument("--after", type=float, default=1.0)
    sh.add_argument("--every", type=float, default=0.1)
    args = ap.parse_args(argv)
    try:
        if args.command == "record":
            recorder = Recorder(zconfig_from_args(args), keys_from_args(args), args.file)
            print(f"recording to {args.file} until stdin closes", flush=True)
            stop = threading.Event()
            threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
            while not stop.wait(FLUSH_S):
                recorder.flush()
            recorder.close()
            print(f"recorded {recorder.count} messages to {args.file}")
            return 0
        if args.at is not None:
            moment(args.at, time.time())  # (checked before the recording is read)
        if not args.file.is_file():
            raise InputError(str(args.file), "", "no such recording")
        vehicles = set(args.vehicles.split(","))
        print("\n".join(events(args.file, vehicles) if args.at is None else
                        show(args.file, vehicles, args.at, args.before, args.after, args.every)))
        return 0
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
