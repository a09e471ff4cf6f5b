"""Pose estimator: a Kalman filter on motion-capture position and yaw (paper 000 §VI-B: "A Kalman
filter with position and yaw estimates from a Vicon motion capture system is used to estimate the
state of the robots").

State [x, y, z, vx, vy, vz, yaw, yaw_rate], constant-velocity model driven by white acceleration
noise (filterpy's `KalmanFilter`). A pose whose innovation has a squared Mahalanobis distance above
the chi-square gate is rejected as an outlier; between poses the estimate is extrapolated, so short
dropouts are bridged; when the predicted position standard deviation exceeds `stale_std` the
pose is "stale" and the state machine must stop trusting it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from common.messages import Pose
from services.executor.trajectory import wrap_angle


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    """pos_std / yaw_std: mocap noise (m, rad); accel_std / yaw_accel_std: process noise (m/s^2,
    rad/s^2; a wheel base turning in place reaches tens of rad/s^2); gate: chi-square threshold on
    the 4-dof innovation (99.9 % -> 18.47); stale_std: predicted position std (m) above which the
    pose is stale (about 0.25 s without poses); reacquire_after: consecutive rejected poses after
    which the filter restarts from the newest one (the rejected ones were the truth)."""

    pos_std: float = 0.002
    yaw_std: float = math.radians(1.0)
    accel_std: float = 3.0
    yaw_accel_std: float = 30.0
    gate: float = 18.47
    stale_std: float = 0.10
    reacquire_after: int = 25


@dataclass(frozen=True, slots=True)
class Estimate:
    """The state extrapolated to a query time, with its position std (m) and staleness."""

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


class PoseEstimator:
    """Constant-velocity Kalman filter over mocap poses of one vehicle."""

    def __init__(self, params: EstimatorParams = EstimatorParams()) -> None:
        self.params = params
        kf = KalmanFilter(dim_x=8, dim_z=4)
        kf.H = np.zeros((4, 8))
        kf.H[0, 0] = kf.H[1, 1] = kf.H[2, 2] = kf.H[3, 6] = 1.0
        kf.R = np.diag([params.pos_std**2] * 3 + [params.yaw_std**2])
        self.kf = kf
        self.t: float | None = None
        self.accepted = 0
        self.rejected = 0
        self._rejected_run = 0
        self._models: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def initialised(self) -> bool:
        return self.t is not None

    def _model(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """F and Q for a step of `dt` s, cached per 0.1 ms (poses come at a near-constant rate)."""
        key = round(dt, 4)
        cached = self._models.get(key)
        if cached is None:
            f = np.eye(8)
            f[0, 3] = f[1, 4] = f[2, 5] = f[6, 7] = key
            q = np.zeros((8, 8))
            qa = Q_discrete_white_noise(2, dt=key, var=self.params.accel_std**2)
            for axis in range(3):
                idx = np.ix_([axis, axis + 3], [axis, axis + 3])
                q[idx] = qa
            q[np.ix_([6, 7], [6, 7])] = Q_discrete_white_noise(2, dt=key, var=self.params.yaw_accel_std**2)
            if len(self._models) > 64:
                self._models.clear()
            cached = self._models[key] = (f, q)
        return cached

    def reset(self, pose: Pose) -> None:
        """Start over at `pose`, at rest."""
        p = self.params
        self.kf.x = np.array([[pose.x], [pose.y], [pose.z], [0.0], [0.0], [0.0], [pose.yaw], [0.0]])
        self.kf.P = np.diag([p.pos_std**2] * 3 + [0.1**2] * 3 + [p.yaw_std**2, 0.5**2])
        self.t = pose.t

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
        f, q = self._model(dt)
        kf.predict(F=f, Q=q)
        self.t = pose.t
        yaw_est = kf.x[6, 0]
        kf.update(np.array([[pose.x], [pose.y], [pose.z], [yaw_est + wrap_angle(pose.yaw - yaw_est)]]))
        if kf.mahalanobis**2 > self.params.gate:
            # outlier: back to the prediction (filterpy keeps it in x_prior / P_prior)
            kf.x, kf.P = kf.x_prior.copy(), kf.P_prior.copy()
            self.rejected += 1
            self._rejected_run += 1
            if self._rejected_run >= self.params.reacquire_after:
                self.reset(pose)
                self._rejected_run = 0
            return False
        self._rejected_run = 0
        kf.x[6, 0] = wrap_angle(kf.x[6, 0])
        self.accepted += 1
        return True

    def pos_std(self, now: float) -> float:
        """Largest per-axis position std (m) predicted at `now`; inf before the first pose."""
        if self.t is None:
            return math.inf
        dt = max(now - self.t, 0.0)
        p = self.kf.P
        qa = self.params.accel_std**2
        var = max(p[i, i] + 2.0 * dt * p[i, i + 3] + dt * dt * p[i + 3, i + 3] for i in range(3))
        return math.sqrt(var + qa * dt**4 / 4.0)

    def estimate(self, now: float) -> Estimate:
        """The state extrapolated (constant velocity) to `now`, without changing the filter."""
        if self.t is None:
            return Estimate(now, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, math.inf, True)
        dt = max(now - self.t, 0.0)
        x = self.kf.x[:, 0].tolist()
        std = self.pos_std(now)
        return Estimate(now, x[0] + x[3] * dt, x[1] + x[4] * dt, x[2] + x[5] * dt, x[3], x[4], x[5],
                        wrap_angle(x[6] + x[7] * dt), x[7], std, std > self.params.stale_std)
