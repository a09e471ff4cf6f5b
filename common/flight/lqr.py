"""LQR flight controller (paper 000 §VI-B: "an LQR flight controller takes over, sending yaw, pitch,
roll and thrust commands to the Crazyflie's on-board attitude controller").

Design model: the quadrotor linearised about hover in the frame yawed with the vehicle (x forward,
y left, z up). Small angles give v'x = g pitch, v'y = -g roll, v'z = a_z (thrust deviation over
mass), each less the linear drag (`common.crazyflie.thrust.DRAG`); the on-board attitude loop is a first-order lag from the roll/pitch setpoint to the angle
and from the yaw-rate setpoint to the yaw rate (`common.crazyflie.thrust`); integrators on the position
error remove steady offsets (mass, thrust curve, drag). State (13):

    [px, py, pz, vx, vy, vz, roll, pitch, yaw, yaw_rate, ix, iy, iz]

inputs [roll_cmd, pitch_cmd, yaw_rate_cmd, a_z]. The model is discretised with a zero-order hold at
the control period and the gain comes from the discrete algebraic Riccati equation
(`scipy.linalg.solve_discrete_are`) with Bryson's-rule weights (1 / largest acceptable value^2).
Roll and pitch are not measured (motion capture gives position and yaw), so the controller
propagates them through the same lag model from its own commands. The reference's acceleration is
fed forward as attitude and thrust; the thrust is divided by cos(roll) cos(pitch) and mapped to the
PWM command through the shared thrust curve. The acceleration the command should produce is kept
for the estimator's prediction (`expected_accel`).
"""

from __future__ import annotations

import bisect
import itertools
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from common.bus.messages import FlightSetpoint
from common.crazyflie.thrust import (
    DRAG,
    MAX_TILT_DEG,
    TAU_ROLL_PITCH,
    TAU_YAW_RATE,
    max_thrust,
    thrust_command,
    thrust_newtons,
    to_flight_setpoint,
)
from common.domain.vehicle_model import G
from common.flight.estimator import Estimate
from common.flight.reference import RefSample, wrap_angle

N_STATES = 13
N_INPUTS = 4


@dataclass(frozen=True, slots=True)
class LqrWeights:
    """Largest acceptable value of each state error and input (Bryson's rule)."""

    pos: float = 0.05
    vel: float = 0.3
    tilt: float = 0.3
    yaw: float = 0.1
    yaw_rate: float = 1.0
    integral: float = 0.05
    tilt_cmd: float = 0.25
    yaw_rate_cmd: float = 1.5
    accel_cmd: float = 3.0


@dataclass(frozen=True, slots=True)
class FlightModel:
    """The linearisation's parameters: control period (s), attitude-loop lags (s) and drag over
    mass (1/s; the default is for Table I's 41 g)."""

    dt: float = 0.01
    tau_roll_pitch: float = TAU_ROLL_PITCH
    tau_yaw_rate: float = TAU_YAW_RATE
    drag_rate: float = DRAG / 0.041


def continuous_model(model: FlightModel) -> tuple[np.ndarray, np.ndarray]:
    """A, B of the linearised hover model (see module docstring)."""
    a = np.zeros((N_STATES, N_STATES))
    b = np.zeros((N_STATES, N_INPUTS))
    for i in range(3):
        a[i, 3 + i] = 1.0  # p' = v
        a[10 + i, i] = 1.0  # integral' = p
        a[3 + i, 3 + i] = -model.drag_rate  # drag
    a[3, 7] = G  # vx' = g pitch
    a[4, 6] = -G  # vy' = -g roll
    b[5, 3] = 1.0  # vz' = a_z
    a[6, 6] = a[7, 7] = -1.0 / model.tau_roll_pitch
    b[6, 0] = b[7, 1] = 1.0 / model.tau_roll_pitch
    a[8, 9] = 1.0  # yaw' = yaw rate
    a[9, 9] = -1.0 / model.tau_yaw_rate
    b[9, 2] = 1.0 / model.tau_yaw_rate
    return a, b


def discretise(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation through the matrix exponential of [[A, B], [0, 0]] dt."""
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = b
    e = expm(block * dt)
    return e[:n, :n], e[:n, n:]


@lru_cache(maxsize=16)
def lqr_gain(model: FlightModel = FlightModel(), weights: LqrWeights = LqrWeights()) -> np.ndarray:
    """K (4 x 13) minimising sum x'Qx + u'Ru of the discretised model: u = -K x."""
    ad, bd = discretise(*continuous_model(model), model.dt)
    w = weights
    q = np.diag([1 / w.pos**2] * 3 + [1 / w.vel**2] * 3 + [1 / w.tilt**2] * 2
                + [1 / w.yaw**2, 1 / w.yaw_rate**2] + [1 / w.integral**2] * 3)
    r = np.diag([1 / w.tilt_cmd**2] * 2 + [1 / w.yaw_rate_cmd**2, 1 / w.accel_cmd**2])
    p = solve_discrete_are(ad, bd, q, r)
    k = np.linalg.solve(r + bd.T @ p @ bd, bd.T @ p @ ad)
    k.setflags(write=False)
    return k


AxisGains = tuple[tuple[float, float, float, float], tuple[float, float, float, float], tuple[float, float],
                  tuple[float, float, float]]

_AXES = ((1, (0, 3, 7, 10)), (0, (1, 4, 6, 11)), (2, (8, 9)), (3, (2, 5, 12)))
"""(input row, the state columns it sees): pitch <- x, vx, pitch, ix; roll <- y, vy, roll, iy; yaw
rate <- yaw, yaw rate; a_z <- z, vz, iz (all in the yawed frame)."""


def axis_gains(k: np.ndarray) -> AxisGains:
    """K's nonzero entries, per input: in the yawed frame the hover model's axes do not couple
    (module docstring: A, B and the diagonal Q, R are block-diagonal over x, y, z and yaw), so
    neither does the Riccati gain, and a command is 13 products instead of a 4 x 13 matrix
    product (25 -> 18 us a command; the command was a third of an executor's work per vehicle).
    Raises if K is not so."""
    seen = np.zeros(k.shape, dtype=bool)
    rows = []
    for row, cols in _AXES:
        seen[row, list(cols)] = True
        rows.append(tuple(float(k[row, c]) for c in cols))
    if np.abs(k[~seen]).max() > 1e-9 * np.abs(k).max():
        raise ValueError("the LQR gain couples the axes: the model is not the hover model's")
    return tuple(rows)  # type: ignore[return-value]


def _lags(model: FlightModel, dt: float) -> tuple[float, float]:
    """How far the attitude loop's roll/pitch and yaw-rate lags close on their setpoints in `dt` s."""
    return 1.0 - math.exp(-dt / model.tau_roll_pitch), 1.0 - math.exp(-dt / model.tau_yaw_rate)


MAX_STEP_S = 0.1
"""s: the longest time one command is taken to have held (a longer gap is a stall, not a step)."""

GAIN_PERIODS = (0.01, 0.02, 0.04, 0.08, 0.16, 0.32)
"""s: the control periods a gain is computed for (`FlightLqr`'s gain schedule); the first is the
model's (100 Hz)."""
PERIOD_SMOOTHING = 0.3
"""Weight of the latest time between two commands in the loop's period as the controller judges it."""


class FlightLqr:
    """Roll, pitch, yaw rate and thrust setpoints for one vehicle of `mass` kg.

    The gain is scheduled on the loop's period: a loaded machine's executor that runs late holds
    each command for longer than the `dt` the gain was computed for, and the 100 Hz gain held for
    0.2-0.3 s sets a hovering vehicle swinging at 1.5-3 m/s (the closed loop without latency: 33
    cm to 3.8 m from where it was held; at 0.1 s with poses 0.1 s late, 0.56 m/s and 9 cm); each
    command uses the gain of the `GAIN_PERIODS` nearest (in ratio) the period it judges, the
    times between its commands smoothed (`PERIOD_SMOOTHING`): 0.18-0.21 m/s and 3-5 cm there, 0.17
    m/s and 2 cm (2026-12-07, docs/control.md; `tests/test_controllers.py`). The integrators are
    rescaled at a change of gain, so that what they add to the command stays the same."""

    def __init__(self, mass: float, dt: float = 0.01, weights: LqrWeights = LqrWeights(),
                 integral_limit: float = 0.1) -> None:
        self.mass = mass
        self.model = model = FlightModel(dt=dt, drag_rate=DRAG / mass)
        self._schedule = [(dt, axis_gains(lqr_gain(model, weights)))] + [
            (p, axis_gains(lqr_gain(FlightModel(dt=p, drag_rate=model.drag_rate), weights)))
            for p in GAIN_PERIODS if p > dt * 1.5]
        """(period, gains) of the gain schedule, shortest first."""
        self._bounds = [math.sqrt(a[0] * b[0]) for a, b in itertools.pairwise(self._schedule)]
        """Where the schedule's next gain takes over: between two periods, at their geometric mean."""
        self.integral_limit = integral_limit
        self.max_tilt = math.radians(MAX_TILT_DEG)
        self.max_accel = max_thrust() / mass * math.cos(self.max_tilt) - G
        self._lags = _lags(model, dt)  # (one control period's, the common case)
        self.reset()

    def reset(self) -> None:
        """Forget the integrators, the propagated attitude and the loop's period (when a flight or
        a landing in place starts)."""
        self.integral = [0.0, 0.0, 0.0]
        self.period = self.model.dt
        """s: the loop's period as this controller judges it (the gain schedule's input)."""
        self._gains = self._schedule[0][1]
        self.roll = self.pitch = self.yaw_rate = 0.0
        self.expected_accel = (0.0, 0.0, 0.0)  # world frame, m/s^2, of the last command
        self._sent: tuple[float, float, float, float] | None = None  # the last command's time, roll, pitch, yaw rate

    def accel_bias(self) -> float:
        """Vertical acceleration (m/s^2) the z integrator adds: the thrust-model error it learned."""
        return -self._gains[3][2] * self.integral[2]

    def _schedule_gain(self, held: float) -> None:
        """Judge the loop's period from the time `held` (s) the last command held, and take the gain
        of the schedule's period nearest it (module docstring), the integrators rescaled to add what
        they added."""
        self.period += PERIOD_SMOOTHING * (held - self.period)
        gains = self._schedule[bisect.bisect(self._bounds, self.period)][1]
        if gains is not self._gains:
            old = self._gains
            ix, iy, iz = self.integral
            self.integral = [ix * old[0][3] / gains[0][3], iy * old[1][3] / gains[1][3], iz * old[3][2] / gains[3][2]]
            self._gains = gains

    def command(self, est: Estimate, ref: RefSample, integrate: bool = True) -> FlightSetpoint:
        """One control step. `integrate` is False while the vehicle still rests on the ground, so
        the integrators do not wind up before liftoff. A loop slower than the model's period (a
        loaded machine's late or missed ticks) is allowed for: the integrators and the propagated
        attitude advance by the time since the last command (up to `MAX_STEP_S`). (The attitude
        advanced one period per command: on a 12.5 Hz loop it lagged the vehicle's, which swung to
        29 deg against 9 believed, and the thrust's lift was 13 % less than expected.)"""
        dt = self.model.dt
        if self._sent is not None:
            t, roll, pitch, yaw_rate = self._sent
            self._schedule_gain(min(max(est.t - t, dt), GAIN_PERIODS[-1]))
            late = min(max(est.t - t - dt, 0.0), MAX_STEP_S - dt)
            if late > 0.0:  # the last command held for longer than one period
                self._propagate(roll, pitch, yaw_rate, late)
                dt += late
        ex, ey, ez = est.x - ref.x, est.y - ref.y, est.z - ref.z
        ix, iy, iz = self.integral
        if integrate:  # (per axis, written out: once per vehicle and control period)
            lim = self.integral_limit
            ix, iy, iz = (min(max(ix + ex * dt, -lim), lim), min(max(iy + ey * dt, -lim), lim),
                          min(max(iz + ez * dt, -lim), lim))
            self.integral = [ix, iy, iz]
        c, s = math.cos(est.yaw), math.sin(est.yaw)
        # reference acceleration in the yawed frame, fed forward as attitude (v'x = g pitch, ...)
        abx, aby = ref.ax * c + ref.ay * s, -ref.ax * s + ref.ay * c
        pitch_ff, roll_ff = abx / G, -aby / G
        evx, evy = est.vx - ref.vx, est.vy - ref.vy
        # u = K err, err in the yawed frame; K's rows each see one axis (`axis_gains`)
        (kpx, kvx, kpitch, kix), (kpy, kvy, kroll, kiy), (kyaw, kyr), (kpz, kvz, kiz) = self._gains
        du_pitch = (kpx * (ex * c + ey * s) + kvx * (evx * c + evy * s) + kpitch * (self.pitch - pitch_ff)
                    + kix * (ix * c + iy * s))
        du_roll = (kpy * (ey * c - ex * s) + kvy * (evy * c - evx * s) + kroll * (self.roll - roll_ff)
                   + kiy * (iy * c - ix * s))
        du_yaw = kyaw * wrap_angle(est.yaw - ref.yaw) + kyr * (self.yaw_rate - ref.yaw_rate)
        du_z = kpz * ez + kvz * (est.vz - ref.vz) + kiz * iz
        tilt = self.max_tilt
        roll = min(max(roll_ff - du_roll, -tilt), tilt)
        pitch = min(max(pitch_ff - du_pitch, -tilt), tilt)
        yaw_rate = ref.yaw_rate - du_yaw
        accel = min(max(ref.az - du_z, -0.5 * G), self.max_accel)
        tilt_cos = math.cos(self.roll) * math.cos(self.pitch)
        cmd = thrust_command(self.mass * (G + accel) / tilt_cos)
        accel = thrust_newtons(cmd) * tilt_cos / self.mass - G  # what the command gives: at the motors' limit, less
        self._propagate(roll, pitch, yaw_rate, self.model.dt)
        self._sent = (est.t, roll, pitch, yaw_rate)
        # what the vehicle should do now, for the estimator's prediction: tilt accelerates it
        # (v'x = g pitch, v'y = -g roll in the yawed frame), the thrust commanded lifts it (the
        # thrust model's error is the estimator's to learn, `PoseEstimator.lift_error`; the
        # integrator's bias is no measure of it: wound up in a transient, 4.4 m/s^2 in a soak, it
        # made a vehicle falling at 5 m/s^2 estimated at 0.5)
        bx, by = G * self.pitch, -G * self.roll
        d = self.model.drag_rate
        self.expected_accel = (bx * c - by * s - d * est.vx, bx * s + by * c - d * est.vy, accel - d * est.vz)
        return to_flight_setpoint(roll, pitch, yaw_rate, cmd)

    def _propagate(self, roll: float, pitch: float, yaw_rate: float, dt: float) -> None:
        """The on-board attitude loop (first-order lags) `dt` s on, commanded `roll`, `pitch`, `yaw_rate`."""
        kr, ky = self._lags if dt == self.model.dt else _lags(self.model, dt)
        self.roll += (roll - self.roll) * kr
        self.pitch += (pitch - self.pitch) * kr
        self.yaw_rate += (yaw_rate - self.yaw_rate) * ky
