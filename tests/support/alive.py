"""Waiting for services by their liveliness tokens (as a client sees them), e.g. after a router restart."""

from __future__ import annotations

import asyncio
import time

from common.bus.keys import Keys
from common.bus.liveliness import watch_alive
from common.bus.session import ZenohConfig, open_session


async def wait_for_services(config: ZenohConfig, keys: Keys, counts: dict[str, int], timeout: float) -> list[str]:
    """Wait until each service has its count of live instances; the ones still missing."""
    session = open_session(config)
    try:
        watches = {svc: await watch_alive(session, keys, svc) for svc in counts}
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            missing = [s for s, n in counts.items() if len(watches[s].instances) < n]
            if not missing:
                break
            await asyncio.sleep(0.2)
        for w in watches.values():
            w.close()
        return [s for s, n in counts.items() if len(watches[s].instances) < n]
    finally:
        session.close()
