"""The Crazyflie's own state estimate and position controllers, as models (not the firmware's code).

Estimator (`stabilizer.estimator`): 1 complementary, the default without a positioning deck, has no
position sensor: its height follows the barometer (noisy), its x and y integrate the IMU and drift;
2 Kalman (`estimator_kalman.c`, `kalman_core.c`) also fuses external position and pose (port 6,
`crtp_localization_service.c`). Both are modelled as the true motion plus an error whose velocity
part random-walks (IMU integration). The Kalman filter is modelled per axis on that error, with the
firmware's own numbers: its position variance starts at `stdDevInitialPosition_xy`^2 = 100^2
(z: 1^2, velocity 0.01^2) where `kalman.resetEstimation` puts it, grows by the process noise
`kalmanCoreAddProcessNoise` adds every step ((procNoiseAcc dt^2)^2 on position, (procNoiseAcc dt)^2
on velocity; 0.5 m/s^2 in x and y, 1 in z: `kalman_core_params_defaults.h`), and an external
position of standard deviation `locSrv.extPosStdDev` (0.01 m) corrects position and velocity with
the Kalman gain. The innovation is taken against the true state at arrival: a pose that is late by
the link's latency is fused as if current, as the firmware does. There is no "position lost"
timeout: without external position the Kalman estimate just drifts (`kalman.varPX` grows).

Controllers (`stabilizer.controller`): 1 PID (`controller_pid.c`, `position_controller_pid.c`), a
cascade: position P (2 /s, x y z; z with I 0.5) -> velocity setpoint (the setpoint's velocity only
in velocity modes: in absolute position mode velocity and acceleration feed-forward are ignored)
-> velocity PI: roll and pitch 25 deg per m/s (I 1), limited to 20 deg; thrust 1000 x (25 per m/s,
I 15) PWM over `thrustBase`, here the vehicle's hover command (`posCtlPid.thrustBase` tuned to the
vehicle). 2 Mellinger (`controller_mellinger.c`): a force from position, velocity and integral
errors (0.4 N/m, 0.2 N s/m, 0.05 N/(m s) in x y; 1.25, 0.4, 0.05 in z; integrals limited to 2 and
0.4 m s) plus `ctrlMel.mass` x (acceleration feed-forward + g), yaw from the setpoint's quaternion;
the force's direction is the commanded attitude, its size the thrust (through the vehicle's thrust
curve where the firmware uses its linear `massThrust`). Attitude setpoints (RPYT, manual) pass
through unchanged. The attitude loop itself is the physics' lag model (`common.crazyflie.thrust`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from common.bus.messages import FlightSetpoint
from common.crazyflie.thrust import MAX_TILT_DEG, hover_command, thrust_command
from common.domain.vehicle_model import G
from services.sim.crazyflie.firmware.commander import Setpoint, Vec3

COMPLEMENTARY, KALMAN = 1, 2
PID, MELLINGER = 1, 2
IMU_BIAS_WALK = 0.02
"""m/s per sqrt(s): random walk of the integrated-velocity error (assumed)."""
BARO_STD = 0.02
"""m, height noise of the barometer-based estimate (assumed)."""
PROC_NOISE_ACC = (0.5, 0.5, 1.0)
"""kalman_core_params_defaults.h procNoiseAcc_xy, procNoiseAcc_z (m/s^2)."""
INITIAL_STD = (100.0, 100.0, 1.0)
"""stdDevInitialPosition_xy, _z (m); stdDevInitialVelocity is `INITIAL_VEL_STD`."""
INITIAL_VEL_STD = 0.01
NORMALS_BATCH = 1024
"""Standard normal draws an estimator takes from numpy at a time (one at a time from `random` was
half its cost per tick)."""
MELLINGER_GAINS = {"kp_xy": 0.4, "kd_xy": 0.2, "ki_xy": 0.05, "kp_z": 1.25, "kd_z": 0.4, "ki_z": 0.05}
"""controller_mellinger.c's defaults (parameters `ctrlMel.<name>`)."""
CF_MASS = 0.029
"""platform_defaults_cf2.h CF_MASS (kg): `ctrlMel.mass` until the gateway writes the vehicle's."""


@dataclass(frozen=True, slots=True)
class OnboardState:
    pos: Vec3
    vel: Vec3
    yaw: float
    yaw_rate: float


class _AxisError:
    """One axis of the estimate's error (position, velocity) and the Kalman filter's covariance."""

    def __init__(self, pos_std: float) -> None:
        self.pos = self.vel = 0.0
        self.p = (pos_std**2, 0.0, INITIAL_VEL_STD**2)  # Ppp, Ppv, Pvv

    def predict(self, dt: float, walk: float, acc_noise: float) -> None:
        self.vel += walk
        self.pos += self.vel * dt
        ppp, ppv, pvv = self.p
        q = acc_noise * dt
        self.p = (ppp + dt * (2.0 * ppv + dt * pvv) + (q * dt) ** 2, ppv + dt * pvv, pvv + q * q)

    def correct(self, innovation: float, std: float) -> None:
        ppp, ppv, pvv = self.p
        s = ppp + std * std
        kp, kv = ppp / s, ppv / s
        self.pos += kp * innovation
        self.vel += kv * innovation
        self.p = ((1.0 - kp) * ppp, (1.0 - kp) * ppv, pvv - kv * ppv)


class OnboardEstimator:
    """The estimate of one vehicle; `kind` is `stabilizer.estimator` (1 or 2); `ext_std` is
    `locSrv.extPosStdDev`."""

    def __init__(self, seed: int = 0) -> None:
        self.kind = COMPLEMENTARY
        self.ext_std = 0.01
        self._np_rng = np.random.default_rng(seed)
        self._normals: list[float] = []
        self.ext_pos: Vec3 | None = None
        self.ext_at: float | None = None
        self.ext_count = 0
        """External positions fused by the Kalman filter since boot."""
        self.reset((0.0, 0.0, 0.0), 0.0)

    def reset(self, pos: Vec3, yaw: float, initial: Vec3 | None = None) -> None:
        """`kalman.resetEstimation` (the estimate starts at `initial`, the firmware's
        `kalman.initial*`, with the initial variances) or a boot (at `pos`, where the vehicle
        stands); no drift yet."""
        self._axes = [_AxisError(std) for std in INITIAL_STD]
        if initial is not None:
            for axis, a, b in zip(self._axes, initial, pos, strict=True):
                axis.pos = a - b
        self._yaw_err = 0.0

    def variance(self, axis: int) -> float:
        """`kalman.varPX` ... `varPZ`."""
        return self._axes[axis].p[0]

    def on_ext_position(self, pos: Vec3, now: float, true_pos: Vec3) -> None:
        self.ext_pos, self.ext_at = pos, now
        if self.kind != KALMAN:
            return  # only the Kalman filter uses external position
        self.ext_count += 1
        for axis, m, truth in zip(self._axes, pos, true_pos, strict=True):
            axis.correct(m - (truth + axis.pos), self.ext_std)

    def on_ext_yaw(self, yaw: float, true_yaw: float) -> None:
        if self.kind == KALMAN:
            self._yaw_err += 0.5 * math.remainder(yaw - (true_yaw + self._yaw_err), 2.0 * math.pi)

    def update(self, dt: float, true_pos: Vec3, true_vel: Vec3, true_yaw: float, yaw_rate: float) -> OnboardState:
        """The estimate after `dt` s more of the error's random walk (every firmware tick of every
        simulated vehicle: written out per axis, its normal draws taken from a batch)."""
        normals = self._normals
        if len(normals) < 4:
            normals = self._normals = self._np_rng.standard_normal(NORMALS_BATCH).tolist()
        step = IMU_BIAS_WALK * math.sqrt(max(dt, 0.0))
        ex, ey, ez = self._axes
        ex.predict(dt, step * normals.pop(), PROC_NOISE_ACC[0])
        ey.predict(dt, step * normals.pop(), PROC_NOISE_ACC[1])
        ez.predict(dt, step * normals.pop(), PROC_NOISE_ACC[2])
        z = true_pos[2] + ez.pos
        if self.kind == COMPLEMENTARY:  # height from the barometer, no drift in z
            ez.pos = ez.vel = 0.0
            z = true_pos[2] + BARO_STD * normals.pop()
        return OnboardState((true_pos[0] + ex.pos, true_pos[1] + ey.pos, z),
                            (true_vel[0] + ex.vel, true_vel[1] + ey.vel, true_vel[2] + ez.vel),
                            math.remainder(true_yaw + self._yaw_err, 2.0 * math.pi), yaw_rate)


@dataclass
class _Pi:
    """A PI term with a limited integral (`pid.c` style)."""

    ki: float
    limit: float
    i: float = 0.0

    def __call__(self, err: float, dt: float) -> float:
        self.i = min(max(self.i + err * dt, -self.limit), self.limit)
        return self.ki * self.i


@dataclass
class PositionController:
    """Setpoint + estimate -> attitude and thrust (module docstring). `kind` is
    `stabilizer.controller`; `mass` the vehicle's (the PID's thrust base is its hover command);
    `mel_mass` is `ctrlMel.mass`."""

    mass: float
    kind: int = PID
    mel_mass: float = CF_MASS
    mel_gains: dict[str, float] = field(default_factory=lambda: dict(MELLINGER_GAINS))
    """`ctrlMel.kp_xy` ... `ki_z` (N/m, N s/m, N/(m s))."""
    _ints: dict[str, _Pi] = field(default_factory=dict)

    def reset(self) -> None:
        self._ints = {"pz": _Pi(0.5, 1e9), "vx": _Pi(1.0, 1e9), "vy": _Pi(1.0, 1e9), "vz": _Pi(15.0, 1e9),
                      "mx": _Pi(0.05, 2.0), "my": _Pi(0.05, 2.0), "mz": _Pi(0.05, 0.4)}

    def command(self, sp: Setpoint, est: OnboardState, dt: float, level: bool = False) -> FlightSetpoint | None:
        """The attitude-loop command, or None for motors off. `level`: the supervisor's
        WarningLevelOut override (x and y released: level attitude; z kept)."""
        if sp.kind == "null":  # motors off; the integrals start from zero with the next command
            self._ints = {}
            return None
        if not self._ints:
            self.reset()
        if sp.kind == "attitude":
            if level:
                return FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=sp.thrust)
            return FlightSetpoint(roll=sp.roll, pitch=sp.pitch, yawrate=sp.yaw_rate, thrust=sp.thrust)
        yaw_rate = sp.yaw_rate
        if sp.yaw is not None:
            yaw_rate = 3.0 * math.remainder(sp.yaw - est.yaw, 2.0 * math.pi)  # the attitude loop's yaw, as a rate
        if self.kind == MELLINGER and sp.kind == "position":
            return self._mellinger(sp, est, dt, 0.0 if level else yaw_rate, level)
        return self._pid(sp, est, dt, 0.0 if level else yaw_rate, level)

    def _mellinger(self, sp: Setpoint, est: OnboardState, dt: float, yaw_rate: float, level: bool) -> FlightSetpoint:
        """`controllerMellinger()`: target force = mass (acc + g) + kp e_p + kd e_v + ki int e_p."""
        i, g = self._ints, self.mel_gains
        force = []
        for k, (axis, name) in enumerate((("xy", "mx"), ("xy", "my"), ("z", "mz"))):
            err = sp.pos[k] - est.pos[k]
            i[name].ki = g[f"ki_{axis}"]
            force.append(self.mel_mass * sp.acc[k] + g[f"kp_{axis}"] * err + g[f"kd_{axis}"] * (sp.vel[k] - est.vel[k])
                         + i[name](err, dt))
        force[2] += self.mel_mass * G
        if level:
            force[0] = force[1] = 0.0
        return self._attitude(force[0], force[1], max(force[2], 0.2 * self.mel_mass * G), est.yaw, yaw_rate)

    def _pid(self, sp: Setpoint, est: OnboardState, dt: float, yaw_rate: float, level: bool) -> FlightSetpoint:
        """`positionController()` then `velocityController()` (world frame here; the firmware
        rotates both into the yaw frame, the same thing for these isotropic gains)."""
        i = self._ints
        if sp.kind == "position":
            vx, vy = (2.0 * (sp.pos[k] - est.pos[k]) for k in range(2))
        elif sp.kind == "hover":
            c, s = math.cos(est.yaw), math.sin(est.yaw)
            vx, vy = c * sp.vel[0] - s * sp.vel[1], s * sp.vel[0] + c * sp.vel[1]
        else:
            vx, vy = sp.vel[0], sp.vel[1]
        if sp.kind == "velocity":
            vz = sp.vel[2]
        else:
            err_z = sp.pos[2] - est.pos[2]
            vz = 2.0 * err_z + i["pz"](err_z, dt)
        lim = 20.0  # PID_VEL_ROLL_MAX, PID_VEL_PITCH_MAX (deg)
        ex, ey = vx - est.vel[0], vy - est.vel[1]
        ax_deg = min(max(25.0 * ex + i["vx"](ex, dt), -lim), lim)  # tilt towards +x (deg)
        ay_deg = min(max(25.0 * ey + i["vy"](ey, dt), -lim), lim)
        ez = vz - est.vel[2]
        thrust = min(max(hover_command(self.mass) + 1000.0 * (25.0 * ez + i["vz"](ez, dt)), 0.0), 65535.0)
        c, s = math.cos(est.yaw), math.sin(est.yaw)
        pitch, roll = c * ax_deg + s * ay_deg, -(-s * ax_deg + c * ay_deg)
        if sp.kind == "zdistance":
            roll, pitch = sp.roll, sp.pitch
        if level:
            roll = pitch = 0.0
        return FlightSetpoint(roll=roll, pitch=pitch, yawrate=-math.degrees(yaw_rate), thrust=int(thrust))

    def _attitude(self, fx: float, fy: float, fz: float, yaw: float, yaw_rate: float) -> FlightSetpoint:
        """The force's direction as roll and pitch in the yaw frame, its size as the thrust."""
        c, s = math.cos(yaw), math.sin(yaw)
        fwd, left = c * fx + s * fy, -s * fx + c * fy
        lim = math.radians(MAX_TILT_DEG)
        pitch = min(max(math.atan2(fwd, fz), -lim), lim)
        roll = min(max(-math.atan2(left, fz), -lim), lim)
        newtons = fz / max(math.cos(roll) * math.cos(pitch), 0.5)
        return FlightSetpoint(roll=math.degrees(roll), pitch=math.degrees(pitch), yawrate=-math.degrees(yaw_rate),
                              thrust=thrust_command(newtons))
