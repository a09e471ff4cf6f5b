"""Pose estimator: constant-velocity Kalman filter on mocap position and yaw, with outlier gating,
prediction through dropouts and a covariance-based stale signal (000 §VI-B)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from common.bus.messages import Pose
from common.flight.estimator import PoseEstimator


def track(est: PoseEstimator, t0: float, t1: float, vel: tuple[float, float, float] = (0.2, -0.1, 0.05),
          yaw_rate: float = 0.0, noise: float = 0.001, seed: int = 1, yaw0: float = 0.0) -> None:
    rng = random.Random(seed)
    for k in range(round((t1 - t0) * 100)):
        t = t0 + k * 0.01
        est.update(Pose(vid="cf1", t=t, x=vel[0] * t + rng.gauss(0, noise), y=vel[1] * t + rng.gauss(0, noise),
                        z=vel[2] * t + rng.gauss(0, noise), yaw=yaw0 + yaw_rate * t + rng.gauss(0, 0.005)))


def test_before_any_pose_the_estimate_is_stale() -> None:
    est = PoseEstimator()
    assert est.estimate(0.0).stale
    assert est.pos_std(0.0) == math.inf


def mean_velocity(est: PoseEstimator, t0: float, t1: float, **motion) -> tuple[float, float, float, float]:
    """Track from t0 to t1 and average the velocity estimates of the last half second."""
    track(est, t0, t1 - 0.5, **motion)
    sums = [0.0, 0.0, 0.0, 0.0]
    for k in range(50):
        track(est, t1 - 0.5 + k * 0.01, t1 - 0.5 + (k + 1) * 0.01, seed=k, **motion)
        e = est.estimate(est.t or 0.0)
        sums = [s + v / 50 for s, v in zip(sums, (e.vx, e.vy, e.vz, e.yaw_rate), strict=True)]
    return sums[0], sums[1], sums[2], sums[3]


def test_converges_on_constant_velocity_motion() -> None:
    est = PoseEstimator()
    vx, vy, vz, _ = mean_velocity(est, 0.0, 3.0)
    assert (vx, vy, vz) == pytest.approx((0.2, -0.1, 0.05), abs=0.01)
    e = est.estimate(2.99)
    assert (e.x, e.y, e.z) == pytest.approx((0.598, -0.299, 0.1495), abs=0.003)
    assert not e.stale
    assert est.rejected == 0


def test_gross_outlier_is_rejected_and_does_not_move_the_estimate() -> None:
    est = PoseEstimator()
    track(est, 0.0, 2.0)
    before = est.estimate(2.0)
    assert not est.update(Pose(vid="cf1", t=2.0, x=0.4 + 0.3, y=-0.2, z=0.1, yaw=0.0))
    assert est.rejected == 1
    after = est.estimate(2.0)
    assert after.x == pytest.approx(before.x, abs=1e-9)
    assert est.update(Pose(vid="cf1", t=2.01, x=0.402, y=-0.201, z=0.1005, yaw=0.0))


def test_prediction_bridges_a_short_dropout_and_long_ones_go_stale() -> None:
    est = PoseEstimator()
    track(est, 0.0, 2.0)
    short = est.estimate(2.15)
    assert not short.stale
    assert short.x == pytest.approx(0.2 * 2.15, abs=0.005)
    assert est.estimate(2.6).stale
    track(est, 2.6, 2.8)  # poses are back
    assert not est.estimate(2.79).stale


def test_stale_threshold_is_a_covariance_bound() -> None:
    est = PoseEstimator()
    track(est, 0.0, 1.0)
    grows = [est.pos_std(1.0 + dt) for dt in (0.0, 0.1, 0.2, 0.3)]
    assert grows == sorted(grows)
    first_stale = next(dt for dt in (k * 0.01 for k in range(100)) if est.estimate(1.0 + dt).stale)
    assert est.pos_std(1.0 + first_stale) > est.params.stale_std >= est.pos_std(1.0 + first_stale - 0.01)
    assert 0.3 < first_stale < 0.5  # a 0.3 s dropout is bridged (docs/reliability.md)


def test_a_real_jump_is_reacquired() -> None:
    est = PoseEstimator()
    track(est, 0.0, 1.0, vel=(0.0, 0.0, 0.0))
    for k in range(est.params.reacquire_after + 5):  # the body really is 0.5 m away (mocap re-identified it)
        est.update(Pose(vid="cf1", t=1.0 + k * 0.01, x=0.5, y=0.0, z=0.0, yaw=0.0))
    assert est.estimate(1.3).x == pytest.approx(0.5, abs=0.01)


def test_a_prediction_gone_wrong_is_reacquired_moving_as_the_rejected_poses_did() -> None:
    """Accelerations fed in that the vehicle never got (commands over a lost link): the prediction
    leaves the poses, which are rejected until the filter restarts from them, at their velocity,
    not at rest (at rest, the controller chased a vehicle it believed still)."""
    est = PoseEstimator()
    track(est, 0.0, 1.0, vel=(0.0, 0.0, 0.0))
    est.set_input((0.0, 0.0, -20.0), 1.0)  # believed: falling hard; truth: climbing at 0.8 m/s
    t = 1.0
    while est.rejected < est.params.reacquire_after:  # until the restart
        t += 0.01
        est.update(Pose(vid="cf1", t=t, x=0.0, y=0.0, z=0.8 * (t - 1.0), yaw=0.0))
        assert t < 1.5, "never reacquired"
    e = est.estimate(t)
    assert e.vz == pytest.approx(0.8, abs=0.05) and e.z == pytest.approx(0.8 * (t - 1.0), abs=0.005)


def test_yaw_crossing_pi_is_smooth() -> None:
    est = PoseEstimator()
    *_, yaw_rate = mean_velocity(est, 0.0, 2.0, vel=(0.0, 0.0, 0.0), yaw_rate=1.0, yaw0=math.pi - 1.5)
    assert est.rejected == 0  # passing +pi at t = 1.5 is no outlier
    assert yaw_rate == pytest.approx(1.0, abs=0.05)
    e = est.estimate(1.99)
    assert math.cos(e.yaw - (math.pi - 1.5 + 1.99)) > 0.999
    assert -math.pi < e.yaw <= math.pi


def test_out_of_order_and_duplicate_poses_are_dropped() -> None:
    est = PoseEstimator()
    track(est, 0.0, 1.0)
    assert not est.update(Pose(vid="cf1", t=0.5, x=0.0, y=0.0, z=0.0, yaw=0.0))
    assert not est.update(Pose(vid="cf1", t=est.t or 0.0, x=0.0, y=0.0, z=0.0, yaw=0.0))


def test_measured_quantities_stay_uncoupled_so_the_innovation_covariance_is_diagonal() -> None:
    """The estimator inverts S = H P H' + R as a diagonal matrix; that holds only while P never
    couples x, y, z and yaw. Run it through motion, inputs, an outlier and a dropout and check."""
    est = PoseEstimator()
    track(est, 0.0, 1.0, yaw_rate=0.5)
    est.set_input((0.3, -0.2, 0.1), 1.0)
    track(est, 1.0, 1.5, yaw_rate=0.5)
    est.update(Pose(vid="cf1", t=1.5, x=5.0, y=0.0, z=0.0, yaw=0.0))
    track(est, 1.8, 2.0, yaw_rate=0.5)
    kf = est.kf
    s = kf.H @ kf.P @ kf.H.T + kf.R
    assert np.count_nonzero(s - np.diag(np.diagonal(s))) == 0
