"""The smallest separation between bodies seen in ground truth during a mission (DESIGN.md:
cylinders of radius r and height h touch when |d_xy| < 2r and |d_z| < h)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from common.bus.messages import SimTruth

log = logging.getLogger(__name__)


@dataclass
class SeparationMonitor:
    """Feed truths, call `sample()` periodically. `min_gap` is the smallest horizontal distance
    minus 2r over pairs whose heights overlap (negative means contact); `contacts` lists them."""

    radius: float
    height: float
    latest: dict[str, SimTruth] = field(default_factory=dict)
    min_gap: float = float("inf")
    min_pair: tuple[str, str] = ("", "")
    contacts: list[tuple[float, str, str, float]] = field(default_factory=list)

    def update(self, truth: SimTruth) -> None:
        self.latest[truth.vid] = truth

    def sample(self) -> None:
        if len(self.latest) < 2:
            return
        vids = list(self.latest)
        pos = np.array([(t.x, t.y, t.z) for t in self.latest.values()])
        reach = float(np.hypot(2 * self.radius + 1.0, self.height))
        for i, j in cKDTree(pos).query_pairs(reach):
            d = pos[i] - pos[j]
            if abs(d[2]) >= self.height:
                continue
            gap = float(np.hypot(d[0], d[1])) - 2 * self.radius
            if gap < self.min_gap:
                self.min_gap, self.min_pair = gap, (vids[i], vids[j])
            if gap < 0:
                a, b = self.latest[vids[i]], self.latest[vids[j]]
                t = max(a.t, b.t)
                if not any({c[1], c[2]} == {a.vid, b.vid} for c in self.contacts):
                    log.warning("contact: %s and %s %.1f cm into each other at %s, %s", a.vid, b.vid, -100 * gap,
                                _where(a), _where(b))
                self.contacts.append((t, vids[i], vids[j], gap))


def _where(t: SimTruth) -> str:
    return (f"({t.x:.2f}, {t.y:.2f}, {t.z:.2f}) {'in the air' if t.airborne else 'on the ground'}"
            f"{' motors on' if t.motors else ''} v=({t.vx:.2f}, {t.vy:.2f}, {t.vz:.2f})")
