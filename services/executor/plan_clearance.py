"""Whether two vehicles on their plans are kept apart by them (issue 15): a proximity stop spared.

A plan is collision-free while every vehicle stays within the margin it was planned with
(`VehicleModel.margin`; the planners keep that clearance between every two bodies). The proximity
stop (`services/executor/proximity.py`) judges from the motion capture alone: the mover on its
velocity bent as its plan bends, the other body standing where it is if it comes closer. Where two
plans pass at their margin, that is a touch foretold for two vehicles each within 2 cm of its
plan: three of four 80-vehicle soaks that failed on 2026-12-07 began so (cf55 stopped 6.5 cm short
of cf54, 0.7 and 1.3 cm from their references, where the plan passes them 5.0 cm apart, the whole
margin), and the stop's hold became a replan that could not place the vehicles around it.

So a closing the stop finds is judged once more on the plans, for two vehicles of one mission that
both follow theirs: each goes on along the reference its executor makes of its plan (`Trajectory`:
the plan's corners blended, within 5 mm of it), offset from it as it is now, and drifting from it
at the difference between its velocity and its reference's over the same window (a vehicle stalled
on its way, its executor starved, goes on standing where it is; one catching up with its plan,
faster). If neither is farther than the margin from its reference now and the two come no nearer
than `near_gap` over the look-ahead, the plans keep them apart and the mover goes on."""

from __future__ import annotations

import numpy as np

from services.executor.trajectory import Trajectory


def on_its_way(way: Trajectory, pos: np.ndarray, vel: np.ndarray, rel: float, pace: float, taus: np.ndarray,
               margin: float, window: float) -> np.ndarray | None:
    """Where a vehicle at `pos` is after `taus` s (len(taus) x 3) going on along its reference
    (`way`, at plan time `rel` now, its clock at `pace`) offset from it as now, drifting at the
    difference between its velocity `vel` (measured over the last `window` s) and its reference's
    over that window; None when it is farther than `margin` from its reference now."""
    ts = rel + pace * np.concatenate(((-window, 0.0), taus))
    at = np.array([(r.x, r.y, r.z) for r in map(way.sample, ts.tolist())])
    off = pos - at[1]
    if float(off @ off) > margin * margin:
        return None
    drift = vel - (at[1] - at[0]) / window
    return at[2:] + off + np.outer(taus, drift)


def kept_apart(a: np.ndarray | None, b: np.ndarray | None, radius: float, height: float, near_gap: float) -> bool:
    """Whether two bodies of `radius` x `height` on their ways (`on_its_way`, sampled alike) stay
    more than `near_gap` from touching (DESIGN.md: nearer than 2 radius across and height up)."""
    if a is None or b is None:
        return False
    d = b - a
    gap = np.maximum(np.hypot(d[:, 0], d[:, 1]) - 2.0 * radius, np.abs(d[:, 2]) - height)
    return bool(gap.min() > near_gap)
