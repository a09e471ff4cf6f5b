"""`fleet sim fault VID KIND`: inject a fault into a running simulated fleet (`fleet up`, `fleet demo`)
from any shell, as the operator (only the `mission` role may publish on `sim/fault/<vid>`:
deploy/router.json5). The simulator obeys (docs/reliability.md "Rehearsing faults"); real vehicles
never see it. This module talks to the simulator over the bus only (it imports nothing of it)."""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
import time
from dataclasses import dataclass
from typing import get_args

import zenoh

from common.bus.args import keys_from_args, zconfig_from_args
from common.bus.keys import Keys, check_chunk
from common.bus.messages import SimFault, SimFaultKind, SimTruth
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import ZenohConfig, open_session
from common.errors import InputError

KINDS: tuple[SimFaultKind, ...] = get_args(SimFaultKind)
TIMED = ("mocap_dropout", "radio_blackout", "gust")
"""Kinds that need a positive `--duration`."""
MAX_GUST = 9.81
"""m/s^2: the strongest wind a `gust` may simulate (1 g sideways)."""
WAIT_S = 2.0
"""How long to wait for the simulator's ground truth and its fault subscription."""


@dataclass(frozen=True)
class Sent:
    """What `inject` found: the simulated vehicles it heard, and whether the fault went out."""

    vehicles: frozenset[str]
    sent: bool


def fault_from_args(vid: str, kind: str, duration: float | None, charge_used: float | None,
                    gust: tuple[float, float] | None = None) -> SimFault:
    """The `SimFault` a command line asks for; InputError naming the option on bad input."""
    try:
        check_chunk(vid, "vehicle id")
    except ValueError as exc:
        raise InputError("VID", "", str(exc)) from None
    if kind not in KINDS:
        raise InputError("KIND", "", f"{kind!r} is not one of {', '.join(KINDS)}")
    if duration is not None and duration < 0:
        raise InputError("--duration", "", f"{duration:g} s: must not be negative")
    if charge_used is not None and charge_used < 0:
        raise InputError("--charge-used", "", f"{charge_used:g} Ah: must not be negative")
    if kind == "battery":
        if charge_used is None:
            raise InputError("--charge-used", "", "battery needs the charge used (Ah)")
        return SimFault(vid=vid, kind="battery", charge_used_ah=charge_used)
    if charge_used is not None:
        raise InputError("--charge-used", "", f"only for battery, not {kind}")
    if kind in TIMED and not duration:
        raise InputError("--duration", "", f"{kind} needs a positive duration (s)")
    if kind == "power_on" and duration:
        raise InputError("--duration", "", "power_on takes none (it switches the vehicle on now)")
    if (kind == "gust") != (gust is not None):
        raise InputError("--gust", "", "gust needs --gust AX AY (m/s^2)" if kind == "gust" else f"only for gust, not {kind}")
    if gust is not None:
        if not all(math.isfinite(a) for a in gust) or math.hypot(*gust) > MAX_GUST:
            raise InputError("--gust", "", f"{gust[0]:g} {gust[1]:g} m/s^2: at most {MAX_GUST:g} m/s^2, finite")
        return SimFault(vid=vid, kind="gust", duration_s=duration or 0.0, gust=(gust[0], gust[1]))
    return SimFault(vid=vid, kind=kind, duration_s=duration or 0.0)  # type: ignore[arg-type]  # checked above


async def inject(zconfig: ZenohConfig, keys: Keys, fault: SimFault, wait_s: float = WAIT_S) -> Sent:
    """Publish `fault` once the simulator is heard simulating its vehicle (ground truth) and
    subscribes to its fault key; nothing is published if it is not, within `wait_s`."""
    session = await asyncio.to_thread(open_session, zconfig)
    try:
        heard: set[str] = set()
        truth = subscribe(session, keys.all_sim_truth, SimTruth, lambda m, _k: heard.add(m.vid))
        pub = Publisher(session, keys.sim_fault(fault.vid), SimFault)
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and not (fault.vid in heard and pub.matched):
            await asyncio.sleep(0.01)
        ready = fault.vid in heard and pub.matched
        if ready:
            pub.put(fault)
            await asyncio.sleep(0.1)  # let it leave before the session closes
        truth.close()
        pub.close()
        return Sent(frozenset(heard), ready)
    finally:
        session.close()


def describe(fault: SimFault) -> str:
    if fault.kind == "battery":
        return f"{fault.vid}: battery at {fault.charge_used_ah:g} Ah used"
    if fault.kind == "power_on":
        return f"{fault.vid}: switched on (it boots)"
    if fault.kind == "gust":
        return f"{fault.vid}: gust of {fault.gust[0]:g}, {fault.gust[1]:g} m/s^2 for {fault.duration_s:g} s"
    if fault.kind == "power_off" and fault.duration_s == 0:
        return f"{fault.vid}: switched off until `fleet sim fault {fault.vid} power_on`"
    return f"{fault.vid}: {fault.kind} for {fault.duration_s:g} s"


def cmd_fault(args: argparse.Namespace) -> int:
    fault = fault_from_args(args.vid, args.kind, args.duration, args.charge_used, args.gust)
    keys = keys_from_args(args)
    try:
        sent = asyncio.run(inject(zconfig_from_args(args), keys, fault, args.wait))
    except zenoh.ZError as exc:
        print(f"fleet sim fault: cannot open a session with the router {args.connect} ({exc})", file=sys.stderr)
        return 1
    if sent.sent:
        print(f"fault injected: {describe(fault)}")
        return 0
    if sent.vehicles and fault.vid not in sent.vehicles:
        raise InputError("VID", "", f"no simulated vehicle {fault.vid!r} on fleet {keys.fleet!r} "
                                    f"(simulated: {', '.join(sorted(sent.vehicles))})")
    why = (f"no simulated vehicle on fleet {keys.fleet!r} within {args.wait:g} s (no ground truth): is `fleet sim` "
           "running, and are you the operator (FLEET_ZENOH_USER=mission)?") if not sent.vehicles else (
           f"the simulator does not receive faults for {fault.vid}: only the operator role (mission) may publish them")
    print(f"fleet sim fault: {why}", file=sys.stderr)
    return 1
