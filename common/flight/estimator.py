"""Pose estimator: a Kalman filter on motion-capture position and yaw (paper 000 §VI-B: "A Kalman
filter with position and yaw estimates from a Vicon motion capture system is used to estimate the
state of the robots").

State [x, y, z, vx, vy, vz, yaw, yaw_rate], constant-velocity model driven by the acceleration the
controller commands (`set_input`, the B u of the prediction) plus white acceleration noise. A pose
whose innovation has a squared Mahalanobis distance above the chi-square gate is rejected as an
outlier. Between poses the state is dead-reckoned with the commanded accelerations, so short
dropouts are bridged and a controller acting on the prediction sees the response to its own
commands (no runaway on a stale velocity). A pose arrives after its capture (tens of ms, more on a
loaded machine) while the commands go on changing, so the estimator keeps the commands since the last
pose: a pose is predicted to with their time-weighted mean, and the state from the pose to now is
dead-reckoned through each of them; the yaw is predicted at the yaw rates a flight controller
commanded since the pose, like the position (`PoseEstimator._yaw_at`). (With only the last command, as before, a controller
saturating back and forth on 120 ms old poses had its estimate 0.39 m/s off, `tests/test_estimator.py`;
in a 32-vehicle soak an executor estimated 0.9 m/s up for a vehicle that hovered.) When the
predicted position standard deviation exceeds `stale_std` the pose is "stale" and the state machine
must stop trusting it.

F, Q, R and the initial P never couple x, y, z and yaw, so the 8-state filter is exactly four
independent 2-state filters (value, rate). `KalmanBank` runs them for many vehicles at once in
numpy arrays (the executor fuses a whole motion-capture frame in one call: issue 15's hot path);
`PoseEstimator` is one vehicle's slot in a bank (its own bank when alone). The filter equations are
filterpy's `KalmanFilter.predict`/`update` (Joseph form) written per axis; a test runs filterpy's
8-state filter beside it and finds the same states.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import msgspec
import numpy as np

from common.bus.messages import Pose
from common.domain.vehicle_model import G
from common.flight.reference import wrap_angle

INPUT_HISTORY_S = 1.0
"""s: the commands kept for poses yet to come (older ones are taken as one: a pose later than this
after the last has a prediction too uncertain to matter)."""

Accel = tuple[float, float, float]

LIFT_LEARN_S = 0.5
"""s: time constant of `PoseEstimator.lift_error`."""
LIFT_ERROR_MAX = 0.2
"""The largest lift error learned (a thrust model a fifth off is a fault, not a model's error)."""
LIFT_LEARN_HEIGHT = 0.05
"""m above its floor from which the lift error learns (nearer the ground its lift is the ground
effect's too)."""
LIFT_LATE_S = 0.05
"""s: a command given on a pose older than this comes from a late loop (`PoseEstimator.command`),
whose thrust commands teach the lift error only while held steady."""
LIFT_STEADY_ACCEL, LIFT_STEADY_S, LIFT_SMOOTH_S = 1.5, 0.1, 0.1
"""A late loop's thrust commands are steady once their vertical acceleration (smoothed over
`LIFT_SMOOTH_S` s: a hover's commands jitter +-1 m/s^2 on the motion capture's noise) has stayed
within `LIFT_STEADY_ACCEL` m/s^2 of one value for `LIFT_STEADY_S` s."""
LIFT_LEARN_GAP_S = 0.1
"""s: a pose later than this after the last teaches no lift error (a gap's prediction holds more
than the thrust model's error)."""


def felt(accel: Accel, aloft: bool) -> Accel:
    """The part of a commanded acceleration that moves the vehicle: all of it aloft; on the ground,
    which holds it, only thrust above its weight, up (an estimate that took none stayed on the
    ground while the vehicle climbed; one that took all fell on through the floor)."""
    return accel if aloft else (0.0, 0.0, max(accel[2], 0.0))


def _reckoned(x: Sequence[float], a: Accel, dt: float) -> list[float]:
    """Position and velocity `x` (x, y, z, vx, vy, vz) after `dt` s at constant acceleration `a`."""
    if dt <= 0.0:
        return list(x)
    return [x[0] + (x[3] + 0.5 * a[0] * dt) * dt, x[1] + (x[4] + 0.5 * a[1] * dt) * dt,
            x[2] + (x[5] + 0.5 * a[2] * dt) * dt, x[3] + a[0] * dt, x[4] + a[1] * dt, x[5] + a[2] * dt]


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    """pos_std / yaw_std: mocap noise (m, rad); accel_std / yaw_accel_std: process noise (m/s^2,
    rad/s^2; a wheel base turning in place reaches 120 rad/s^2, 6 rad/s through its wheels' 0.05 s
    lag, and twice that reversing a turn, but 150, on the wheels alone or everywhere, made the yaw
    rate too noisy to extrapolate over a slow loop's old poses: the slow flights of
    tests/test_tracking_guard.py tracked worse); gate: chi-square threshold on
    the 4-dof innovation (99.9 % -> 18.47); stale_std: predicted position std (m) above which the
    pose is stale (about 0.4 s without poses: 3 m/s^2 of process noise is conservative, and the
    closed loop stayed within 2 cm of its reference through 0.5 s dropouts in the air, so a 0.3 s
    dropout is flown through on the prediction); reacquire_after, reacquire_s: after this many
    consecutive rejected poses spanning at least this long the filter restarts from the newest one,
    moving as the rejected ones did (they were the truth: the prediction had gone wrong, e.g. on
    accelerations commanded over a link that was down). 25 poses (0.25 s) let a vehicle climb 1 m
    between restarts at rest; 10 poses, 0.1 s at 100 Hz, took 0.6 s on a loaded machine's 15 poses
    a second (a soak vehicle's estimate went 1.7 m off while it counted as fresh); now 3 poses
    and 0.08 s."""

    pos_std: float = 0.002
    yaw_std: float = math.radians(1.0)
    accel_std: float = 3.0
    yaw_accel_std: float = 30.0
    gate: float = 18.47
    stale_std: float = 0.25
    reacquire_after: int = 3
    reacquire_s: float = 0.08


class Estimate(msgspec.Struct, frozen=True, gc=False):
    """The state predicted to a query time, with its position std (m) and staleness. (A struct, not
    a frozen dataclass: one or two are made per vehicle and control tick, ten times faster.)"""

    t: float
    x: float
    y: float
    z: float
    vx: float
    vy: float
    vz: float
    yaw: float
    yaw_rate: float
    pos_std: float
    stale: bool


class KalmanBank:
    """The four per-axis filters (x, y, z, yaw: value and rate, covariance Ppp, Ppv, Pvv) of up to
    `capacity` vehicles (it grows), one slot each."""

    def __init__(self, params: EstimatorParams, capacity: int = 8) -> None:
        self.params = params
        self.x = np.zeros((capacity, 4, 2))
        self.p = np.zeros((capacity, 4, 3))
        self._free = list(range(capacity - 1, -1, -1))
        self._r = np.array([params.pos_std**2] * 3 + [params.yaw_std**2])
        self._q = np.array([params.accel_std**2] * 3 + [params.yaw_accel_std**2])

    def allocate(self) -> int:
        if not self._free:
            n = len(self.x)
            self.x = np.concatenate([self.x, np.zeros_like(self.x)])
            self.p = np.concatenate([self.p, np.zeros_like(self.p)])
            self._free = list(range(2 * n - 1, n - 1, -1))
        return self._free.pop()

    def release(self, slot: int) -> None:
        self._free.append(slot)

    def reset(self, slot: int, value: Sequence[float], rate: Sequence[float]) -> None:
        """Slot `slot` starts at `value` (x, y, z, yaw) moving at `rate` (vx, vy, vz, yaw rate)."""
        p = self.params
        self.x[slot, :, 0] = value
        self.x[slot, :, 1] = rate
        self.p[slot] = 0.0
        self.p[slot, :3, 0], self.p[slot, :3, 2] = p.pos_std**2, 0.1**2
        self.p[slot, 3, 0], self.p[slot, 3, 2] = p.yaw_std**2, 0.5**2

    def update(self, slots: np.ndarray, dt: np.ndarray, z: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Predict slots `slots` by `dt` (s, each) with the accelerations `u` (M x 3, world frame),
        then fuse the measurements `z` (M x 4: x, y, z, yaw). A measurement outside the gate leaves
        its slot at the prediction. Whether each was accepted."""
        x, p = self.x[slots], self.p[slots]
        dt1 = dt[:, None]
        dt2 = dt1 * dt1
        accel = np.zeros((len(slots), 4))
        accel[:, :3] = u
        value = x[:, :, 0] + x[:, :, 1] * dt1 + 0.5 * accel * dt2
        rate = x[:, :, 1] + accel * dt1
        q = self._q
        ppp = p[:, :, 0] + 2.0 * dt1 * p[:, :, 1] + dt2 * p[:, :, 2] + q * dt2 * dt2 / 4.0
        ppv = p[:, :, 1] + dt1 * p[:, :, 2] + q * dt2 * dt1 / 2.0
        pvv = p[:, :, 2] + q * dt2
        innovation = z - value
        innovation[:, 3] = np.remainder(innovation[:, 3] + math.pi, 2.0 * math.pi) - math.pi
        s = ppp + self._r
        accepted = np.sum(innovation * innovation / s, axis=1) <= self.params.gate
        kp, kv = ppp / s, ppv / s
        a = 1.0 - kp  # Joseph form, as filterpy: P = (I - KH) P (I - KH)' + K R K'
        kr = self._r
        new = np.empty_like(x)
        new[:, :, 0] = value + kp * innovation
        new[:, :, 1] = rate + kv * innovation
        new[:, 3, 0] = np.remainder(new[:, 3, 0] + math.pi, 2.0 * math.pi) - math.pi
        new_p = np.empty_like(p)
        new_p[:, :, 0] = a * a * ppp + kp * kp * kr
        new_p[:, :, 1] = a * (ppv - kv * ppp) + kp * kv * kr
        new_p[:, :, 2] = pvv - 2.0 * kv * ppv + kv * kv * (ppp + kr)
        keep = accepted[:, None]
        self.x[slots, :, 0] = np.where(keep, new[:, :, 0], value)
        self.x[slots, :, 1] = np.where(keep, new[:, :, 1], rate)
        self.p[slots] = np.where(keep[:, :, None], new_p, np.stack([ppp, ppv, pvv], axis=2))
        return accepted


class PoseEstimator:
    """The Kalman filter of one vehicle's mocap poses, with the commanded acceleration as input: a
    slot of `bank` (shared with the other vehicles of an executor, for `fuse_frame`), or of its own."""

    def __init__(self, params: EstimatorParams = EstimatorParams(), bank: KalmanBank | None = None) -> None:
        if bank is not None and bank.params != params:
            raise ValueError("an estimator's parameters must be its bank's")
        self.params = params
        self.bank = bank if bank is not None else KalmanBank(params, capacity=1)
        self.slot = self.bank.allocate()
        weakref.finalize(self, self.bank.release, self.slot)
        self.t: float | None = None
        self.accepted = 0
        self.rejected = 0
        self.restarts = 0
        """Restarts from rejected poses (`EstimatorParams.reacquire_s`)."""
        self._rejected_run = 0
        self._rejected_first: Pose | None = None  # the first pose of the current rejected run
        self._accel: Accel = (0.0, 0.0, 0.0)
        self._input_base: Accel = (0.0, 0.0, 0.0)  # the command in force before the first of `_inputs`
        self._inputs: list[tuple[float, Accel]] = []  # (from when, acceleration), since the last pose
        self._yaw_from: tuple[float, float, float | None] = (0.0, 0.0, None)
        """The yaw predicted from: (time, yaw then, the yaw rate commanded from then on, None for none)."""
        self._yaw_inputs: list[tuple[float, float | None]] = []  # (from when, yaw rate or None), since `_yaw_from`
        self._unlearned_until = math.inf  # the end of the last input that teaches no lift error (inf: in force)
        self._steady: tuple[float, float] = (-math.inf, math.inf)  # (since, vertical acceleration) commanded steadily
        self._smooth: tuple[float, float] | None = None  # (when, the thrust commands' vertical acceleration smoothed)
        self.floor: float | None = None
        """Height (m) the vehicle cannot be below, set by its controller (the ground where it takes
        off or lands; else the lowest ground there is): the dead reckoning and the filter's state
        stop there. (Without it a vehicle that touched down falling, or bounced in a take-off on
        late poses, was estimated falling on through the floor, the poses that showed it on the
        ground rejected as outliers of that prediction, and controllers acted on it: climbs, motors
        stopped in the air.)"""
        self._dr_t = 0.0  # dead reckoning since the last pose: time, position, velocity
        self._dr = [0.0] * 6
        self._seen_yaw_rate = 0.0  # the filter's yaw rate at the last pose
        self._pos_cov: Sequence[float] = ()  # per axis x, y, z: P_pp, P_pv, P_vv at the last pose
        self._noise_dt4 = params.accel_std**2 / 4.0  # `pos_std`: the process noise adds (accel_std dt^2 / 2)^2 = this x dt^4
        self.lift_error = 0.0
        """The fraction of its thrust a thrust command gives beyond what its controller expects
        (`command`): the thrust model's error (battery, propellers, payload), learned aloft from the
        vertical velocity corrections the poses make (each, divided by g, adds itself over
        `LIFT_LEARN_S`: with a thrust a fraction k off the corrections come to k g' per second, g'
        the thrust's acceleration, and they sum to nothing once k is learned; divided by each
        interval's own g' instead, corrections that follow the thrust's swings, late by the motors'
        lag, did not, and a slow loop learned a 10 % error as 3-6 %). The predictions add it. A
        fraction, not an acceleration: a take-off's thrust is 1.5 times a hover's, and its error
        with it. On a late loop only steady commands teach it (`_teaches`). (The flight
        controller's settled integrator stood in for it, learned only on its reference: a vehicle
        10 % stronger than its model that lost its poses a second or two after lift-off descended
        blind on a thrust that climbed, to 2-7 m, its motors stopped there.)"""

    def reset(self, pose: Pose, velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """Start over at `pose`, at rest or at `velocity` (m/s)."""
        self.bank.reset(self.slot, (pose.x, pose.y, pose.z, pose.yaw), (*velocity, 0.0))
        self.t = pose.t
        self._restart_dead_reckoning(self.bank.x[self.slot].ravel().tolist(), self.bank.p[self.slot].ravel().tolist())

    def _restart_dead_reckoning(self, x: Sequence[float], p: Sequence[float]) -> None:
        """From the slot's state `x` and covariance `p` at the pose's time (flattened: per axis x,
        y, z, yaw its value and rate, and its Ppp, Ppv, Pvv), through the commands given since then."""
        assert self.t is not None
        self._dr_t = self.t
        self._dr = [x[0], x[2], x[4], x[1], x[3], x[5]]
        self._seen_yaw_rate = x[7]
        self._pos_cov = p[:9]
        while self._inputs and self._inputs[0][0] <= self.t:
            self._input_base = self._inputs.pop(0)[1]
        commanded = self._yaw_from[2]
        while self._yaw_inputs and self._yaw_inputs[0][0] <= self.t:
            commanded = self._yaw_inputs.pop(0)[1]
        self._yaw_from = (self.t, x[6], commanded)
        a = self._input_base
        for t, accel in self._inputs:
            self._dr, self._dr_t, a = self._floored(_reckoned(self._dr, a, t - self._dr_t)), t, accel
        self._accel = a

    def _floored(self, x: list[float]) -> list[float]:
        """Dead-reckoned `x` held at `floor`: on it, not sinking."""
        if self.floor is not None and x[2] < self.floor:
            x[2], x[5] = self.floor, max(x[5], 0.0)
        return x

    def _reckon(self, now: float) -> list[float]:
        """Position and velocity dead-reckoned from the last pose to `now` (no change of state)."""
        return self._floored(_reckoned(self._dr, self._accel, now - self._dr_t))

    def mean_input(self, until: float) -> Accel:
        """The commanded acceleration averaged over the time from the last pose to `until`."""
        start = self.t if self.t is not None else until
        if until <= start:
            return self._accel
        sx = sy = sz = 0.0  # (per axis, written out: once per vehicle and frame)
        a, t0 = self._input_base, start
        for t, accel in self._inputs:
            if t >= until:
                break
            d = t - t0
            sx, sy, sz = sx + a[0] * d, sy + a[1] * d, sz + a[2] * d
            a, t0 = accel, t
        d, span = until - t0, until - start
        return ((sx + a[0] * d) / span, (sy + a[1] * d) / span, (sz + a[2] * d) / span)

    def set_input(self, accel: Accel, now: float, learn: bool = False, yaw_rate: float | None = None) -> None:
        """The acceleration (world frame, m/s^2) the vehicle is commanded from `now` on; with
        `learn`, the poses that follow teach `lift_error`; `yaw_rate`: the yaw rate (rad/s) a flight
        controller's command gives it from `now` on (None: its yaw is predicted at the rate the
        poses show, `estimate`)."""
        if self.t is not None and now > self._dr_t:
            self._dr, self._dr_t = self._reckon(now), now
        self._accel = accel
        if self._unlearned_until == math.inf:  # the input it replaces taught nothing until now
            self._unlearned_until = now
        if not learn:
            self._unlearned_until = math.inf
        self._inputs.append((now, accel))
        while self._inputs and self._inputs[0][0] < now - INPUT_HISTORY_S:
            self._input_base = self._inputs.pop(0)[1]
        self._yaw_inputs.append((now, yaw_rate))
        while self._yaw_inputs and self._yaw_inputs[0][0] < now - INPUT_HISTORY_S:  # (no pose for a while)
            since, commanded = self._yaw_inputs.pop(0)
            self._yaw_from = (since, self._yaw_at(since)[0], commanded)

    def command(self, accel: Accel, now: float, aloft: bool, learn: bool = True,
                yaw_rate: float | None = None) -> None:
        """The acceleration a thrust command is expected to give from `now` on (a flight
        controller's), with the lift error learned added; on the ground only what lifts it (`felt`).
        The poses that follow teach the lift error if it is `aloft` and `learn`s (not a command
        sent blind, or at a cap its model does not know). `yaw_rate`: the yaw rate it gives (rad/s)."""
        ax, ay, az = accel
        teaches = self._teaches(az, now, aloft)
        self.set_input(felt((ax, ay, az + self.lift_error * (G + az)), aloft), now, learn=aloft and learn and teaches,
                       yaw_rate=yaw_rate if aloft else None)

    def _teaches(self, az: float, now: float, aloft: bool) -> bool:
        """Whether a thrust command for vertical acceleration `az` given at `now` may teach the lift
        error: on a recent pose (`LIFT_LATE_S`), or steady (`LIFT_STEADY_ACCEL`). The predictions
        count a command from its tick, but it acts tens of milliseconds later (`ACTUATION_S`), more
        on a late loop: the thrust's changes within that lag show in the poses as a thrust-model
        error. On a loop whose poses were 0.1 s old, ticking every other period, its commands
        acting 60 ms late, a model-true vehicle's lift error learned the swings of its height loop
        (0.09, where there was none) and fed them back: its height swung 23 cm peak to peak in
        level flight, 10-12 with only steady commands teaching (`tests/test_closed_loop.py`). A loop
        that turns late teaches from its first 0.1 s of steady commands on."""
        if not aloft or now - (self.t or now) <= LIFT_LATE_S:
            self._smooth = None
            return True
        smooth = self._smooth
        if smooth is None:  # late from now on: steady from now on
            self._smooth = self._steady = (now, az)
            return False
        smoothed = smooth[1] + min((now - smooth[0]) / LIFT_SMOOTH_S, 1.0) * (az - smooth[1])
        self._smooth = (now, smoothed)
        if abs(smoothed - self._steady[1]) > LIFT_STEADY_ACCEL:
            self._steady = (now, smoothed)
        return now - self._steady[0] >= LIFT_STEADY_S

    def update(self, pose: Pose) -> bool:
        """Fuse one pose; False if it was dropped (out of order) or rejected by the gate."""
        return fuse_poses([self], [pose])[0]

    def _fused(self, pose: Pose, accepted: bool, x: list[float], p: list[float], dvz: float,
               lift: float) -> None:
        """After the bank fused `pose` into this slot (state `x`, covariance `p` now, flattened as
        `_restart_dead_reckoning` takes them; `dvz` the vertical velocity correction it made, `lift`
        the thrust's acceleration, m/s^2, it was predicted with): counts, the lift error, and the
        restart after `reacquire_after` rejected poses in a row."""
        last = self.t
        assert last is not None  # fuse_poses resets an estimator on its first pose instead
        learns = (self._unlearned_until <= last and pose.t - last <= LIFT_LEARN_GAP_S
                  and lift > 0.5 * G and x[4] > (self.floor or 0.0) + LIFT_LEARN_HEIGHT)
        self.t = pose.t
        if accepted:
            if learns:  # every input since the last pose taught it, and that pose was recent
                k = self.lift_error + dvz / (G * LIFT_LEARN_S)
                self.lift_error = min(max(k, -LIFT_ERROR_MAX), LIFT_ERROR_MAX)
            self._rejected_run = 0
            self._rejected_first = None
            self.accepted += 1
        else:
            self.rejected += 1
            self._rejected_run += 1
            first = self._rejected_first = self._rejected_first or pose
            span = pose.t - first.t
            if self._rejected_run >= self.params.reacquire_after and span >= self.params.reacquire_s:
                self.restarts += 1
                self._rejected_run = 0
                self._rejected_first = None
                self.reset(pose, ((pose.x - first.x) / span, (pose.y - first.y) / span, (pose.z - first.z) / span))
                return
        if self.floor is not None and x[4] < self.floor:  # the filter's state too: on it, not sinking
            x[4], x[5] = self.floor, max(x[5], 0.0)
            self.bank.x[self.slot, 2] = x[4:6]
        self._restart_dead_reckoning(x, p)

    def pos_std(self, now: float) -> float:
        """Largest per-axis position std (m) predicted at `now`; inf before the first pose."""
        if self.t is None:
            return math.inf
        dt = max(now - self.t, 0.0)
        c, dt2 = self._pos_cov, dt * dt
        var = max(c[0] + 2.0 * dt * c[1] + dt2 * c[2], c[3] + 2.0 * dt * c[4] + dt2 * c[5],
                  c[6] + 2.0 * dt * c[7] + dt2 * c[8])
        return math.sqrt(var + self._noise_dt4 * dt2 * dt2)

    def estimate(self, now: float) -> Estimate:
        """The state predicted to `now` (dead reckoning since the last pose), without changing the filter."""
        if self.t is None:
            return Estimate(now, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, math.inf, True)
        px, py, pz, vx, vy, vz = self._reckon(now)
        yaw, yaw_rate = self._yaw_at(now)
        std = self.pos_std(now)
        return Estimate(now, px, py, pz, vx, vy, vz, yaw, yaw_rate, std, std > self.params.stale_std)

    def ahead(self, est: Estimate, dt: float) -> Estimate:
        """`est` (this estimator's, at `est.t`) carried `dt` s on at the acceleration commanded last
        and its yaw rate: `estimate(est.t + dt)` while no command comes meanwhile, at a fraction of
        its cost (a controller leading its commands' delay asks for it every tick)."""
        ax, ay, az = self._accel
        x = self._floored([est.x + (est.vx + 0.5 * ax * dt) * dt, est.y + (est.vy + 0.5 * ay * dt) * dt,
                           est.z + (est.vz + 0.5 * az * dt) * dt, est.vx + ax * dt, est.vy + ay * dt, est.vz + az * dt])
        return Estimate(est.t + dt, *x, wrap_angle(est.yaw + est.yaw_rate * dt), est.yaw_rate, est.pos_std, est.stale)

    def _yaw_at(self, now: float) -> tuple[float, float]:
        """Yaw and yaw rate predicted to `now` from the last pose: at the yaw rates a flight
        controller commanded since (`set_input`), else at the rate the poses show. (At the poses'
        rate alone, a vehicle turning to its heading at the top of a take-off on 0.2 s old poses
        had its yaw estimated 60-100 deg behind, and the yaw loop swung it +-50 deg at 500 deg/s
        while its tilt was turned the wrong way: it flew off by metres.)"""
        seen_rate = self._seen_yaw_rate
        t, yaw, rate = self._yaw_from
        for since, commanded in self._yaw_inputs:
            if since >= now:
                break
            yaw += (seen_rate if rate is None else rate) * (since - t)
            t, rate = since, commanded
        rate = seen_rate if rate is None else rate
        return wrap_angle(yaw + rate * max(now - t, 0.0)), rate


def fuse_poses(estimators: Sequence[PoseEstimator], poses: Sequence[Pose]) -> list[bool]:
    """Fuse `poses[i]` into `estimators[i]`, those that share a bank in one vectorised step; False
    for a pose dropped (not newer than its estimator's last) or rejected by the gate."""
    out = [False] * len(estimators)
    groups: dict[int, list[int]] = {}
    for i, (est, pose) in enumerate(zip(estimators, poses, strict=True)):
        if est.t is None:
            est.reset(pose)
            est.accepted += 1
            out[i] = True
        elif pose.t > est.t:
            groups.setdefault(id(est.bank), []).append(i)
    for members in groups.values():
        bank = estimators[members[0]].bank
        ests = [estimators[i] for i in members]
        ps = [poses[i] for i in members]
        slots = np.fromiter((e.slot for e in ests), np.intp, len(ests))
        dt = np.fromiter((p.t - (e.t or 0.0) for e, p in zip(ests, ps, strict=True)), float, len(ests))
        z = np.array([(p.x, p.y, p.z, p.yaw) for p in ps])
        inputs = [e.mean_input(p.t) for e, p in zip(ests, ps, strict=True)]
        u = np.array(inputs)
        prior_vz = bank.x[slots, 2, 1] + u[:, 2] * dt
        accepted = bank.update(slots, dt, z, u).tolist()
        xs, covs = bank.x[slots].reshape(len(slots), 8).tolist(), bank.p[slots].reshape(len(slots), 12).tolist()
        dvz = (bank.x[slots, 2, 1] - prior_vz).tolist()
        for k, i in enumerate(members):
            estimators[i]._fused(poses[i], accepted[k], xs[k], covs[k], dvz[k], G + inputs[k][2])
            out[i] = accepted[k]
    return out
