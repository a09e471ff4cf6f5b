"""Whether two vehicles on their plans are kept apart by them (issue 15): a proximity stop spared.

A plan is collision-free while every vehicle stays within the margin it was planned with
(`VehicleModel.margin`; the planners keep that clearance between every two bodies). The proximity
stop (`services/executor/proximity.py`) judges from the motion capture alone: the mover on its
velocity bent as its plan bends, the other body standing where it is if it comes closer. Where two
plans pass at their margin, that is a touch foretold for two vehicles each a centimetre or two
from its plan: each of the four 80-vehicle soaks that failed on 2026-12-07 (fortieth session)
began with such a stop of one flyer for another, both 0.7-3.2 cm from their references (cf55
stopped 6.5 cm short of cf54, 0.7 and 1.3 cm from theirs, where their plans pass 5.0 cm apart,
the whole margin), and the stop's hold became replans that could not place the vehicles around it.

So a closing the stop finds is judged once more on the plans, for two vehicles of one mission that
both follow theirs: each goes on along the reference its executor makes of its plan (`Trajectory`:
the plan's corners blended, within 5 mm of it), offset from it as it is now, and drifting from it
at the difference between its velocity and its reference's over the same window until its
controller has taken that difference up: for the commands' reaction at the full difference, then
settling as a held vehicle comes to rest (`ProximityParams.hold_s`: within its speed x 0.12 s). A
vehicle stalled on its way (at rest, its reference going on) lags its plan by the more; one
farther than the margin from its reference now is not judged on it (a stall of 0.17 s at 0.3 m/s
on a 5 cm margin), nor is one whose executor has not told its state for a while
(`ExecutorService._keeping_to_plan`). If the two come no nearer than `near_gap` over the
look-ahead, the plans keep them apart and the mover goes on."""

from __future__ import annotations

import numpy as np

from services.executor.trajectory import Trajectory


def drift_time(taus: np.ndarray, react: float, settle: float) -> np.ndarray:
    """How long (s) a velocity's difference from its reference goes on, counted by `taus` s: at
    the full difference for `react` s, then decaying with time constant `settle` s."""
    after = np.maximum(taus - react, 0.0)
    return np.minimum(taus, react) + settle * (1.0 - np.exp(-after / settle))


def on_its_way(way: Trajectory, pos: np.ndarray, vel: np.ndarray, rel: float, pace: float, taus: np.ndarray,
               margin: float, window: float, react: float, settle: float) -> np.ndarray | None:
    """Where a vehicle at `pos` is after `taus` s (len(taus) x 3) going on along its reference
    (`way`, at plan time `rel` now, its clock at `pace`) offset from it as now, drifting at the
    difference between its velocity `vel` (measured over the last `window` s) and its reference's
    over that window for `drift_time`; None when it is farther than `margin` from its reference now."""
    ts = rel + pace * np.concatenate(((-window, 0.0), taus))
    at = np.array([(r.x, r.y, r.z) for r in map(way.sample, ts.tolist())])
    off = pos - at[1]
    if float(off @ off) > margin * margin:
        return None
    drift = vel - (at[1] - at[0]) / window
    return at[2:] + off + np.outer(drift_time(taus, react, settle), drift)


def nearest(a: np.ndarray | None, b: np.ndarray | None, radius: float, height: float) -> float:
    """How near (m) two bodies of `radius` x `height` on their ways (`on_its_way`, sampled alike)
    come to touching (DESIGN.md: nearer than 2 radius across and height up; negative: into each
    other); -inf when either is not judged on its plan."""
    if a is None or b is None:
        return -np.inf
    d = b - a
    return float(np.maximum(np.hypot(d[:, 0], d[:, 1]) - 2.0 * radius, np.abs(d[:, 2]) - height).min())
