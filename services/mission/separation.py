"""The smallest separation between bodies seen in ground truth during a mission (DESIGN.md:
cylinders of radius r and height h touch when |d_xy| < 2r and |d_z| < h)."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from common.bus.messages import SimTruth, SimTruthFrame

log = logging.getLogger(__name__)

NEAR_M = 1.0
"""m: pairs further apart than this (beyond contact) are not counted in `min_gap`."""
SAME_INSTANT_S = 0.001
"""s: truths this close in time are of one instant (the simulated bodies' clocks add up their
physics steps apart, and differ by rounding)."""


@dataclass
class SeparationMonitor:
    """Feed it every truth (`update`). The bodies are judged at every instant of the truths: when a
    truth of a later time arrives, every pair on the latest truths (the simulator publishes all
    bodies' at one time, 100 times a second from `fleet sim`). (A mission judged them ten times a
    second and missed a brush shorter than that.) `min_gap` is the smallest horizontal distance
    minus 2r over pairs whose heights overlap, within `NEAR_M` (negative means contact); `contacts`
    lists (t, vid, vid, gap) for every instant and pair in contact."""

    radius: float
    height: float
    latest: dict[str, SimTruth] = field(default_factory=dict)
    min_gap: float = float("inf")
    min_pair: tuple[str, str] = ("", "")
    contacts: list[tuple[float, str, str, float]] = field(default_factory=list)
    _instant: float = -float("inf")
    _touched: set[frozenset[str]] = field(default_factory=set)
    _pairs: tuple[np.ndarray, np.ndarray] = (np.zeros(0, int), np.zeros(0, int))

    def update(self, truth: SimTruth) -> None:
        if truth.t > self._instant + SAME_INSTANT_S:
            self._judge()
            self._instant = truth.t
        self.latest[truth.vid] = truth

    def update_frame(self, frame: SimTruthFrame) -> None:
        """Every truth of a simulator's instant (`sim/truths`; several simulators' frames mix as
        their truths would)."""
        for truth in frame.truths:
            self.update(truth)

    def _judge(self) -> None:
        """Every pair of the latest truths."""
        if len(self.latest) < 2:
            return
        truths = list(self.latest.values())
        pos = np.array([(t.x, t.y, t.z) for t in truths])
        if len(self._pairs[0]) != len(truths) * (len(truths) - 1) // 2:
            self._pairs = np.triu_indices(len(truths), 1)
        i, j = self._pairs
        d = pos[i] - pos[j]
        level = np.abs(d[:, 2]) < self.height
        if not level.any():
            return
        i, j = i[level], j[level]
        gaps = np.hypot(d[level, 0], d[level, 1]) - 2.0 * self.radius
        k = int(np.argmin(gaps))
        if gaps[k] < min(self.min_gap, NEAR_M):
            self.min_gap, self.min_pair = float(gaps[k]), (truths[i[k]].vid, truths[j[k]].vid)
        for a, b, gap in zip(i[gaps < 0.0].tolist(), j[gaps < 0.0].tolist(), gaps[gaps < 0.0].tolist(), strict=True):
            ta, tb = truths[a], truths[b]
            pair = frozenset((ta.vid, tb.vid))
            if pair not in self._touched:
                self._touched.add(pair)
                log.warning("contact: %s and %s %.1f cm into each other at %s: %s, %s", ta.vid, tb.vid,
                            -100 * gap, _clock(max(ta.t, tb.t)), _where(ta), _where(tb))
            self.contacts.append((max(ta.t, tb.t), ta.vid, tb.vid, gap))


def _clock(t: float) -> str:
    """A truth's time of day as the services' logs print theirs (local, to the millisecond), to find
    what they did then."""
    return time.strftime("%H:%M:%S", time.localtime(t)) + f",{int(1000 * (t % 1.0)):03d}"


def _where(t: SimTruth) -> str:
    return (f"({t.x:.2f}, {t.y:.2f}, {t.z:.2f}) {'in the air' if t.airborne else 'on the ground'}"
            f"{' motors on' if t.motors else ''} v=({t.vx:.2f}, {t.vy:.2f}, {t.vz:.2f})")
