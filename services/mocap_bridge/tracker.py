"""Rigid bodies seen by a motion-capture backend -> vehicle poses and lost / found events.

Backend-agnostic: a backend reports frames (capture time, the bodies it sees); the tracker maps
body names to vehicle ids, limits each vehicle to `rate_hz` poses per second, numbers them, and
reports a body unseen for `lost_after_s` as lost (`mocap_lost`), once, publishing nothing for it
until it is seen again (`mocap_found`): a vanished body is never frozen at its last pose. A
configured body counts from the system's first frame (connecting may take a while).
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

from common.bus.keys import check_chunk
from common.bus.messages import Pose

log = logging.getLogger(__name__)

BodyPose = tuple[float, float, float, float]
"""x, y, z (m), yaw (rad, CCW from +x)."""
Event = tuple[str, str, str]
"""(vid, kind, detail)."""

_RATE_TOLERANCE = 0.25
"""A frame up to this fraction of a period early still counts as the next one (clock jitter)."""


def yaw_of(w: float, x: float, y: float, z: float) -> float:
    """Yaw (rotation about +z, ZYX convention) of a unit quaternion."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class BodyTracker:
    """`bodies` maps rigid-body names to vehicle ids; empty means each body is the vehicle of its name."""

    def __init__(self, bodies: Mapping[str, str], rate_hz: float, lost_after_s: float, source: str = "mocap") -> None:
        self.bodies = dict(bodies)
        self.period = 1.0 / rate_hz
        self.lost_after_s = lost_after_s
        self.source = source
        self.seq: dict[str, int] = {}
        self.ignored: dict[str, int] = {}
        self._due: dict[str, float] = {}
        self._seen: dict[str, float] = {}
        self._lost: set[str] = set()
        self.frames = 0
        self.found: set[str] = set()
        """Rigid bodies of ours seen at least once (with a finite pose)."""

    def vid_of(self, body: str) -> str | None:
        """The vehicle of `body`, or None (counted in `ignored`, logged once) if it is not one of ours."""
        vid = self.bodies.get(body) if self.bodies else body
        if vid is not None and not self.bodies:
            try:
                check_chunk(vid, "vehicle id")
            except ValueError:
                vid = None
        if vid is None:
            self.ignored[body] = self.ignored.get(body, 0) + 1
            if self.ignored[body] == 1:
                log.info("mocap: rigid body %r is not mapped to a vehicle: ignored", body)
        return vid

    def frame(self, t: float, seen: Mapping[str, BodyPose], now: float) -> tuple[list[Pose], list[Event]]:
        """Poses to publish and events for a frame captured at `t`, arriving at `now`."""
        poses: list[Pose] = []
        events: list[Event] = []
        if not self._seen:  # the system runs: a configured body must show up from now on
            self._seen = dict.fromkeys(self.bodies.values(), now)
        self.frames += 1
        for body, (x, y, z, yaw) in seen.items():
            vid = self.vid_of(body)
            if vid is None or not all(math.isfinite(v) for v in (x, y, z, yaw)):
                continue  # an occluded body some systems report as NaN: not seen
            self._seen[vid] = now
            self.found.add(body)
            if vid in self._lost:
                self._lost.discard(vid)
                events.append((vid, "mocap_found", f"rigid body {body} visible again"))
            due = self._due.get(vid, -math.inf)
            if t < due - _RATE_TOLERANCE * self.period:
                continue
            self._due[vid] = max(due + self.period, t)
            self.seq[vid] = self.seq.get(vid, 0) + 1
            poses.append(Pose(vid=vid, t=t, x=x, y=y, z=z, yaw=yaw, seq=self.seq[vid], source=self.source))
        return poses, events

    def check(self, now: float) -> list[Event]:
        """`mocap_lost` for every vehicle unseen for `lost_after_s` (once until it is seen again)."""
        events: list[Event] = []
        for vid, at in self._seen.items():
            if vid not in self._lost and now - at > self.lost_after_s:
                self._lost.add(vid)
                events.append((vid, "mocap_lost", f"not seen for {now - at:.2f} s: no poses until it is back"))
        return events

    def all_found(self) -> bool:
        """Every mapped body seen at least once (never true without a mapping: nothing to expect)."""
        return bool(self.bodies) and self.found.issuperset(self.bodies)

    def startup_report(self) -> StartupReport:
        """Which mapped bodies were never seen, and which bodies were seen but are not ours."""
        missing = {body: vid for body, vid in self.bodies.items() if body not in self.found}
        return StartupReport(self.frames, missing, sorted(self.ignored), sorted(self.found), bool(self.bodies))


def _plain(name: str) -> str:
    """A body name without case, punctuation or leading zeros: `CF_07` and `cf7` are alike."""
    return re.sub(r"(?<!\d)0+(?=\d)", "", re.sub(r"[^a-z0-9]", "", name.lower()))


@dataclass(frozen=True)
class StartupReport:
    """The rigid bodies after the bridge's start-up wait: `missing` maps each mapped body never seen
    to its vehicle; `unmapped` the bodies seen that are not ours; `found` ours that were seen."""

    frames: int
    missing: dict[str, str]
    unmapped: list[str]
    found: list[str]
    mapped: bool = True

    def look_alikes(self) -> dict[str, str]:
        """Missing body -> a seen but unmapped body of nearly the same name (a likely typo)."""
        plain = {_plain(name): name for name in self.unmapped}
        return {body: plain[_plain(body)] for body in self.missing if _plain(body) in plain}

    @property
    def ok(self) -> bool:
        return self.frames > 0 and not self.missing

    def message(self, system: str, wait_s: float) -> str:
        if self.frames == 0:
            if system == "sim":
                return f"no frame from the simulated system within {wait_s:g} s: is `fleet sim` running?"
            return (f"no frame from the {system} system within {wait_s:g} s: is it streaming, and is this host "
                    "on its network (docs/mocap.md, 'Systems')?")
        if not self.mapped:
            return (f"no body mapping: bodies seen as vehicles: {', '.join(self.found) or 'none'}"
                    + (f"; not vehicle ids, ignored: {', '.join(self.unmapped)}" if self.unmapped else ""))
        unmapped = f"; seen but not mapped: {', '.join(self.unmapped)}" if self.unmapped else ""
        if not self.missing:
            return f"every mapped rigid body seen ({len(self.found)}){unmapped}"
        alike = self.look_alikes()
        names = ", ".join(f"{body} (vehicle {vid}" + (f"; did you mean {alike[body]!r}?" if body in alike else "")
                          + ")" for body, vid in sorted(self.missing.items()))
        total = len(self.missing) + len(self.found)
        return f"{len(self.missing)} of {total} mapped rigid bodies not seen within {wait_s:g} s: {names}{unmapped}"
