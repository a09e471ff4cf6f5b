"""The simulated Crazyradio: when (and whether) a packet crosses the link (docs/radio.md).

One `SimRadio` per radio is shared by all its simulated vehicles, as the real dongle is:

- uplink (gateway -> vehicle): each packet takes one transaction slot of ``1 / budget_pps`` s; a
  packet that would wait more than `max_queue_s` for its slot is dropped ("congested"); one that
  gets its slot is lost with probability `loss` (after the radio's retries), else delivered
  `latency_s` after its slot starts. Packets stay in order.
- downlink (vehicle -> gateway): replies ride in acknowledgements, so they take no slot of their
  own; lost with probability `loss`, delivered after `latency_s`.
- request/reply traffic cflib waits for (`endpoint.reliable`) is never lost: over a Crazyradio cflib
  resends it until acknowledged, over UDP it would wait forever.
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

    def uplink(self, now: float, reliable: bool = False) -> float | None:
        """Delivery time of a packet handed to the radio at `now`, or None if it is dropped. A
        `reliable` one (a request cflib waits for) waits for its slot however long and is not lost."""
        m = self.model
        start = max(now, self._free_at)
        if start - now > m.max_queue_s and not reliable:
            self.congested += 1
            return None
        self._free_at = start + 1.0 / m.budget_pps
        if not reliable and self._rng.random() < m.loss:
            self.lost += 1
            return None
        self.delivered += 1
        return start + m.latency_s

    def downlink(self, now: float, reliable: bool = False) -> float | None:
        """Delivery time of a reply sent at `now`, or None if it is lost (never a `reliable` one)."""
        if not reliable and self._rng.random() < self.model.loss:
            self.lost += 1
            return None
        return now + self.model.latency_s
