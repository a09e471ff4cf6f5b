"""Timed path -> smooth, time-parametrised reference (paper 000 §VI-B, §VI-C: "the trajectory
generator smooths the path into closely spaced waypoints").

The plan (DESIGN.md, "Plan file") is piecewise linear in time: consecutive entries at different
nodes are traversed at constant velocity, two entries at one node are a wait, and the vehicle rests
at its start before the first entry and at its goal after the last. Its velocity jumps at every
entry. Each jump is replaced by a parabolic blend of half-width h centred on the entry's time
(linear segments with parabolic blends): the velocity ramps linearly from v_in to v_out over
[t_i - h, t_i + h]. Outside the blends the reference *is* the plan; inside, it is at most
|v_out - v_in| h / 4 from the plan's position at the same instant, and h is chosen per entry so
that this stays below `max_deviation` (default 5 mm against 2 x 0.06 m body radii). At t_i the
reference is therefore within `max_deviation` of node i; it touches a node where it stops at most
h <= `max_blend` after t_i and is back on the plan's schedule at t_i + h.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from common.bus.messages import PlanStep
from common.flight.modes import AIRBORNE, Mode, segment_mode
from common.flight.reference import RefSample, wrap_angle

_EPS = 1e-9


@dataclass(frozen=True, slots=True)
class TrajectoryParams:
    """max_deviation: bound on |reference - plan| at any instant (m); max_blend: largest blend
    half-width (s); yaw_rate: rate of the yaw turn while airborne (rad/s)."""

    max_deviation: float = 0.005
    max_blend: float = 0.2
    yaw_rate: float = 0.6


class Trajectory:
    """The smoothed reference of one vehicle's timed path; `sample(t)` is O(log n)."""

    def __init__(self, steps: Sequence[PlanStep], params: TrajectoryParams = TrajectoryParams(),
                 yaw0: float | None = None) -> None:
        if not steps:
            raise ValueError("a trajectory needs at least one path entry")
        self.params = params
        self.steps = _dedupe(steps)
        self.times = [s.t for s in self.steps]
        self.nodes = [s.pos for s in self.steps]
        n = len(self.steps)
        # vel[k] is the plan's velocity on segment k, from entry k to k+1; rest before and after
        self.vel: list[tuple[float, float, float]] = []
        for k in range(n - 1):
            dt = self.times[k + 1] - self.times[k]
            if dt <= _EPS:
                raise ValueError(f"entries {k} and {k + 1} ({self.steps[k].node} -> "
                                 f"{self.steps[k + 1].node}) are at the same time")
            a, b = self.nodes[k], self.nodes[k + 1]
            self.vel.append(((b[0] - a[0]) / dt, (b[1] - a[1]) / dt, (b[2] - a[2]) / dt))
        self.half = [self._blend_half_width(i) for i in range(n)]
        self.ways = self._ways()
        """For each value of `segment(t)`: the unit direction of the plan's latest move at or before
        t (None before any): the way along which a vehicle is behind its plan."""
        self.modes = self._plan_modes()
        self._yaw = self._plan_yaw(yaw0)
        self._plan_arrays: tuple[np.ndarray, np.ndarray] | None = None  # times, nodes (n x 3): `plan_positions`

    def _ways(self) -> list[tuple[float, float, float] | None]:
        out: list[tuple[float, float, float] | None] = [None]
        way = None
        for vx, vy, vz in self.vel:
            speed = math.sqrt(vx * vx + vy * vy + vz * vz)
            if speed > _EPS:
                way = (vx / speed, vy / speed, vz / speed)
            out.append(way)
        out.append(way)
        return out

    @property
    def start_time(self) -> float:
        return self.times[0]

    @property
    def end_time(self) -> float:
        return self.times[-1]

    def _v(self, k: int) -> tuple[float, float, float]:
        """Plan velocity on segment k; k = -1 and k = n - 1 are the rests before and after."""
        return self.vel[k] if 0 <= k < len(self.vel) else (0.0, 0.0, 0.0)

    def _blend_half_width(self, i: int) -> float:
        vi, vo = self._v(i - 1), self._v(i)
        dv = math.dist(vi, vo)
        if dv < _EPS:
            return 0.0
        h = min(self.params.max_blend, 4.0 * self.params.max_deviation / dv)
        if i > 0:
            h = min(h, 0.5 * (self.times[i] - self.times[i - 1]))
        if i < len(self.times) - 1:
            h = min(h, 0.5 * (self.times[i + 1] - self.times[i]))
        return h

    def deviation_bound(self) -> float:
        """Largest |reference - plan| over all instants: max over entries of |dv| h / 4."""
        return max((math.dist(self._v(i - 1), self._v(i)) * h / 4.0 for i, h in enumerate(self.half)),
                   default=0.0)

    def _plan_modes(self) -> list[Mode]:
        """modes[k + 1] is the planned mode on segment k; modes[0] before the first entry and
        modes[-1] after the last (at the goal)."""
        first = self.steps[0]
        modes = [Mode.FLYING if first.kind == "air" else Mode.PARKED]
        for k in range(len(self.steps) - 1):
            nxt = self.steps[k + 1]
            edge = nxt.edge if nxt.node != self.steps[k].node else ""
            modes.append(segment_mode(edge, nxt.kind, modes[-1]))
        last = self.steps[-1]
        modes.append(Mode.FLYING if last.kind == "air" else Mode.DONE)
        return modes

    def _plan_yaw(self, yaw0: float | None) -> list[tuple[float, float, float]]:
        """Per segment k + 1 (as in `modes`): (yaw at its start, start time, signed turn).

        On the ground the yaw is the direction of travel (held through waits); airborne, the
        vehicle turns at `yaw_rate` from its takeoff heading to the heading of the drive that
        follows its landing, so that it touches down facing its road.
        """
        n = len(self.steps)
        heading: list[float | None] = [None] * (n + 1)
        for k, (vx, vy, _) in enumerate(self.vel):
            if self.modes[k + 1] == Mode.DRIVING and math.hypot(vx, vy) > _EPS:
                heading[k + 1] = math.atan2(vy, vx)
        known = [h for h in heading if h is not None]
        current = yaw0 if yaw0 is not None else (known[0] if known else 0.0)
        out: list[tuple[float, float, float]] = []
        k = 0
        while k <= n:
            if self.modes[k] in AIRBORNE and k > 0:  # an airborne stretch: segments k .. end - 1
                end = k
                while end <= n and self.modes[end] in AIRBORNE:
                    end += 1
                after = next((h for h in heading[end:] if h is not None), current)
                turn = wrap_angle(after - current)
                out.extend([(current, self.times[k - 1], turn)] * (end - k))
                current = wrap_angle(current + turn)
                k = end
                continue
            if heading[k] is not None:
                current = heading[k]
            out.append((current, 0.0, 0.0))
            k += 1
        return out

    def segment(self, t: float) -> int:
        """Index into `modes`: 0 before the first entry, k + 1 on segment k, n after the last; also
        the progress, the number of path entries at or before `t`."""
        return bisect_right(self.times, t)

    def sample(self, t: float) -> RefSample:
        """The reference at `t` (s since mission start)."""
        times, nodes, half = self.times, self.nodes, self.half
        seg = bisect_right(times, t)
        # the entry whose blend may contain t: the nearer of the segment's two ends
        i = seg if seg < len(times) and times[seg] - t < half[seg] else seg - 1
        if i >= 0 and abs(t - times[i]) < half[i]:
            h = half[i]
            vi, vo = self._v(i - 1), self._v(i)
            s = t - times[i]
            w = (s + h) * (s + h) / (4.0 * h)
            f = (s + h) / (2.0 * h)
            n_i = nodes[i]
            px = n_i[0] + vi[0] * s + (vo[0] - vi[0]) * w
            py = n_i[1] + vi[1] * s + (vo[1] - vi[1]) * w
            pz = n_i[2] + vi[2] * s + (vo[2] - vi[2]) * w
            vx, vy, vz = (vi[0] + (vo[0] - vi[0]) * f, vi[1] + (vo[1] - vi[1]) * f,
                          vi[2] + (vo[2] - vi[2]) * f)
            ax, ay, az = ((vo[0] - vi[0]) / (2 * h), (vo[1] - vi[1]) / (2 * h), (vo[2] - vi[2]) / (2 * h))
        else:
            j = min(max(seg - 1, 0), len(times) - 1)
            vx, vy, vz = self._v(seg - 1)
            s = t - times[j]
            n_j = nodes[j]
            px, py, pz = n_j[0] + vx * s, n_j[1] + vy * s, n_j[2] + vz * s
            ax = ay = az = 0.0
        mode = self.modes[seg]
        base, t_turn, turn = self._yaw[seg]
        if turn:
            elapsed = max(t - t_turn, 0.0) * self.params.yaw_rate
            yaw_rate = math.copysign(self.params.yaw_rate, turn) if elapsed < abs(turn) else 0.0
            yaw = wrap_angle(base + math.copysign(min(elapsed, abs(turn)), turn))
        else:
            yaw_rate = 0.0
            yaw = math.atan2(vy, vx) if mode == Mode.DRIVING and vx * vx + vy * vy > 1e-8 else base
        return RefSample(t, px, py, pz, vx, vy, vz, ax, ay, az, yaw, yaw_rate, mode)

    def samples(self, dt: float = 0.01, lead: float = 0.0, tail: float = 0.0) -> list[RefSample]:
        """Closely spaced samples from `lead` s before the first entry to `tail` s after the last."""
        t0 = self.start_time - lead
        count = int(math.floor((self.end_time + tail - t0) / dt + 1e-9)) + 1
        return [self.sample(t0 + k * dt) for k in range(count)]

    def plan_position(self, t: float) -> tuple[float, float, float]:
        """The plan's own (unsmoothed, linear) position at `t`: the reference the smoothing deviates from."""
        seg = bisect_right(self.times, t)
        j = min(max(seg - 1, 0), len(self.times) - 1)
        v = self._v(seg - 1)
        s = t - self.times[j]
        n_j = self.nodes[j]
        return (n_j[0] + v[0] * s, n_j[1] + v[1] * s, n_j[2] + v[2] * s)

    def plan_positions(self, ts: np.ndarray) -> np.ndarray:
        """`plan_position` at each of the times `ts` at once (len(ts) x 3)."""
        if self._plan_arrays is None:
            self._plan_arrays = (np.array(self.times), np.array(self.nodes))
        times, nodes = self._plan_arrays
        return np.stack([np.interp(ts, times, nodes[:, k]) for k in range(3)], axis=1)


def _dedupe(steps: Sequence[PlanStep]) -> list[PlanStep]:
    """Drops an entry repeating the previous one's node and time (a zero-length wait)."""
    out = [steps[0]]
    for s in steps[1:]:
        if s.node == out[-1].node and abs(s.t - out[-1].t) <= _EPS:
            continue
        if s.t < out[-1].t:
            raise ValueError(f"path entry {s.node} at t={s.t} goes back in time")
        out.append(s)
    return out
