"""`fleet estop`: the operator's emergency stop (issue 14). Publishes `EmergencyStop` on `estop`
(only the operator role may: deploy/router.json5), a few times in case one is lost; every gateway
sends the supervisor's emergency stop to every vehicle it serves (motors off, Locked) and refuses
commands until `fleet estop --release`, which reboots the vehicles it locked. The command then
waits `CONFIRM_S` for the gateways' events (`emergency_stop`, or `rebooting` on release) and names
the vehicles that confirmed; with no gateway listening it fails."""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from dataclasses import dataclass

from common.bus.args import keys_from_args, zconfig_from_args
from common.bus.keys import Keys
from common.bus.messages import EmergencyStop, VehicleEvent
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import ZenohConfig, open_session

REPEATS = 5
"""Times the stop is published, `REPEAT_S` apart (the gateways act on the first and ignore repeats)."""
REPEAT_S = 0.05
MATCH_WAIT_S = 1.0
"""How long to wait for a gateway's subscription to match before publishing anyway."""
CONFIRM_S = 1.0
"""How long the gateways' confirmations are collected after the first publication."""


@dataclass(frozen=True)
class EstopOutcome:
    sent_at: float
    """Epoch s of the first publication."""
    listened: bool
    """A gateway's subscription matched the publication."""
    confirmed: tuple[str, ...]
    """Vehicles whose gateway reported acting on it."""


async def emergency_stop(zconfig: ZenohConfig, keys: Keys, reason: str = "", release: bool = False) -> EstopOutcome:
    """Publish the stop (or its release) and collect the gateways' confirmations."""
    session = await asyncio.to_thread(open_session, zconfig)
    kind = "rebooting" if release else "emergency_stop"
    confirmed: dict[str, None] = {}
    try:
        subscribe(session, keys.all_vehicles("event"), VehicleEvent,
                  lambda e, _k: confirmed.setdefault(e.vid) if e.kind == kind else None)
        pub = Publisher(session, keys.estop, EmergencyStop)
        deadline = time.monotonic() + MATCH_WAIT_S
        while not pub.matched and time.monotonic() < deadline:  # a put before the route exists is lost
            await asyncio.sleep(0.005)
        first = time.time()
        for _ in range(REPEATS):
            pub.put(EmergencyStop(t=first, reason=reason, release=release))
            await asyncio.sleep(REPEAT_S)
        await asyncio.sleep(max(0.0, first + CONFIRM_S - time.time()))
        listened = pub.matched
        pub.close()
        return EstopOutcome(first, listened, tuple(sorted(confirmed)))
    finally:
        session.close()


def cmd_estop(args: argparse.Namespace) -> int:
    out = asyncio.run(emergency_stop(zconfig_from_args(args), keys_from_args(args), args.reason, args.release))
    if not out.listened:
        print("emergency stop NOT delivered: no gateway is listening on this fleet's router", file=sys.stderr)
        return 1
    what = "released (rebooting)" if args.release else "stopped"
    names = ", ".join(out.confirmed) if out.confirmed else f"none within {CONFIRM_S:.0f} s"
    print(f"emergency stop {'release ' if args.release else ''}sent; {what}: {names}")
    return 0
