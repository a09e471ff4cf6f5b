"""The simulated Crazyradio: when (and whether) a packet crosses the link (docs/radio.md).

One `SimRadio` per radio is shared by all its simulated vehicles, as the real dongle is:

- uplink (gateway -> vehicle): each packet takes one transaction slot of ``1 / budget_pps`` s; a
  packet that would wait more than `max_queue_s` for its slot is dropped ("congested"); one that
  gets its slot is lost with probability `loss` (after the radio's retries), else delivered
  `latency_s` after its slot starts. Packets stay in order.
- downlink (vehicle -> gateway): status rides in acknowledgements, so it takes no slot of its own;
  it is lost with probability `loss` and delivered after `latency_s`.
"""

from __future__ import annotations

import random

from common.deploy.radios import LinkModel


class SimRadio:
    """Link model of one radio; times are the caller's clock (s)."""

    def __init__(self, name: str, model: LinkModel) -> None:
        self.name = name
        self.model = model
        self._rng = random.Random(model.seed)
        self._free_at = 0.0
        self.delivered = 0
        self.lost = 0
        self.congested = 0

    def uplink(self, now: float) -> float | None:
        """Delivery time of a packet handed to the radio at `now`, or None if it is dropped."""
        m = self.model
        start = max(now, self._free_at)
        if start - now > m.max_queue_s:
            self.congested += 1
            return None
        self._free_at = start + 1.0 / m.budget_pps
        if self._rng.random() < m.loss:
            self.lost += 1
            return None
        self.delivered += 1
        return start + m.latency_s

    def downlink(self, now: float) -> float | None:
        """Delivery time of a reply sent at `now`, or None if it is lost."""
        if self._rng.random() < self.model.loss:
            self.lost += 1
            return None
        return now + self.model.latency_s
