"""The proximity stop (issue 15): the last line between bodies when tracking fails.

A plan keeps its bodies apart only while every vehicle keeps to it (`VehicleModel.margin`); the
tracking guard holds a vehicle that leaves it by two margins, but on an overloaded machine a
vehicle stalled a few centimetres behind its plan (inside the guard's allowance) was driven into
by a neighbour on time: 80-vehicle soaks had ground contacts in every run that took off
(docs/reliability.md). The motion capture sees every body, so every executor knows where all of
them are, whoever owns them: from every frame it keeps each body's position and velocity
(`Bodies`), and before each control cycle it asks, for each vehicle of its own that moves on its
plan, whether that vehicle, at its estimated or planned velocity and bent as its plan bends, is
heading into a body (within
`near_gap` of contact) before it could have stopped, the other going on as it moves if it
moves away and standing where it is if it comes closer (its approach is its own executor's to
stop: each of two vehicles heading into each other stops for its own motion, unless nothing
stops it: a fault landing's or an emergency landing's descent goes on, and its approach counts:
in an 80-vehicle soak a driver went on in under a lost link's landing, which it counted as
standing, and the landing came down on it, 12 cm deep); if so, the vehicle
stops short (`VehicleController.stop_short`: it holds like a vehicle the guard holds, is reported
and the fleet's reflex and the mission's replan follow). A vehicle at rest, or moving away, does
not stop: its stopping would not help, and the one closing in stops instead.

The Crazyflie firmware has a layer of the same purpose for peers it localises itself
(`src/modules/interface/collision_avoidance.h`, buffered Voronoi cells: it keeps the vehicle in
its cell for `horizonSecs`, and stops in place when the cell is empty); here the executor has the
motion capture's view of every body and holds the vehicle instead of steering it, so the plans'
timing stays the planner's to repair."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from common.bus.messages import PoseFrame, VehicleState

NEVER = -1e9
"""The capture time of a body not seen yet (s)."""


@dataclass(frozen=True, slots=True)
class ProximityParams:
    """near_gap: m between two bodies that counts as touching (a third of town's 3 cm margin:
    plans keep a whole margin, tracking in a 32-vehicle soak came to 1.5 cm); a closing is looked
    for as far ahead as the mover needs to stop: its executor's reaction (`closing`'s `react_s`,
    `Bodies.reaction`: the recent pose-to-command p99, or the newest frame's age while the frames
    stall, and a period; at least `react_s` here) and a stop from
    the pair's relative speed at `brake` m/s^2 (the flight controller's tilt limit; wheels stop
    faster), taking at least `hold_s` at that speed: a vehicle held stops as its controller brings
    it to rest, within its speed x 0.104-0.119 s flying from 0.15-0.59 m/s and x 0.049 s driving
    (the flight LQR and pure pursuit in the closed loop, 2026-12-07), so at 0.3 m/s 3.1 cm, where
    the brake alone counted 2.3 and the stop came a whole `near_gap` late; closing_speed: m/s towards the other body at which a
    vehicle counts as heading into it; velocity_s: the window over which a body's velocity is
    measured from its positions (1 mm motion-capture noise is 1.4 cm/s over 0.1 s); fresh_s: a
    body not seen for longer is not counted (the motion capture lost it); samples: the points of the
    look-ahead at which the two bodies are judged; standoff: m between a vehicle held hovering
    and any other body that it keeps: its hover's point moves away, level, at `standoff_speed` m/s,
    to at most `standoff_reach` m from where it began to hover (half the reach the replans allow a
    held vehicle: `services/mission/sweeps.py`'s `SWEEP_REACH`). The proximity stop leaves its
    movers a few centimetres short of the body they stopped for, and a held vehicle on a starved
    loop wanders by several: two held 2.7 cm apart in an 80-vehicle soak wandered into each other
    (2026-12-07), as had two held while converging before (docs/reliability.md); trust_plans: a
    closing found is judged once more on the two vehicles' plans, and the mover goes on when both
    keep to theirs and they keep them apart (`services/executor/plan_clearance.py`); pause: a mover
    that heads into a vehicle keeping to its plan of the same mission pauses instead of being held
    (`VehicleController.pause`): the mission's plan clock stands, every vehicle comes to rest where
    its plan has it, and after at least `pause_settle_s` the mover goes on once the two plans are
    judged to keep them apart from there at full pace; a pause that has not ended by `pause_max_s`
    becomes the hold it would have been (the mission plans around it); pause_tracking: a flyer on
    its plan that the tracking guard would hold for its own tracking (not a burst) pauses too
    (`VehicleController._pause_for_tracking`): it flies back onto its plan's standing place and
    goes on once within the margin of it, after at least `pause_settle_s`, or is held as the guard
    would have held it at `pause_max_s`."""

    near_gap: float = 0.01
    react_s: float = 0.03
    brake: float = 2.0
    hold_s: float = 0.12
    closing_speed: float = 0.02
    velocity_s: float = 0.1
    fresh_s: float = 1.0
    samples: int = 4
    standoff: float = 0.04
    standoff_speed: float = 0.1
    standoff_reach: float = 0.05
    trust_plans: bool = True
    pause: bool = True
    pause_tracking: bool = True
    pause_settle_s: float = 0.5
    pause_max_s: float = 5.0


class Closing(NamedTuple):
    """A mover heading into another body: the gap between them now (m), the mover's speed towards
    it (m/s), the mover's velocity judged and the other's as counted (m/s, world; zero when it comes
    closer), and the reaction it was judged with (s)."""

    mover: str
    other: str
    gap: float
    speed: float
    v_mover: tuple[float, float, float]
    v_other: tuple[float, float, float]
    react: float

    def why(self) -> str:
        """The hold's reason, as reported."""
        vm, vo = (", ".join(f"{c:.2f}" for c in v) for v in (self.v_mover, self.v_other))
        return (f"stops short of {self.other}: bodies {100 * self.gap:.1f} cm apart, closing at {self.speed:.2f} m/s "
                f"(its velocity ({vm}), {self.other}'s ({vo}); reaction {1000 * self.react:.0f} ms)")


def standing(vid: str, state: VehicleState | None, now: float) -> str:
    """How `vid` stood as its executor last told (`state`, `now - state.t` ago): its mode, whether
    it was held, how far from the reference it follows and how far its plan's clock stood behind
    (`VehicleState.delay`). A proximity stop's report names the mover's and the other body's, so
    that the one off its plan (late, ahead, held, or on a clock of its own) shows without a
    trace; "no state" for a body no executor reports (one outside every mission)."""
    if state is None:
        return f"{vid}: no state"
    held = ", held" if state.held else ""
    return (f"{vid}: {state.mode}{held}, {100 * state.tracking_error:.1f} cm from its reference, "
            f"clock {state.delay:.2f} s behind, {1000 * max(now - state.t, 0.0):.0f} ms ago")


class Bodies:
    """Every body's latest position in the motion-capture frames and its velocity over the last
    `velocity_s`, one row per vehicle."""

    def __init__(self, params: ProximityParams = ProximityParams()) -> None:
        self.params = params
        self.rows: dict[str, int] = {}
        self.vids: list[str] = []
        self.pos = np.zeros((0, 3))
        self.seen = np.zeros(0)
        self.vel = np.zeros((0, 3))
        self.newest = NEVER
        """The capture time of the newest frame settled (s)."""
        self._history: deque[tuple[float, np.ndarray, np.ndarray]] = deque()
        self._frame_vids: list[str] = []  # the bodies of the last frame taken, and their rows
        self._frame_rows: list[int] = []
        self._steps = np.linspace(0.0, 1.0, params.samples)
        """The points of a look-ahead at which two bodies are judged, as shares of it."""
        self._grid = np.linspace(0.0, 1.0, 2 * params.samples)
        """The points of a mover's farthest look-ahead at which its plan's bend is asked for."""

    def _row(self, vid: str) -> int:
        row = self.rows.get(vid)
        if row is None:
            row = self.rows[vid] = len(self.vids)
            self.vids.append(vid)
            if row >= len(self.seen):
                grow = max(8, len(self.seen))
                self.pos = np.vstack((self.pos, np.zeros((grow, 3))))
                self.vel = np.vstack((self.vel, np.zeros((grow, 3))))
                self.seen = np.concatenate((self.seen, np.full(grow, NEVER)))
                self._history.clear()
        return row

    def update(self, frame: PoseFrame) -> None:
        """Take the positions of `frame`."""
        if not frame.poses:
            return
        vids = [p.vid for p in frame.poses]
        if vids != self._frame_vids:  # (the motion capture's frames name the same bodies in turn)
            self._frame_vids, self._frame_rows = vids, [self._row(vid) for vid in vids]
        rows = self._frame_rows
        self.pos[rows] = [(p.x, p.y, p.z) for p in frame.poses]
        self.seen[rows] = frame.t

    def settle(self, t: float) -> None:
        """After a cycle's frames (the newest of capture time `t`): the velocities over the last
        `velocity_s` (0 for a body without positions that far apart, or seen then but not since)."""
        self.newest = max(self.newest, t)
        window = self.params.velocity_s
        history = self._history
        history.append((t, self.pos.copy(), self.seen.copy()))
        while len(history) > 1 and history[1][0] <= t - window:
            history.popleft()
        _, old_pos, old_seen = history[0]
        dt = self.seen - old_seen
        ok = (dt >= 0.5 * window) & (dt <= 10.0 * window)
        self.vel[:] = 0.0
        self.vel[ok] = (self.pos[ok] - old_pos[ok]) / dt[ok, None]

    def reaction(self, now: float, latency: float, period: float) -> float:
        """The time from the capture of the positions judged to a stop's effect (s): the executor's
        recent pose-to-command `latency` (its p99), or the newest frame's age while the frames stall
        (the movers drive on, on their estimates, and are judged every cycle: in an 80-vehicle soak
        a stall of a tenth of a second let a driver go on into a vehicle stopped before it), and a
        control `period`."""
        age = now - self.newest if self.newest > NEVER else 0.0
        return max(latency, age) + period

    def stop_time(self, speed: np.ndarray | float) -> np.ndarray | float:
        """How long (s) a closing at `speed` (m/s) goes on at that speed, counted for the stop: the
        brake's distance, or the hold's at least (`ProximityParams`)."""
        return np.maximum(speed / (2.0 * self.params.brake), self.params.hold_s)

    def push_apart(self, vid: str, at: tuple[float, float, float], radius: float, height: float,
                   now: float) -> tuple[float, float] | None:
        """How far (dx, dy, m) the hover point `at` of `vid`'s body should move, level, to be
        `standoff` from every other body seen within `fresh_s` (bodies of `radius` x `height`,
        `closing`): the sum of the shortfalls, each directly away from its body; None when none
        is that near, or when the move would leave it nearer to the nearest body than it is."""
        p = self.params
        n = len(self.vids)
        pos = self.pos[:n]
        d = np.asarray(at[:2]) - pos[:, :2]
        across = np.hypot(d[:, 0], d[:, 1])
        short = p.standoff - (across - 2.0 * radius)
        others = (np.abs(pos[:, 2] - at[2]) - height < p.standoff) & (now - self.seen[:n] < p.fresh_s)
        if vid in self.rows:
            others[self.rows[vid]] = False
        near = others & (short > 0.0) & (across > 1e-6)
        if not near.any():
            return None
        push = (d[near] * (short[near] / across[near])[:, None]).sum(axis=0)
        moved = np.hypot(*(np.asarray(at[:2]) + push - pos[others, :2]).T)
        if moved.min() <= across[others].min():
            return None
        return float(push[0]), float(push[1])

    def closing(self, movers: list[str], v_self: np.ndarray, radius: float, height: float,
                now: float, react_s: float = 0.0,
                going_on: Callable[[], Collection[str]] = tuple,
                bend: Callable[[str, np.ndarray], np.ndarray] | None = None) -> list[Closing]:
        """Which of `movers` (vehicles seen in the frames) head into another body before they could
        have stopped: `v_self` (len(movers) x K x 3) are the velocities each may move at (estimated,
        planned); bodies of `radius` x `height` touch when nearer than 2 radius across and height
        up (DESIGN.md); `react_s`: how late the mover's commands take effect (s); `going_on`: the
        bodies no proximity stop stops (their approach counts, module docstring), asked for only
        when a pair is near; `bend(mover, taus)`: how far the mover's plan takes it from the
        straight line at its planned velocity in `taus` s (len(taus) x 3; none: straight on), asked
        for only when a pair is near: a mover goes the way of its velocity bent as its plan bends
        (judged on straight lines, a vehicle on time into a corner beside a body its plan passes 5 cm
        away went straight on into it, and stopped: the first hold of 80-vehicle soaks that failed,
        2026-12-07). One `Closing` per such pair, nearest first."""
        p = self.params
        react = max(react_s, p.react_s)
        n = len(self.vids)
        fastest = np.sqrt(np.einsum("mkx,mkx->mk", v_self, v_self)).max(axis=1)
        moving = fastest > p.closing_speed  # (slower heads into nothing)
        if n < 2 or not moving.any():
            return []
        index = np.nonzero(moving)[0]
        movers, v_self, fastest = [movers[k] for k in index.tolist()], v_self[index], fastest[index]
        own = np.fromiter((self.rows[v] for v in movers), np.intp, len(movers))
        pos, vel = self.pos[:n], self.vel[:n]
        body_speed = np.sqrt(np.einsum("bx,bx->b", vel, vel))
        reach_xy, reach_z = 2.0 * radius + p.near_gap, height + p.near_gap
        # the pairs that may be near: within the farthest any pair closes in before stopping, across
        # (every mover x body at once: the one pass over all pairs), then each pair's own reach
        top = float(body_speed.max()) + float(fastest.max())
        most = top * (react + self.stop_time(top))
        x, y = pos[:, 0], pos[:, 1]
        dx, dy = x[None, :] - x[own, None], y[None, :] - y[own, None]
        i, j = np.nonzero(dx * dx + dy * dy < (reach_xy + most) ** 2)
        fresh = now - self.seen[:n] < p.fresh_s
        mine = own[i]
        keep = np.nonzero((j != mine) & fresh[j] & fresh[mine])[0]
        i, j, mine = i[keep], j[keep], mine[keep]
        dij = pos[j] - pos[mine]  # pairs x 3: to the other body
        across = np.hypot(dij[:, 0], dij[:, 1])
        speed = body_speed[j] + fastest[i]
        ahead = speed * (react + self.stop_time(speed))  # the farthest the pair closes in before stopping
        near = np.nonzero((across - ahead < reach_xy) & (np.abs(dij[:, 2]) - ahead < reach_z))[0]
        if not len(near):
            return []
        i, j, dij, across = i[near], j[near], dij[near], across[near]
        vo = vel[j]
        counted = np.einsum("ij,ij->i", vo, dij) > 0.0  # its approach is its own to stop ...
        if unstopped := [self.rows[v] for v in going_on() if v in self.rows]:  # ... unless nothing stops it
            counted |= np.isin(j, unstopped)
        vo = np.where(counted[:, None], vo, 0.0)
        unit = dij / np.maximum(np.sqrt(np.einsum("ij,ij->i", dij, dij)), 1e-9)[:, None]
        w_all = vo[:, None, :] - v_self[i]  # pairs x candidates x 3: the other's motion relative to the mover
        horizons = react + self.stop_time(np.sqrt(np.einsum("pkx,pkx->pk", w_all, w_all)))  # until it could have stopped
        if bend is not None:  # each mover's bend once, over the farthest look-ahead of its pairs
            owners, slot = np.unique(i, return_inverse=True)
            far = np.zeros(len(owners))
            np.maximum.at(far, slot, horizons.max(axis=1))
            grid = far[:, None] * self._grid[None, :]
            bends = np.stack([bend(movers[u], grid[n]) for n, u in enumerate(owners.tolist())])  # owners x grid x 3
        hits: dict[tuple[str, str], Closing] = {}
        for k in range(v_self.shape[1]):
            vs = v_self[i, k]  # pairs x 3
            taus = horizons[:, k, None] * self._steps[None, :]
            way = vs[:, None, :] * taus[..., None]  # pairs x samples x 3: the mover's way on a straight line ...
            if bend is not None:  # ... bent as its plan bends (between the points of its grid, linearly)
                at = taus / far[slot, None] * (len(self._grid) - 1)
                lo = np.minimum(at.astype(np.intp), len(self._grid) - 2)
                f = (at - lo)[..., None]
                way += bends[slot[:, None], lo] * (1.0 - f) + bends[slot[:, None], lo + 1] * f
            q = dij[:, None, :] + vo[:, None, :] * taus[..., None] - way
            inside = (np.hypot(q[..., 0], q[..., 1]) < reach_xy) & (np.abs(q[..., 2]) < reach_z)
            touch = inside.any(axis=1)
            # its speed towards the other: on its way to where they would touch (or its velocity's, touching now)
            first = np.argmax(inside[:, 1:], axis=1) + 1
            rows = np.arange(len(i))
            towards = np.where(inside[:, 1:].any(axis=1),
                               np.einsum("ij,ij->i", way[rows, first], unit) / np.maximum(taus[rows, first], 1e-9),
                               np.einsum("ij,ij->i", vs, unit))
            for m in np.nonzero(touch & (towards > p.closing_speed))[0].tolist():
                gap = max(float(across[m]) - 2.0 * radius, float(abs(dij[m, 2])) - height)
                pair = (movers[i[m]], self.vids[j[m]])
                if pair not in hits or hits[pair].speed < towards[m]:
                    hits[pair] = Closing(*pair, gap, float(towards[m]), tuple(vs[m].tolist()), tuple(vo[m].tolist()),
                                         react)
        return sorted(hits.values(), key=lambda h: h.gap)
