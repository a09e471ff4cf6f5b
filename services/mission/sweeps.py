"""Where a vehicle that left a mission may be from now on (issue 16: `Sweep`s, the bodies the
others are replanned around), for what its executor does on its own:

- held by the tracking guard (`tracking_hold`): it hovers where it is until the mission ends, or
  stops where it is on the ground: that spot, for ever, and once the mission's plan has ended the
  column below it too (`held`);
- an emergency descent (stale pose; a fall): straight down from where it is, at least at the slowest
  descent assumed (`DESCENT_S_PER_M`) after `REST_S`; the column below its highest possible
  position in each `SLICE_S`, so that the column's top frees as it comes down (a vehicle following
  it in its lane may pass above it once it is low enough); then its foot, for ever;
- a fault landing to a node (low battery, lost link: `safe_landing_steps`): level to above the node,
  then down onto it (sliced the same way), resting there.
The times assumed are the fly and land speeds with 50 % slack (and the emergency descent's 0.25 m/s
with its `descent_slack`), each with `REST_S` more.
"""

from __future__ import annotations

import math

from common.bus.messages import Sweep

SWEEP_REACH = 0.1
"""m: how far a vehicle that left may wander from where it is assumed to go (a held vehicle on a
slow control loop oscillates by up to 10 cm, `tests/test_tracking_guard.py`)."""
REST_REACH = 0.03
"""m: how far a vehicle landing on its own (its executor's fault landing or emergency descent, on a
control loop that is not slow) may be from where it is assumed to go; 10 cm there left most replans
of an 80-vehicle fleet without a plan (the vehicle following the faulted one in its lane is inside)."""
LEVEL_S_PER_M, DESCENT_S_PER_M, REST_S = 1.5 / 0.5, 1.5 / 0.2, 1.0
"""How long a vehicle that left is assumed to take to fly a metre level and descend a metre (its
fault landing: the fly and land speeds with 50 % slack, the emergency descent's 0.25 m/s too), and
the margin added to each."""
SLICE_S = 0.5
"""s: a descent's column is swept in pieces this long, each below the highest the body may be then."""

Point = tuple[float, float, float]


def held(vid: str, p: Point, t: float, ground: float, end: float) -> list[Sweep]:
    """A vehicle held at `p` from `t` (`tracking_hold`): that spot, for ever (it hovers there, or
    stands, until its mission ends), and from `end` (the mission's plan's end) on the column below
    it: once the others are done its executor lands it, on a clear node of its choice
    (`VehicleController._choose_landing`), or straight down if its poses are lost, so no vehicle
    may rest beneath it. While the plan runs, a vehicle may pass beneath it as beneath any vehicle
    flying its plan; an emergency descent is an event of its own, whose replan sweeps the descent
    (`descent`). (Its whole column for ever from `t` closed the roads beneath a held flyer to
    the cars on them: in a 10-minute 80-vehicle soak a car 15 cm before a road node 29 cm beside a
    held flyer's column could not be placed, was stopped on the road for good, and the replans
    around it stopped 35 vehicles more; replayed with this sweep, that replan plans.)"""
    spot = Sweep(vid, p, p, t, t, rest=True, reach=SWEEP_REACH)
    foot = (p[0], p[1], min(ground, p[2]))
    if foot == p:
        return [spot]
    later = max(end, t)
    return [spot, Sweep(vid, p, foot, later, later, rest=True, reach=SWEEP_REACH)]


def descent(vid: str, top: Point, bottom: Point, t: float) -> list[Sweep]:
    """Straight down from `top` (at `t`) to `bottom`, resting there for ever: per `SLICE_S` the
    column from the highest the body may still be down to `bottom` (it may also fall)."""
    height = top[2] - bottom[2]
    end = t + DESCENT_S_PER_M * height + REST_S
    out = []
    start = t
    while start < end:
        stop = min(start + SLICE_S, end)
        z = top[2] - max(0.0, start - t - REST_S) / DESCENT_S_PER_M
        out.append(Sweep(vid, (top[0], top[1], max(z, bottom[2])), bottom, start, stop, reach=REST_REACH))
        start = stop
    return out + [Sweep(vid, bottom, bottom, t, t, rest=True, reach=REST_REACH)]


def fault_landing(vid: str, p: Point, t: float, target: Point) -> list[Sweep]:
    """Level from `p` (at `t`) to above `target`, then down onto it, resting there for ever."""
    above = (target[0], target[1], p[2])
    t1 = t + LEVEL_S_PER_M * math.dist(p, above) + REST_S
    return [Sweep(vid, p, above, t, t1, reach=REST_REACH)] + descent(vid, above, target, t1)


def left_vehicle(vid: str, kind: str, p: Point, t: float, ground: float, target: Point | None,
                 end: float) -> list[Sweep]:
    """Where a vehicle at `p` at `t` that left on a `kind` fault may be (module doc): held (`end`:
    the mission's plan's end, `held`), or coming straight down (an emergency descent, a fall), and
    with a fault landing's node (`target`, at least 5 cm below it) also level to above it and down
    onto it."""
    if kind == "tracking_hold":
        return held(vid, p, t, ground, end)
    out = descent(vid, p, (p[0], p[1], min(ground, p[2])), t)
    if target is not None and p[2] - target[2] >= 0.05:
        out += fault_landing(vid, p, t, target)
    return out
