"""The gateway's safety landing: a flying vehicle whose commands went stale hovers, then lands, then
its motors stop (paper 000 §VI-C: the gateway is the last link to the vehicle, so it must not leave
one in the air when its executor goes silent).

- With poses (`vehicle/<vid>/pose`): the executor's own flight stack, reused: the Kalman filter
  (`PoseEstimator`, fed the accelerations the LQR commands) and the LQR (`FlightLqr`) hold the
  horizontal position and yaw where the landing began, hover `hover_s`, then descend at `speed`
  to twice `touchdown_height` below the ground, so the vehicle settles on it at the descent speed instead
  of being held just above; motors off once it has rested `rest_s` (slower than 5 cm/s) at least
  `touchdown_height` above the reference: on the ground, or on something higher (a helipad).
- Onboard control mode (`OnboardLanding`): the vehicle's own estimator (fed the motion capture by
  the gateway) and controller fly it; full-state setpoints hold x, y and yaw where the landing
  began, hover, then descend the same way; motors off on the same rest rule, or, without poses
  (the onboard estimate then drifts: the IMU alone), a margin after the predicted touchdown.
- Without a trusted pose: level and open loop (`OpenLoopDescent`), the thrust scaled from the last
  flight setpoint (the hover thrust the executor had found) and making up for the descent's drag:
  from the vertical speed it had, to `speed` at `accel`, then coast at `speed` onto the ground
  below the last known height (or `blind_height` if no pose was ever seen), where the coast
  thrust, below the weight, keeps it; motors off a margin after the predicted touchdown. Poses
  that come back and show it climbing end it: the position control lands the vehicle from where
  they show it (a hover thrust too high makes the blind descent climb: in a 32-vehicle soak, to 12 m).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from common.bus.messages import FlightSetpoint, Pose, PositionSetpoint
from common.crazyflie.firmware import FIRMWARE_MIN_THRUST
from common.crazyflie.thrust import DRAG, thrust_command, thrust_newtons, to_flight_setpoint
from common.deploy.radios import LandingParams
from common.domain.vehicle_model import G
from common.flight.estimator import Estimate, PoseEstimator
from common.flight.landing import LandInPlace, RestWatch, descent_ref
from common.flight.lqr import FlightLqr
from common.flight.modes import Mode

log = logging.getLogger(__name__)

_LIFTOFF_HEIGHT = 0.01
"""m: below this the LQR integrators stay off (as in the executor)."""
_CUT_SLACK = 0.25
"""Open loop: fraction of the predicted descent time waited past touchdown (the height and the
hover thrust are estimates) before the motors stop."""
_CUT_MARGIN_S = 0.3
"""Open loop: and this much more (s)."""
_CLIMBING = 0.1
"""m/s: a blind descent that poses show climbing faster than this hands over to position control
(its hover thrust was too high); one that descends goes on blind (switching back and forth on a
loaded machine's intermittent poses made the descent jerk: 0.45 m/s at times)."""


@dataclass(slots=True)
class HandBack:
    """When a vehicle the gateway took over for stale commands goes back to its owner: once the
    owner's commands have come for `resume_s`, none more than `gap_s` after the one before
    (`GatewayParams.resume_s`). Given back to the first fresh command, an executor starved in
    bursts (0.2-0.5 s silent, then 20-100 ms of commands: a saturated machine) had the vehicle
    back for each burst on an estimate it had carried on over the silence with commands that never
    acted, and its gateway's landing started afresh after each: in the closed loop (four patterns
    of bursts, four seeds each) the vehicle was thrown about at 0.5-1.8 m/s, twice onto the ground;
    an 80-vehicle soak's flyer so flew sideways at 1.15 m/s, 4 cm up, into a parked vehicle
    (2026-12-07). Held until the commands come steadily, the gateway's landing brings it down, at
    0.31-0.36 m/s at most (`tests/test_gateway_landing.py`)."""

    resume_s: float
    gap_s: float
    since: float | None = None
    """When the owner's commands began to come again (None: not yet)."""
    last: float = -math.inf

    def command(self, now: float) -> bool:
        """The owner's command at `now`: whether the vehicle goes back to it."""
        if self.since is None or now - self.last > self.gap_s:
            self.since = now
        self.last = now
        return now - self.since >= self.resume_s


@dataclass(frozen=True, slots=True)
class OpenLoopDescent:
    """A level descent of `height` m starting at downward speed `v0`: to `speed` at `accel`, then
    coast at `speed`; no braking, so a vehicle lower than believed simply rests on the ground (the
    coast thrust is below its weight). The motors stop at the predicted touchdown plus `_CUT_SLACK`
    of the descent time plus `_CUT_MARGIN_S`."""

    height: float
    speed: float
    accel: float
    v0: float = 0.0

    @property
    def _ramp(self) -> float:
        return abs(self.speed - self.v0) / self.accel

    @property
    def touchdown(self) -> float:
        """Predicted time (s) to reach the ground."""
        ramp_d = 0.5 * (self.v0 + self.speed) * self._ramp
        return self._ramp + max(self.height - ramp_d, 0.0) / self.speed

    @property
    def duration(self) -> float:
        return (1.0 + _CUT_SLACK) * self.touchdown + _CUT_MARGIN_S

    def accel_at(self, t: float) -> float | None:
        """Vertical acceleration (m/s^2) `t` s into the descent; None once the motors must stop."""
        if t >= self.duration:
            return None
        if t < self._ramp:
            return -self.accel if self.v0 < self.speed else self.accel
        return 0.0

    def speed_at(self, t: float) -> float:
        """Planned downward speed (m/s) at `t`."""
        return self.v0 + (self.speed - self.v0) * t / self._ramp if t < self._ramp else self.speed


class SafeLanding:
    """One vehicle's hover-then-land, started at `start` after `last` (the last flight setpoint sent).
    Feed it poses with `on_pose`; `step(now)` gives the next setpoint, or None once landed."""

    def __init__(self, start: float, last: FlightSetpoint | None, params: LandingParams, dt: float) -> None:
        self.params = params
        self.start = start
        self.estimator = PoseEstimator()
        self.estimator.floor = 0.0  # (the ground its descents end on)
        self.lqr = FlightLqr(params.mass, dt=dt)
        self.hover_newtons = params.mass * G
        if last is not None and last.thrust >= FIRMWARE_MIN_THRUST:
            tilt = math.cos(math.radians(last.roll)) * math.cos(math.radians(last.pitch))
            self.hover_newtons = thrust_newtons(last.thrust) * tilt
        self.pose_at = -math.inf
        self.last_z: float | None = None
        self._vertical: tuple[float, float, float] | None = None  # t, z, vz of the last estimate used
        self.closed_loop = False
        self._in_place = LandInPlace(self.lqr, self.estimator, params.speed, params.touchdown_height, params.rest_s,
                                     _LIFTOFF_HEIGHT, Mode.LANDING)
        self._open_loop: tuple[float, OpenLoopDescent] | None = None
        self._failed = False  # the flight stack raised: open loop to the end

    @property
    def descent_start(self) -> float:
        return self.start + self.params.hover_s

    def on_pose(self, pose: Pose, now: float) -> None:
        """A pose received at `now` (gateway clock)."""
        if self.estimator.update(pose):
            self.pose_at = now
        self.last_z = pose.z

    def step(self, now: float) -> FlightSetpoint | None:
        if not self._failed and now - self.pose_at <= self.params.pose_timeout_s:
            try:
                est = self.estimator.estimate(now)
                if not est.stale and (self._open_loop is None or est.vz > _CLIMBING):
                    if self._open_loop is not None:  # the blind descent climbs: land from here
                        self._open_loop = None
                        self._in_place.release()
                    return self._closed_loop(now, est)
            except Exception:  # the borrowed flight stack failed: the open-loop descent still lands
                log.exception("safety landing: position control failed, descending open loop")
                self._failed = True
                return self._descend_open_loop(now)
        if self.closed_loop or now >= self.descent_start:
            return self._descend_open_loop(now)
        self.estimator.set_input((0.0, 0.0, 0.0), now)  # (its own thrust model: it teaches no lift error)
        return self._level(0.0)  # hovering while the first poses come in

    def _closed_loop(self, now: float, est: Estimate) -> FlightSetpoint | None:
        self.closed_loop = True
        self._vertical = (now, est.z, est.vz)
        return self._in_place.step(now, est, not_before=self.descent_start)

    def _descend_open_loop(self, now: float) -> FlightSetpoint | None:
        if self._open_loop is None:
            self._open_loop = (now, self._plan_descent(now))
        start, plan = self._open_loop
        accel = plan.accel_at(now - start)
        self.estimator.set_input((0.0, 0.0, accel or 0.0), now)  # (as planned; it teaches no lift error)
        # the thrust also makes up for the drag of the planned descent (common.crazyflie.thrust.DRAG)
        return None if accel is None else self._level(accel - DRAG / self.params.mass * plan.speed_at(now - start))

    def _plan_descent(self, now: float) -> OpenLoopDescent:
        """From the last position-controlled estimate carried forward, else the last pose, else blind."""
        p = self.params
        v0 = 0.0
        if self._vertical is not None:
            t, z, vz = self._vertical
            height, v0 = z + vz * (now - t), max(-vz, 0.0)
        elif self.last_z is not None:
            height = self.last_z
        else:
            height = p.blind_height
        return OpenLoopDescent(max(height, 0.0), p.speed, p.accel, v0=v0)

    def _level(self, accel: float) -> FlightSetpoint:
        """Level attitude, no yaw rate, the thrust for vertical acceleration `accel` (m/s^2)."""
        return to_flight_setpoint(0.0, 0.0, 0.0, thrust_command(self.hover_newtons * (G + accel) / G))


class OnboardLanding:
    """Onboard control mode's safety landing (module docstring), started at `start` after `last`
    (the last full-state setpoint sent): `on_pose` the motion capture, `step(now)` the next
    setpoint, None once landed."""

    def __init__(self, start: float, last: PositionSetpoint, params: LandingParams) -> None:
        self.params = params
        self.start = start
        self.last = last
        self.estimator = PoseEstimator()
        self.pose_at = -math.inf
        self.closed_loop = False
        """Poses showed the touchdown (else the predicted time ended it)."""
        self._anchor: tuple[float, float, float] | None = None  # x, y, z where it hovers
        self._rests = RestWatch(params.touchdown_height, params.rest_s)

    def on_pose(self, pose: Pose, now: float) -> None:
        if self.estimator.update(pose):
            self.pose_at = now

    def _fresh(self, now: float) -> Estimate | None:
        if now - self.pose_at > self.params.pose_timeout_s:
            return None
        est = self.estimator.estimate(now)
        return None if est.stale else est

    def step(self, now: float) -> PositionSetpoint | None:
        p, est = self.params, self._fresh(now)
        if self._anchor is None:
            src = est if est is not None else self.last
            self._anchor = (src.x, src.y, src.z)
        x0, y0, z0 = self._anchor
        t0 = self.start + p.hover_s
        z_ref, vz_ref = descent_ref(p.speed, p.touchdown_height, t0, z0, now)
        if est is not None:
            if self._rests(now, est.z - z_ref, est.vz):
                self.closed_loop = True
                return None
        elif now >= t0 + (1.0 + _CUT_SLACK) * (z0 + 2.0 * p.touchdown_height) / p.speed + _CUT_MARGIN_S:
            return None  # no poses: the predicted touchdown, plus a margin
        return PositionSetpoint(x=x0, y=y0, z=z_ref, vz=vz_ref, yaw=self.last.yaw)
