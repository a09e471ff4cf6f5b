"""Pose estimator: a Kalman filter on motion-capture position and yaw (paper 000 §VI-B: "A Kalman
filter with position and yaw estimates from a Vicon motion capture system is used to estimate the
state of the robots").

State [x, y, z, vx, vy, vz, yaw, yaw_rate], constant-velocity model (filterpy's `KalmanFilter`)
driven by the acceleration the controller commands (`set_input`, the B u of the prediction) plus
white acceleration noise. A pose whose innovation has a squared Mahalanobis distance above the
chi-square gate is rejected as an outlier. Between poses the state is dead-reckoned with the
commanded accelerations, so short dropouts are bridged and a controller acting on the prediction
sees the response to its own commands (no runaway on a stale velocity); when the predicted position
standard deviation exceeds `stale_std` the pose is "stale" and the state machine must stop
trusting it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from common.bus.messages import Pose
from common.flight.reference import wrap_angle


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    """pos_std / yaw_std: mocap noise (m, rad); accel_std / yaw_accel_std: process noise (m/s^2,
    rad/s^2; a wheel base turning in place reaches tens of rad/s^2); gate: chi-square threshold on
    the 4-dof innovation (99.9 % -> 18.47); stale_std: predicted position std (m) above which the
    pose is stale (about 0.4 s without poses: 3 m/s^2 of process noise is conservative, and the
    closed loop stayed within 2 cm of its reference through 0.5 s dropouts in the air, so a 0.3 s
    dropout is flown through on the prediction); reacquire_after: consecutive rejected poses after
    which the filter restarts from the newest one, moving as the rejected ones did (they were the
    truth: the prediction had gone wrong, e.g. on accelerations commanded over a link that was
    down). 25 (0.25 s) let a vehicle climb 1 m between restarts at rest; 10 (0.1 s) now."""

    pos_std: float = 0.002
    yaw_std: float = math.radians(1.0)
    accel_std: float = 3.0
    yaw_accel_std: float = 30.0
    gate: float = 18.47
    stale_std: float = 0.25
    reacquire_after: int = 10


@dataclass(frozen=True, slots=True)
class Estimate:
    """The state predicted to a query time, with its position std (m) and staleness."""

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


def _inverse_of_diagonal(s: np.ndarray) -> np.ndarray:
    """Inverse of the innovation covariance S = H P H' + R, which is diagonal here: the four
    measured quantities (x, y, z, yaw) belong to independent blocks of F, Q, R and the initial P,
    so P never couples them (a test checks it). 5x cheaper than numpy.linalg.inv on a 4x4."""
    return np.diag(1.0 / np.diagonal(s))


class PoseEstimator:
    """Kalman filter over mocap poses of one vehicle, with the commanded acceleration as input."""

    def __init__(self, params: EstimatorParams = EstimatorParams()) -> None:
        self.params = params
        kf = KalmanFilter(dim_x=8, dim_z=4, dim_u=3)
        kf.H = np.zeros((4, 8))
        kf.H[0, 0] = kf.H[1, 1] = kf.H[2, 2] = kf.H[3, 6] = 1.0
        kf.R = np.diag([params.pos_std**2] * 3 + [params.yaw_std**2])
        kf.inv = _inverse_of_diagonal
        self.kf = kf
        self.t: float | None = None
        self.accepted = 0
        self.rejected = 0
        self._rejected_run = 0
        self._rejected_first: Pose | None = None  # the first pose of the current rejected run
        self._models: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._accel = (0.0, 0.0, 0.0)
        self._u: np.ndarray | None = None  # the same as filterpy's control input (None: zero)
        self._dr_t = 0.0  # dead reckoning since the last pose: time, position, velocity
        self._dr = [0.0] * 6
        self._pos_cov: list[tuple[float, float, float]] = []  # per axis: P_pp, P_pv, P_vv at the last pose

    def _model(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """F, Q and B for a step of `dt` s, cached per 0.1 ms (poses come at a near-constant rate)."""
        key = round(dt, 4)
        cached = self._models.get(key)
        if cached is None:
            f = np.eye(8)
            f[0, 3] = f[1, 4] = f[2, 5] = f[6, 7] = key
            b = np.zeros((8, 3))
            q = np.zeros((8, 8))
            qa = Q_discrete_white_noise(2, dt=key, var=self.params.accel_std**2)
            for axis in range(3):
                b[axis, axis], b[axis + 3, axis] = 0.5 * key * key, key
                q[np.ix_([axis, axis + 3], [axis, axis + 3])] = qa
            q[np.ix_([6, 7], [6, 7])] = Q_discrete_white_noise(2, dt=key, var=self.params.yaw_accel_std**2)
            if len(self._models) > 64:
                self._models.clear()
            cached = self._models[key] = (f, q, b)
        return cached

    def reset(self, pose: Pose, velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """Start over at `pose`, at rest or at `velocity` (m/s)."""
        p = self.params
        vx, vy, vz = velocity
        self.kf.x = np.array([[pose.x], [pose.y], [pose.z], [vx], [vy], [vz], [pose.yaw], [0.0]])
        self.kf.P = np.diag([p.pos_std**2] * 3 + [0.1**2] * 3 + [p.yaw_std**2, 0.5**2])
        self.t = pose.t
        self._restart_dead_reckoning()

    def _restart_dead_reckoning(self) -> None:
        assert self.t is not None
        self._dr_t = self.t
        self._dr = self.kf.x[:6, 0].tolist()
        p = self.kf.P
        self._pos_cov = [(float(p[i, i]), float(p[i, i + 3]), float(p[i + 3, i + 3])) for i in range(3)]

    def _reckon(self, now: float) -> list[float]:
        """Position and velocity dead-reckoned from the last pose to `now` (no change of state)."""
        dt = now - self._dr_t
        x, a = self._dr, self._accel
        if dt <= 0.0:
            return x
        return [x[0] + (x[3] + 0.5 * a[0] * dt) * dt, x[1] + (x[4] + 0.5 * a[1] * dt) * dt,
                x[2] + (x[5] + 0.5 * a[2] * dt) * dt, x[3] + a[0] * dt, x[4] + a[1] * dt, x[5] + a[2] * dt]

    def set_input(self, accel: tuple[float, float, float], now: float) -> None:
        """The acceleration (world frame, m/s^2) the vehicle is commanded from `now` on."""
        if self.t is not None and now > self._dr_t:
            self._dr, self._dr_t = self._reckon(now), now
        self._accel = accel
        self._u = np.array([accel]).T if any(accel) else None

    def update(self, pose: Pose) -> bool:
        """Fuse one pose; False if it was dropped (out of order) or rejected by the gate."""
        if self.t is None:
            self.reset(pose)
            self.accepted += 1
            return True
        dt = pose.t - self.t
        if dt <= 0.0:
            return False
        kf = self.kf
        f, q, b = self._model(dt)
        kf.predict(u=self._u, B=b, F=f, Q=q)
        self.t = pose.t
        yaw_est = float(kf.x[6, 0])
        z = np.array([[pose.x], [pose.y], [pose.z], [yaw_est + wrap_angle(pose.yaw - yaw_est)]])
        kf.update(z, H=kf.H)  # z is already a column: passing H skips filterpy's reshaping
        accepted = kf.mahalanobis**2 <= self.params.gate
        if accepted:
            self._rejected_run = 0
            self._rejected_first = None
            self.accepted += 1
            kf.x[6, 0] = wrap_angle(float(kf.x[6, 0]))
        else:
            # outlier: back to the prediction (filterpy keeps it in x_prior / P_prior)
            kf.x, kf.P = kf.x_prior.copy(), kf.P_prior.copy()
            self.rejected += 1
            self._rejected_run += 1
            first = self._rejected_first = self._rejected_first or pose
            if self._rejected_run >= self.params.reacquire_after:
                span = pose.t - first.t
                self.reset(pose, ((pose.x - first.x) / span, (pose.y - first.y) / span, (pose.z - first.z) / span)
                           if span > 0.0 else (0.0, 0.0, 0.0))
                self._rejected_run = 0
                self._rejected_first = None
        self._restart_dead_reckoning()
        return accepted

    def pos_std(self, now: float) -> float:
        """Largest per-axis position std (m) predicted at `now`; inf before the first pose."""
        if self.t is None:
            return math.inf
        dt = max(now - self.t, 0.0)
        var = max(pp + 2.0 * dt * pv + dt * dt * vv for pp, pv, vv in self._pos_cov)
        return math.sqrt(var + self.params.accel_std**2 * dt**4 / 4.0)

    def estimate(self, now: float) -> Estimate:
        """The state predicted to `now` (dead reckoning since the last pose), without changing the filter."""
        if self.t is None:
            return Estimate(now, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, math.inf, True)
        px, py, pz, vx, vy, vz = self._reckon(now)
        yaw, yaw_rate = float(self.kf.x[6, 0]), float(self.kf.x[7, 0])
        std = self.pos_std(now)
        return Estimate(now, px, py, pz, vx, vy, vz, wrap_angle(yaw + yaw_rate * max(now - self.t, 0.0)),
                        yaw_rate, std, std > self.params.stale_std)
