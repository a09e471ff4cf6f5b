"""Every service's health on the bus: its counters and figures on `stats/<service>/<instance>`.

A service spawns `publish_stats` in its `main()`; the soak (bench/soak.py) and operators subscribe to
`stats/**` to see dropped messages, refusals and service-specific figures (the executor's missed
control deadlines and pose-to-command latency, ...) without reading logs::

    self.spawn(publish_stats(self, self._figures), name="stats")
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Collection

import numpy as np

from common.bus.messages import ServiceStats
from common.bus.service import Service

STATS_PERIOD_S = 2.0

Figures = Callable[[], dict[str, float]]
"""Service-specific measurements, sampled at each publication."""


def percentile_figures(name: str, seconds: Collection[float]) -> dict[str, float]:
    """`<name>_p50_ms` and `<name>_p99_ms` of `seconds` (nothing if empty)."""
    if not seconds:
        return {}
    p50, p99 = np.percentile(np.fromiter(seconds, float, len(seconds)), [50, 99])
    return {f"{name}_p50_ms": 1e3 * float(p50), f"{name}_p99_ms": 1e3 * float(p99)}


def snapshot(service: Service, figures: Figures | None = None) -> ServiceStats:
    """The service's counters and figures now."""
    return ServiceStats(service=service.name, instance=service.instance, t=time.time(),
                        drops=service.counters.total(), counters=dict(service.counters),
                        figures=figures() if figures is not None else {})


async def publish_stats(service: Service, figures: Figures | None = None, period_s: float = STATS_PERIOD_S) -> None:
    """Publish `snapshot(service, figures)` every `period_s` until cancelled."""
    pub = service.publisher(service.keys.stats(service.name, service.instance), ServiceStats)
    while True:
        await asyncio.sleep(period_s)
        pub.put(snapshot(service, figures))
