"""Landing in place on motion capture: the vertical reference of a descent, the watch that says it
has touched down, and the flight controller that follows one to the other. Shared by the gateway's
safety landing (services/radio_gateway/landing.py) and the executor's emergency descent once poses
are back (services/executor/vehicle_controller.py)."""

from __future__ import annotations

import msgspec

from common.bus.messages import FlightSetpoint
from common.crazyflie.thrust import thrust_command
from common.domain.vehicle_model import G
from common.flight.estimator import Estimate, PoseEstimator
from common.flight.lqr import FlightLqr
from common.flight.modes import Mode
from common.flight.reference import RefSample

REST_SPEED = 0.05
"""m/s: slower than this counts as resting."""

SETTLE_HEIGHT = 0.1
"""m: with its descent's reference on the floor, a vehicle this close to the ground settles on it
(`SETTLE_THRUST`): a fall from here at that thrust touches down at 0.63 m/s at most."""
REANCHOR_GAP = 0.1
"""m: a vehicle this far above its descent's reference (it bounced off the ground, or was thrown up)
descends afresh from where it is: with the reference left on the floor, the flight controller
dived at its full 0.5 g from 0.47 m and a soak vehicle touched down at 2.15 m/s."""
SETTLE_THRUST = 0.8
"""Of its weight: the most thrust a settling vehicle gets (on a 12.5 Hz loop's 0.2 s old poses the
flight controller kept a landed vehicle hopping 2-5 cm for 10 s, motors on, never at rest)."""


def descent_end(touchdown_height: float, ground: float = 0.0) -> float:
    """Where a descent's reference ends and stays: twice `touchdown_height` below `ground` (the
    vehicle settles on the ground at the descent speed instead of being held just above it)."""
    return ground - 2.0 * touchdown_height


def descent_ref(speed: float, touchdown_height: float, t0: float, z0: float, now: float,
                ground: float = 0.0) -> tuple[float, float]:
    """The vertical reference (z, vz) at `now` of a descent from `z0` starting at `t0`: down at
    `speed` to its end (`descent_end`)."""
    end = descent_end(touchdown_height, ground)
    z_ref = max(z0 - speed * max(now - t0, 0.0), end)
    return z_ref, (-speed if end < z_ref < z0 else 0.0)


class RestWatch:
    """Touchdown: at least `touchdown_height` above the descent's reference (the ground, or a
    helipad, holds it up) and slower than `REST_SPEED`, for `rest_s`."""

    def __init__(self, touchdown_height: float, rest_s: float) -> None:
        self.touchdown_height = touchdown_height
        self.rest_s = rest_s
        self._since: float | None = None

    def __call__(self, now: float, above_ref: float, vz: float) -> bool:
        if above_ref >= self.touchdown_height and abs(vz) < REST_SPEED:
            self._since = self._since if self._since is not None else now
            return now - self._since >= self.rest_s
        self._since = None
        return False


class LandInPlace:
    """Lands a flying vehicle where it is, on motion capture: the flight LQR, its integrators reset
    when the landing begins (a stalled loop may have wound them up), holds the x, y and yaw of that
    moment and follows `descent_ref` down at `speed` onto `ground` (afresh from where it is if it rose
    `REANCHOR_GAP` above it), where it settles (`SETTLE_THRUST`);
    done once `RestWatch` says it rests there (or on anything higher: a helipad, another vehicle's
    roof). It tells `estimator` what it commands, as the flight controller does."""

    def __init__(self, lqr: FlightLqr, estimator: PoseEstimator, speed: float, touchdown_height: float,
                 rest_s: float, liftoff_height: float, mode: Mode) -> None:
        self.lqr = lqr
        self.estimator = estimator
        self.speed = speed
        self.touchdown_height = touchdown_height
        self.liftoff_height = liftoff_height
        self.mode = mode
        self.anchor: tuple[float, float, float, float, float] | None = None
        """t, x, y, z, yaw where the landing began; None until it has (or after `release`)."""
        self._rests = RestWatch(touchdown_height, rest_s)

    def release(self) -> None:
        """The poses are gone: the next `step` begins the landing afresh from where they show it."""
        self.anchor = None

    def step(self, now: float, est: Estimate, ground: float = 0.0, not_before: float = -float("inf"),
             over: tuple[float, float] | None = None) -> FlightSetpoint | None:
        """The setpoint at `now` for the fresh estimate `est`, None once it rests. The descent
        begins at `not_before` at the earliest (until then it holds its height); it comes down
        over (x, y) `over` if given, else where it is when the landing begins."""
        if self.anchor is None:
            x, y = over if over is not None else (est.x, est.y)
            self.anchor = (max(now, not_before), x, y, est.z, est.yaw)
            self.lqr.reset()
        t0, x0, y0, z0, yaw0 = self.anchor
        z_ref, vz_ref = descent_ref(self.speed, self.touchdown_height, t0, z0, now, ground=ground)
        if est.z - z_ref > REANCHOR_GAP and est.z - ground > SETTLE_HEIGHT:  # down afresh from there
            t0 = max(now, t0)
            self.anchor = (t0, x0, y0, est.z, yaw0)
            z_ref, vz_ref = descent_ref(self.speed, self.touchdown_height, t0, est.z, now, ground=ground)
        if self._rests(now, est.z - z_ref, est.vz):
            return None
        ref = RefSample(t=now, x=x0, y=y0, z=z_ref, vx=0.0, vy=0.0, vz=vz_ref, ax=0.0, ay=0.0, az=0.0,
                        yaw=yaw0, yaw_rate=0.0, mode=self.mode)
        aloft = est.z - ground > self.liftoff_height
        sp = self.lqr.command(est, ref, integrate=aloft)
        ax, ay, az = self.lqr.expected_accel
        capped = False
        if z_ref <= descent_end(self.touchdown_height, ground) and est.z - ground < SETTLE_HEIGHT:
            cap = thrust_command(SETTLE_THRUST * self.lqr.mass * G)
            if sp.thrust > cap:
                sp = msgspec.structs.replace(sp, thrust=cap)
                az, capped = min(az, (SETTLE_THRUST - 1.0) * G), True
        # (on the ground only thrust above its weight; settling on something higher than `ground`,
        # a capped thrust against a vehicle at rest teaches no lift error)
        self.estimator.command((ax, ay, az), now, aloft, learn=not capped, yaw_rate=self.lqr.yaw_rate)
        return sp
