"""Lower a process's CPU priority so that it cannot delay the fleet's control loops, or raise the
simulator's so that the world it stands for does not wait for the fleet's services.

`os.nice` alone is not enough on Linux with autogrouping (`kernel.sched_autogroup_enabled`): the
scheduler first shares the CPU between autogroups (one per session), and a nice value only weighs
within its group. `fleet up` starts each service in its own session, so a niced recorder still got
an equal share beside the executors and gateways (measured: 32 % of a core on a saturated 2-core
machine). The autogroup's own nice value is lowered too, where the kernel has autogroups and this
process leads its session (so the group is its own, not a terminal's shared with the user's shell).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)

AUTOGROUP = Path("/proc/self/autogroup")


def lower_priority(nice: int) -> None:
    """Add `nice` (> 0) to this process's nice value, and to its autogroup's if the group is its own."""
    if nice <= 0:
        return
    _set_autogroup(os.nice(nice))


def raise_priority(by: int) -> bool:
    """Take `by` (> 0) from this process's nice value, and from its autogroup's if the group is its
    own, where the system allows it (root, or CAP_SYS_NICE); False, and a log line, where not."""
    if by <= 0:
        return True
    try:
        value = os.nice(-by)
    except PermissionError as exc:
        log.info("cannot raise this process's priority (%s): it runs at its nice value %d", exc, os.nice(0))
        return False
    _set_autogroup(value)
    return True


def _set_autogroup(value: int) -> None:
    if not AUTOGROUP.exists() or os.getsid(0) != os.getpid():
        return
    try:
        AUTOGROUP.write_text(f"{value}\n")
    except OSError as exc:  # a kernel without autogroups, or a sandbox that refuses it
        log.info("cannot set the autogroup's priority: %s", exc)
