"""The Crazyflie's own state estimate and position controller, as models (not the firmware's code).

Estimator (`stabilizer.estimator`): 1 complementary, the default without a positioning deck, has no
position sensor: its height follows the barometer (noisy), its x and y integrate the IMU and drift;
2 Kalman (`estimator_kalman.c`) also fuses external position and pose (port 6, `locSrv`). Both are
modelled as the true motion plus an error: a velocity bias that random-walks (IMU integration)
and, with the Kalman filter, is pulled back by each external position with a fixed gain (a steady
state Kalman gain for `locSrv.extPosStdDev` against the IMU's process noise, assumed). There is no
"position lost" timeout in the firmware: without external position the Kalman estimate just drifts.

Controller (the stock PID controller's position and velocity loops, `controller_pid.c`, modelled as
a PD on position with feed-forward, an integrator on height, the commanded tilt limited to 25 deg):
it turns position, velocity, hover and z-distance setpoints into the roll, pitch, yaw rate and thrust
of the attitude loop, which the physics models (`common.crazyflie.thrust`). Attitude setpoints pass
through unchanged. Gains are assumptions of the order of the firmware's defaults.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from common.bus.messages import FlightSetpoint
from common.crazyflie.thrust import MAX_TILT_DEG, thrust_command
from common.domain.vehicle_model import G
from services.sim.crazyflie.firmware.commander import Setpoint, Vec3

COMPLEMENTARY, KALMAN = 1, 2
IMU_BIAS_WALK = 0.02
"""m/s per sqrt(s): random walk of the integrated-velocity error (assumed)."""
EXTPOS_GAIN = 0.5
"""Fraction of the innovation an external position corrects (assumed steady-state Kalman gain)."""
BARO_STD = 0.02
"""m, height noise of the barometer-based estimate (assumed)."""


@dataclass(frozen=True, slots=True)
class OnboardState:
    pos: Vec3
    vel: Vec3
    yaw: float
    yaw_rate: float


class OnboardEstimator:
    """The estimate of one vehicle; `kind` is `stabilizer.estimator` (1 or 2)."""

    def __init__(self, seed: int = 0) -> None:
        self.kind = COMPLEMENTARY
        self._rng = random.Random(seed)
        self.ext_pos: Vec3 | None = None
        self.ext_at: float | None = None
        self.reset((0.0, 0.0, 0.0), 0.0)

    def reset(self, pos: Vec3, yaw: float) -> None:
        """`kalman.resetEstimation`, or a boot: the estimate starts at `pos` (the firmware's
        `kalman.initial*`, or where the vehicle stands) with no drift yet."""
        self._err = [0.0, 0.0, 0.0]
        self._bias = [0.0, 0.0, 0.0]
        self._yaw_err = 0.0
        self._origin = pos
        self._yaw0 = yaw

    def on_ext_position(self, pos: Vec3, now: float, true_pos: Vec3) -> None:
        self.ext_pos, self.ext_at = pos, now
        if self.kind != KALMAN:
            return  # only the Kalman filter uses external position
        for i in range(3):
            est = true_pos[i] + self._err[i]
            innovation = pos[i] - est
            self._err[i] += EXTPOS_GAIN * innovation
            self._bias[i] *= 1.0 - EXTPOS_GAIN

    def on_ext_yaw(self, yaw: float, true_yaw: float) -> None:
        if self.kind == KALMAN:
            self._yaw_err += EXTPOS_GAIN * math.remainder(yaw - (true_yaw + self._yaw_err), 2.0 * math.pi)

    def update(self, dt: float, true_pos: Vec3, true_vel: Vec3, true_yaw: float, yaw_rate: float) -> OnboardState:
        g = self._rng.gauss
        step = IMU_BIAS_WALK * math.sqrt(max(dt, 0.0))
        for i in range(3):
            self._bias[i] += g(0.0, step)
            self._err[i] += self._bias[i] * dt
        pos = [true_pos[i] + self._err[i] for i in range(3)]
        if self.kind == COMPLEMENTARY:  # height from the barometer, no drift in z
            self._err[2] = self._bias[2] = 0.0
            pos[2] = true_pos[2] + g(0.0, BARO_STD)
        vel = tuple(true_vel[i] + self._bias[i] for i in range(3))
        return OnboardState((pos[0], pos[1], pos[2]), vel, math.remainder(true_yaw + self._yaw_err, 2.0 * math.pi),
                            yaw_rate)


@dataclass
class PositionController:
    """Setpoint + estimate -> attitude and thrust (module docstring); `mass` is what the firmware's
    thrust base is tuned for."""

    mass: float
    kp: float = 6.0
    kd: float = 4.5
    ki_z: float = 2.0
    kv: float = 3.0
    k_yaw: float = 3.0
    _iz: float = 0.0

    def reset(self) -> None:
        self._iz = 0.0

    def command(self, sp: Setpoint, est: OnboardState, dt: float, level: bool = False) -> FlightSetpoint | None:
        """The attitude-loop command, or None for motors off. `level`: the supervisor's
        WarningLevelOut override (x and y released: level attitude; z kept)."""
        if sp.kind == "null":
            self.reset()
            return None
        if sp.kind == "attitude":
            if level:
                return FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=sp.thrust)
            return FlightSetpoint(roll=sp.roll, pitch=sp.pitch, yawrate=sp.yaw_rate, thrust=sp.thrust)
        ax, ay = self._horizontal(sp, est)
        az = self._vertical(sp, est, dt)
        yaw_rate = sp.yaw_rate
        if sp.yaw is not None:
            yaw_rate = self.k_yaw * math.remainder(sp.yaw - est.yaw, 2.0 * math.pi)
        if level:
            ax = ay = yaw_rate = 0.0
        return self._attitude(ax, ay, az, est.yaw, yaw_rate, sp)

    def _horizontal(self, sp: Setpoint, est: OnboardState) -> tuple[float, float]:
        if sp.kind == "position":
            return tuple(self.kp * (sp.pos[i] - est.pos[i]) + self.kd * (sp.vel[i] - est.vel[i]) + sp.acc[i]
                         for i in range(2))  # type: ignore[return-value]
        if sp.kind == "velocity":
            return tuple(self.kv * (sp.vel[i] - est.vel[i]) for i in range(2))  # type: ignore[return-value]
        if sp.kind == "hover":
            c, s = math.cos(est.yaw), math.sin(est.yaw)
            vx, vy = c * sp.vel[0] - s * sp.vel[1], s * sp.vel[0] + c * sp.vel[1]
            return self.kv * (vx - est.vel[0]), self.kv * (vy - est.vel[1])
        return 0.0, 0.0  # zdistance: roll and pitch are given

    def _vertical(self, sp: Setpoint, est: OnboardState, dt: float) -> float:
        if sp.kind == "velocity":
            return self.kv * (sp.vel[2] - est.vel[2])
        err = sp.pos[2] - est.pos[2]
        self._iz = min(max(self._iz + err * dt, -0.5), 0.5)
        return self.kp * err + self.kd * (sp.vel[2] - est.vel[2]) + sp.acc[2] + self.ki_z * self._iz

    def _attitude(self, ax: float, ay: float, az: float, yaw: float, yaw_rate: float, sp: Setpoint) -> FlightSetpoint:
        c, s = math.cos(yaw), math.sin(yaw)
        fwd, left = c * ax + s * ay, -s * ax + c * ay
        up = max(G + az, 0.2 * G)
        lim = math.radians(MAX_TILT_DEG)
        pitch = min(max(math.atan2(fwd, up), -lim), lim)
        roll = min(max(-math.atan2(left, up), -lim), lim)
        if sp.kind == "zdistance":
            roll, pitch = math.radians(sp.roll), math.radians(sp.pitch)
        newtons = self.mass * up / max(math.cos(roll) * math.cos(pitch), 0.5)
        return FlightSetpoint(roll=math.degrees(roll), pitch=math.degrees(pitch), yawrate=-math.degrees(yaw_rate),
                              thrust=thrust_command(newtons))
