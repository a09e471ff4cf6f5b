"""The machine's own account of its CPU (`/proc/stat`): how busy its cores were over a run, and how
much of their time the virtual machine's host gave to other guests ("steal": the guest's vCPU was
ready to run but not running). A soak's fleet that misses its deadlines on a machine whose host
stole a third of a second is not the fleet's figure alone: on 2026-12-07 a one-minute 80-vehicle
soak here had 6.7 % of its CPU time stolen, up to 68 % in a tenth of a second, in the seconds when
vehicles came down onto parked ones (docs/reliability.md). Linux only; elsewhere nothing is
sampled and the figures are empty."""

from __future__ import annotations

import asyncio
import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path

STAT = Path("/proc/stat")
_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def task_cpu_seconds(stat: str) -> float:
    """User + system CPU time (s) in a process's or a thread's `/proc/<pid>[/task/<tid>]/stat` text
    (fields 14 and 15, counted after the parenthesised name, which may hold spaces)."""
    fields = stat.rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICKS
BUSY_IDLE_MAX = 0.05
"""A window with less idle CPU time than this share counts as saturated (every core busy)."""


def cpu_times() -> tuple[int, int, int] | None:
    """The machine's (total, idle, steal) CPU time so far, in clock ticks over all cores: the first
    line of /proc/stat (user nice system idle iowait irq softirq steal ...; idle counts iowait
    too). None where it cannot be read."""
    try:
        fields = STAT.read_text().split("\n", 1)[0].split()
        user, nice, system, idle, iowait, irq, softirq, steal = (int(v) for v in fields[1:9])
    except (OSError, ValueError):
        return None
    return user + nice + system + idle + iowait + irq + softirq + steal, idle + iowait, steal


@dataclass
class MachineCpu:
    """Samples of `cpu_times`, one a window."""

    samples: list[tuple[int, int, int]] = field(default_factory=list)

    def sample(self) -> None:
        times = cpu_times()
        if times is not None:
            self.samples.append(times)

    def figures(self) -> dict[str, float]:
        """busy_pct, steal_pct: shares of all the cores' time over the samples; steal_worst_pct:
        the worst window's steal; saturated_windows: windows with less than `BUSY_IDLE_MAX` idle.
        Empty with fewer than two samples."""
        if len(self.samples) < 2:
            return {}
        windows = [(t1 - t0, i1 - i0, s1 - s0) for (t0, i0, s0), (t1, i1, s1) in itertools.pairwise(self.samples)]
        total = sum(w[0] for w in windows) or 1
        return {"busy_pct": 100.0 * (1.0 - sum(w[1] for w in windows) / total),
                "steal_pct": 100.0 * sum(w[2] for w in windows) / total,
                "steal_worst_pct": max(100.0 * s / t for t, _i, s in windows if t > 0),
                "saturated_windows": float(sum(1 for t, i, _s in windows if t > 0 and i < BUSY_IDLE_MAX * t))}

    def line(self, window_s: float) -> str:
        """The figures in words, or "" without them."""
        f = self.figures()
        if not f:
            return ""
        return (f"the machine's cores were {f['busy_pct']:.0f} % busy, the host took {f['steal_pct']:.1f} % of their "
                f"time (steal; worst {window_s:.0f} s: {f['steal_worst_pct']:.0f} %), every core busy in "
                f"{f['saturated_windows']:.0f} of {len(self.samples) - 1} {window_s:.0f}-s windows")


async def sample_machine(cpu: MachineCpu, every_s: float) -> None:
    """Sample `cpu` every `every_s` until cancelled."""
    while True:
        cpu.sample()
        await asyncio.sleep(every_s)
