"""The smallest separation between bodies seen in ground truth during a mission (DESIGN.md:
cylinders of radius r and height h touch when |d_xy| < 2r and |d_z| < h)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from common.bus.messages import SimTruth


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
                t = max(self.latest[vids[i]].t, self.latest[vids[j]].t)
                self.contacts.append((t, vids[i], vids[j], gap))
