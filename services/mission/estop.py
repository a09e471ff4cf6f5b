"""`fleet estop`: the operator's emergency stop (issue 14). Publishes `EmergencyStop` on `estop`
(only the operator role may: deploy/router.json5), a few times in case one is lost; every gateway
sends the supervisor's emergency stop to every vehicle it serves (motors off, Locked) and refuses
commands until `fleet estop --release`, which reboots the vehicles it locked."""

from __future__ import annotations

import argparse
import asyncio
import time

from common.bus.args import keys_from_args, zconfig_from_args
from common.bus.keys import Keys
from common.bus.messages import EmergencyStop
from common.bus.pubsub import Publisher
from common.bus.session import ZenohConfig, open_session

REPEATS = 5
"""Times the stop is published, `REPEAT_S` apart (the gateways act on the first and ignore repeats)."""
REPEAT_S = 0.05
MATCH_WAIT_S = 1.0
"""How long to wait for a gateway's subscription to match before publishing anyway."""


async def emergency_stop(zconfig: ZenohConfig, keys: Keys, reason: str = "", release: bool = False) -> float:
    """Publish the stop (or its release); the time (epoch s) it first went out."""
    session = await asyncio.to_thread(open_session, zconfig)
    try:
        pub = Publisher(session, keys.estop, EmergencyStop)
        deadline = time.monotonic() + MATCH_WAIT_S
        while not pub.matched and time.monotonic() < deadline:  # a put before the route exists is lost
            await asyncio.sleep(0.005)
        first = time.time()
        for _ in range(REPEATS):
            pub.put(EmergencyStop(t=first, reason=reason, release=release))
            await asyncio.sleep(REPEAT_S)
        pub.close()
        return first
    finally:
        session.close()


def cmd_estop(args: argparse.Namespace) -> int:
    asyncio.run(emergency_stop(zconfig_from_args(args), keys_from_args(args), args.reason, args.release))
    print("emergency stop " + ("released: the gateways reboot the vehicles it locked" if args.release
                               else "sent: every gateway stops every vehicle's motors"))
    return 0
