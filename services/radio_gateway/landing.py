"""The gateway's safety landing: a flying vehicle whose commands went stale hovers, then lands, then
its motors stop (paper 000 §VI-C: the gateway is the last link to the vehicle, so it must not leave
one in the air when its executor goes silent).

- With poses (`vehicle/<vid>/pose`): the executor's own flight stack, reused: the Kalman filter
  (`PoseEstimator`, fed the accelerations the LQR commands) and the LQR (`FlightLqr`) hold the
  horizontal position and yaw where the landing began, hover `hover_s`, then descend at `speed`
  to z = 0; motors off below `touchdown_height`, or after resting `rest_s` on something higher
  (a helipad) with the reference well below.
- Without a trusted pose: level and open loop, the thrust scaled from the last flight setpoint
  (the hover thrust the executor had found): accelerate down at `accel` to `speed`, coast, brake
  to rest at the last known height's ground, motors off. With no pose ever seen the height is
  unknown: the descent is planned from `blind_height`, without the braking (the vehicle may be
  lower and already resting), and the motors stop when it would have reached the ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from common.messages import FlightSetpoint, Pose
from common.model import G
from common.thrust import thrust_command, thrust_newtons, to_flight_setpoint
from services.executor.estimator import Estimate, PoseEstimator
from services.executor.lqr import FlightLqr
from services.executor.modes import Mode
from services.executor.trajectory import RefSample
from services.radio_gateway.config import LandingParams
from services.radio_gateway.physics import FIRMWARE_MIN_THRUST

_LIFTOFF_HEIGHT = 0.01
"""m: below this the LQR integrators stay off (as in the executor)."""
_REST_SPEED = 0.05
"""m/s: slower than this counts as resting."""
_REST_GAP = 0.1
"""m: the reference this far below the vehicle while it rests means it sits on something."""


@dataclass(frozen=True, slots=True)
class OpenLoopDescent:
    """Vertical acceleration (m/s^2) against time of a level descent of `height` m: down at `accel`
    to `speed`, coast, and (`brake`) up at `accel` to rest at the ground; None once it is over."""

    height: float
    speed: float
    accel: float
    brake: bool

    @property
    def duration(self) -> float:
        ramp = self.speed / self.accel
        ramps = 2 if self.brake else 1
        coast = max(self.height - ramps * 0.5 * self.speed * ramp, 0.0) / self.speed
        return ramps * ramp + coast

    def accel_at(self, t: float) -> float | None:
        ramp = self.speed / self.accel
        if t >= self.duration:
            return None
        if t < ramp:
            return -self.accel
        if self.brake and t > self.duration - ramp:
            return self.accel
        return 0.0


class SafeLanding:
    """One vehicle's hover-then-land, started at `start` after `last` (the last flight setpoint sent).
    Feed it poses with `on_pose`; `step(now)` gives the next setpoint, or None once landed."""

    def __init__(self, start: float, last: FlightSetpoint | None, params: LandingParams, dt: float) -> None:
        self.params = params
        self.start = start
        self.estimator = PoseEstimator()
        self.lqr = FlightLqr(params.mass, dt=dt)
        self.hover_newtons = params.mass * G
        if last is not None and last.thrust >= FIRMWARE_MIN_THRUST:
            tilt = math.cos(math.radians(last.roll)) * math.cos(math.radians(last.pitch))
            self.hover_newtons = thrust_newtons(last.thrust) * tilt
        self.pose_at = -math.inf
        self.last_z: float | None = None
        self.closed_loop = False
        self._anchor: tuple[float, float, float, float, float] | None = None  # t, x, y, z, yaw
        self._resting_since: float | None = None
        self._open_loop: tuple[float, OpenLoopDescent] | None = None

    @property
    def descent_start(self) -> float:
        return self.start + self.params.hover_s

    def on_pose(self, pose: Pose, now: float) -> None:
        """A pose received at `now` (gateway clock)."""
        if self._open_loop is None and self.estimator.update(pose):
            self.pose_at = now
        self.last_z = pose.z

    def step(self, now: float) -> FlightSetpoint | None:
        if self._open_loop is None and now - self.pose_at <= self.params.pose_timeout_s:
            est = self.estimator.estimate(now)
            if not est.stale:
                return self._closed_loop(now, est)
        if self.closed_loop or now >= self.descent_start:
            return self._descend_open_loop(now)
        return self._level(0.0)  # hovering while the first poses come in

    def _closed_loop(self, now: float, est: Estimate) -> FlightSetpoint | None:
        p = self.params
        if self._anchor is None:
            self._anchor = (max(now, self.descent_start), est.x, est.y, est.z, est.yaw)
            self.lqr.reset()
        self.closed_loop = True
        t0, x0, y0, z0, yaw0 = self._anchor
        z_ref = max(z0 - p.speed * max(now - t0, 0.0), 0.0)
        vz_ref = -p.speed if 0.0 < z_ref < z0 else 0.0
        if est.z < p.touchdown_height or self._rests(now, est.z - z_ref, est.vz):
            return None
        ref = RefSample(t=now, x=x0, y=y0, z=z_ref, vx=0.0, vy=0.0, vz=vz_ref, ax=0.0, ay=0.0, az=0.0,
                        yaw=yaw0, yaw_rate=0.0, mode=Mode.LANDING, step=0)
        aloft = est.z > _LIFTOFF_HEIGHT
        sp = self.lqr.command(est, ref, integrate=aloft)
        self.estimator.set_input(self.lqr.expected_accel if aloft else (0.0, 0.0, 0.0), now)
        return sp

    def _rests(self, now: float, above_ref: float, vz: float) -> bool:
        if above_ref > _REST_GAP and abs(vz) < _REST_SPEED:
            self._resting_since = self._resting_since if self._resting_since is not None else now
            return now - self._resting_since >= self.params.rest_s
        self._resting_since = None
        return False

    def _descend_open_loop(self, now: float) -> FlightSetpoint | None:
        p = self.params
        if self._open_loop is None:
            if self.closed_loop:
                height = self.estimator.estimate(now).z
            else:
                height = self.last_z if self.last_z is not None else p.blind_height
            plan = OpenLoopDescent(max(height, 0.0), p.speed, p.accel, brake=self.last_z is not None)
            self._open_loop = (now, plan)
        start, plan = self._open_loop
        accel = plan.accel_at(now - start)
        return None if accel is None else self._level(accel)

    def _level(self, accel: float) -> FlightSetpoint:
        """Level attitude, no yaw rate, the thrust for vertical acceleration `accel` (m/s^2)."""
        return to_flight_setpoint(0.0, 0.0, 0.0, thrust_command(self.hover_newtons * (G + accel) / G))
