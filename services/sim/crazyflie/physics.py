"""Simulated flying car: the physics behind a simulated Crazyflie (paper 000 §VI-A/B).

It takes exactly the setpoints the real vehicle takes (`FlightSetpoint` in cflib `send_setpoint`
units, `WheelSetpoint`, `StopSetpoint`) and models:

- on the ground, a differential drive (wheel speed limit and lag, `common.crazyflie.thrust.WheelBase`);
- in the air, a point-mass quadrotor of the vehicle's mass (Table I: 41 g) with the Förster 2015
  thrust curve (`common.crazyflie.thrust`), the on-board attitude loop as first-order lags on roll/pitch and
  on the yaw rate, a thrust lag for the motors and linear drag; ground contact below z = 0
  (liftoff when thrust exceeds weight, touchdown kills the velocity and records its speed);
- the Crazyflie commander watchdog (firmware commander.c): with no flight setpoint for 0.5 s the
  attitude is levelled (roll = pitch = 0, yaw rate 0) keeping the thrust, after 2 s the motors stop
  and the vehicle falls. Wheels stop 0.5 s after their last setpoint (assumed, same safety idea);
- the battery: power per mode from Table II (`VehicleModel.power`), flight power scaled with
  (thrust / weight)^1.5 (momentum theory: induced power ~ T^3/2) and driving power with wheel
  speed, drained through eq. 4-5 (`VehicleModel.charge_ah`); the voltage is a Li-Po open-circuit
  curve of the charge left minus the sag of the current over the internal resistance.

Frames: world x, y, z up (z = 0 is the ground); yaw CCW from +x; body x forward, y left.
Clock: `t` is the simulator's own clock (s); pass the same clock to `apply(…, now)`.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

from common.bus.messages import FlightSetpoint, Setpoint, SimTruth, StopSetpoint, WheelSetpoint
from common.crazyflie.firmware import FIRMWARE_MIN_THRUST, WATCHDOG_CUT_S, WATCHDOG_LEVEL_S
from common.crazyflie.thrust import (
    DRAG,
    TAU_ROLL_PITCH,
    TAU_YAW_RATE,
    WheelBase,
    from_flight_setpoint,
    thrust_newtons,
)
from common.domain.battery import open_circuit_voltage
from common.domain.vehicle_model import G, VehicleModel

REST_EPS = 1e-6
"""Thrust (N) and wheel speed (m/s) below which a stopped motor or wheel counts as at rest."""


@dataclass(frozen=True, slots=True)
class PhysicsParams:
    """Simulator constants. The defaults are the nominal vehicle the controllers are designed on;
    tests perturb them (`thrust_scale`, lags, `mass_scale`) to check robustness.

    tau_motor: thrust lag (s, assumed); drag: linear drag (kg/s, `common.crazyflie.thrust.DRAG`); r_internal: battery internal resistance (ohm, assumed);
    max_substep: integration step (s)."""

    wheels: WheelBase = WheelBase()
    tau_roll_pitch: float = TAU_ROLL_PITCH
    tau_yaw_rate: float = TAU_YAW_RATE
    tau_motor: float = 0.03
    drag: float = DRAG
    thrust_scale: float = 1.0
    mass_scale: float = 1.0
    r_internal: float = 0.15
    wheel_watchdog_s: float = 0.5
    max_substep: float = 0.002


def unit_thrust(vid: str, spread: float) -> float:
    """The thrust scale of simulated unit `vid` when units differ by up to `spread` (a fraction)
    from the model the controllers are designed on: propellers, motors and what each carries
    (decks, markers) differ, and the firmware's battery compensation keeps only each unit's own
    thrust steady over its battery (Bitcraze docs, "Battery Compensation"). Fixed by the id, spread
    evenly over [1 - spread, 1 + spread]."""
    return 1.0 + spread * (2.0 * (zlib.crc32(vid.encode()) % 10007) / 10006 - 1.0)


def _lag(h: float, tau: float) -> float:
    """How far a first-order lag of time constant `tau` closes on its input over `h` s."""
    return 1.0 - math.exp(-h / tau)


@dataclass(frozen=True, slots=True)
class BatteryState:
    charge_used_ah: float
    soc: float
    vbat: float
    current_a: float


class SimFlyingCar:
    """One simulated flying car. `apply` setpoints, `step` time, read `truth()` and `battery`."""

    def __init__(self, vid: str, model: VehicleModel | None = None, params: PhysicsParams = PhysicsParams(),
                 pos: tuple[float, float, float] = (0.0, 0.0, 0.0), yaw: float = 0.0, t: float = 0.0,
                 charge_used_ah: float = 0.0) -> None:
        self.vid = vid
        self.model = model = model or VehicleModel()
        self.params = params
        self.mass = model.mass * params.mass_scale
        self.t = t
        self.x, self.y, self.z = pos
        self.vx = self.vy = self.vz = 0.0
        self.roll = self.pitch = 0.0
        self.yaw = yaw
        self.yaw_rate = 0.0
        self.thrust = 0.0
        self.wheel_left = self.wheel_right = 0.0
        self.airborne = pos[2] > 0.0
        self.charge_used_ah = charge_used_ah
        self.current = 0.0
        self.last_impact_speed = 0.0
        self._flight: tuple[float, float, float, int] = (0.0, 0.0, 0.0, 0)
        self._flight_t = -math.inf
        self._wheels: tuple[float, float] = (0.0, 0.0)
        self._wheels_t = -math.inf
        self._gust: tuple[float, float, float] = (0.0, 0.0, -math.inf)
        self._battery: tuple[tuple[float, float], BatteryState] = ((math.nan, math.nan), BatteryState(0, 0, 0, 0))
        self._lags_at: tuple[float, tuple[float, float, float, float]] = (math.nan, (0.0, 0.0, 0.0, 0.0))
        self._thrust_of: tuple[int, float] = (0, 0.0)

    def push(self, ax: float, ay: float, until: float) -> None:
        """Wind (a `gust` fault): a horizontal acceleration (m/s^2, world frame) on the body in
        the air until `until` (simulator clock)."""
        self._gust = (ax, ay, until)

    def apply(self, setpoint: Setpoint, now: float | None = None) -> None:
        """Take one setpoint as the Crazyflie would, received at `now` (simulator clock)."""
        t = self.t if now is None else now
        if isinstance(setpoint, FlightSetpoint):
            roll, pitch, yaw_rate = from_flight_setpoint(setpoint)
            cmd = setpoint.thrust if setpoint.thrust >= FIRMWARE_MIN_THRUST else 0
            self._flight, self._flight_t = (roll, pitch, yaw_rate, cmd), t
        elif isinstance(setpoint, WheelSetpoint):
            self._wheels, self._wheels_t = (setpoint.left, setpoint.right), t
        elif isinstance(setpoint, StopSetpoint):
            self._flight, self._flight_t = (0.0, 0.0, 0.0, 0), t
            self._wheels, self._wheels_t = (0.0, 0.0), t
        else:
            raise TypeError(f"not a setpoint: {setpoint!r}")

    def flight_command(self) -> tuple[float, float, float, int]:
        """The (roll, pitch, yaw rate, thrust command) in force now, after the commander watchdog."""
        age = self.t - self._flight_t
        roll, pitch, yaw_rate, cmd = self._flight
        if age > WATCHDOG_CUT_S:
            return 0.0, 0.0, 0.0, 0
        if age > WATCHDOG_LEVEL_S:
            return 0.0, 0.0, 0.0, cmd
        return roll, pitch, yaw_rate, cmd

    def step(self, dt: float) -> None:
        """Advance the simulation by `dt` s (in sub-steps of at most `max_substep`; a parked
        vehicle in one step: nothing but its idle drain changes until a command comes)."""
        if self._parked():
            self.thrust = self.wheel_left = self.wheel_right = 0.0
            self.vx = self.vy = self.vz = self.roll = self.pitch = self.yaw_rate = 0.0
            self._drain(dt)
            self.t += dt
            return
        n = max(1, math.ceil(dt / self.params.max_substep - 1e-9))
        h = dt / n
        lags = self._lags(h)
        for _ in range(n):
            self._substep(h, lags)

    def _parked(self) -> bool:
        """On the ground with motors and wheels at rest and no command to move them in force
        (a thrust command outlives the watchdog's cut only as 0; wheels their own watchdog)."""
        if self.airborne or self.thrust > REST_EPS or abs(self.wheel_left) > REST_EPS or abs(self.wheel_right) > REST_EPS:
            return False
        if self._flight[3] and self.t - self._flight_t <= WATCHDOG_CUT_S:
            return False
        return not any(self._wheels) or self.t - self._wheels_t > self.params.wheel_watchdog_s

    def _lags(self, h: float) -> tuple[float, float, float, float]:
        """The first-order lags' factors 1 - exp(-h / tau) over a step of `h` s: wheels, motors,
        roll and pitch, yaw rate (computed once for the step size every sub-step uses)."""
        if self._lags_at[0] != h:
            p = self.params
            self._lags_at = (h, (_lag(h, p.wheels.tau), _lag(h, p.tau_motor), _lag(h, p.tau_roll_pitch),
                                 _lag(h, p.tau_yaw_rate)))
        return self._lags_at[1]

    def _thrust_target(self, cmd: int) -> float:
        """The thrust (N) the motors settle to at command `cmd` (the last command's, kept)."""
        if self._thrust_of[0] != cmd:
            self._thrust_of = (cmd, thrust_newtons(cmd) * self.params.thrust_scale)
        return self._thrust_of[1]

    def _substep(self, h: float, lags: tuple[float, float, float, float]) -> None:
        """One sub-step of `h` s; `lags`: `_lags(h)`."""
        p = self.params
        kw, km, ka, ky = lags
        roll_c, pitch_c, yaw_rate_c, cmd = self.flight_command()
        wl, wr = self._wheels if self.t - self._wheels_t <= p.wheel_watchdog_s else (0.0, 0.0)
        if wl or wr or self.wheel_left or self.wheel_right:
            lim = p.wheels.max_speed
            self.wheel_left += (min(max(wl, -lim), lim) - self.wheel_left) * kw
            self.wheel_right += (min(max(wr, -lim), lim) - self.wheel_right) * kw
        if cmd or self.thrust:
            self.thrust += (self._thrust_target(cmd) - self.thrust) * km
        if not self.airborne and self.thrust > self.mass * G:
            self.airborne = True
        if self.airborne:
            self._fly(h, roll_c, pitch_c, yaw_rate_c, ka, ky)
        else:
            self._drive(h)
        self._drain(h)
        self.t += h

    def _fly(self, h: float, roll_c: float, pitch_c: float, yaw_rate_c: float, ka: float, ky: float) -> None:
        """One sub-step in the air; `ka`, `ky`: the roll/pitch and yaw-rate lags' factors."""
        p = self.params
        self.roll += (roll_c - self.roll) * ka
        self.pitch += (pitch_c - self.pitch) * ka
        self.yaw_rate += (yaw_rate_c - self.yaw_rate) * ky
        self.yaw = math.remainder(self.yaw + self.yaw_rate * h, 2.0 * math.pi)
        cr, sr = math.cos(self.roll), math.sin(self.roll)
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        a = self.thrust / self.mass
        k = p.drag / self.mass
        # thrust along body z of R = Rz(yaw) Ry(pitch) Rx(roll)
        gx, gy, until = self._gust
        if self.t >= until:
            gx = gy = 0.0
        self.vx += (a * (cy * sp * cr + sy * sr) - k * self.vx + gx) * h
        self.vy += (a * (sy * sp * cr - cy * sr) - k * self.vy + gy) * h
        self.vz += (a * cp * cr - G - k * self.vz) * h
        self.x += self.vx * h
        self.y += self.vy * h
        self.z += self.vz * h
        if self.z <= 0.0:
            self.last_impact_speed = -self.vz
            self.z = 0.0
            self.vx = self.vy = self.vz = 0.0
            self.roll = self.pitch = self.yaw_rate = 0.0
            self.airborne = False

    def _drive(self, h: float) -> None:
        v = 0.5 * (self.wheel_left + self.wheel_right)
        self.yaw = math.remainder(self.yaw + (self.wheel_right - self.wheel_left) / self.params.wheels.track * h,
                                  2.0 * math.pi)
        self.vx, self.vy, self.vz = v * math.cos(self.yaw), v * math.sin(self.yaw), 0.0
        self.x += self.vx * h
        self.y += self.vy * h
        self.roll = self.pitch = self.yaw_rate = 0.0

    def power(self) -> float:
        """Electrical power now (W): Table II idle, plus flight power scaled by (T / weight)^1.5,
        plus driving power scaled by wheel speed over the nominal driving speed."""
        pw = self.model.power
        p = pw.idle
        if self.thrust > 0.0:
            p += (pw.fly - pw.idle) * (self.thrust / (self.mass * G)) ** 1.5
        wheel = 0.5 * (abs(self.wheel_left) + abs(self.wheel_right))
        return p + (pw.drive - pw.idle) * wheel / self.model.speed.drive

    def _drain(self, h: float) -> None:
        watts = self.power()
        self.current = watts / self.model.voltage  # eq. 4
        self.charge_used_ah += self.model.charge_ah(watts, h)  # eq. 5

    @property
    def battery(self) -> BatteryState:
        """The battery now (read several times a tick: by the power manager, the log blocks and
        the truth; computed once per state)."""
        key = (self.charge_used_ah, self.current)
        if self._battery[0] != key:
            soc = max(1.0 - self.charge_used_ah / self.model.capacity_ah, 0.0)
            vbat = open_circuit_voltage(soc) - self.current * self.params.r_internal
            self._battery = (key, BatteryState(self.charge_used_ah, soc, vbat, self.current))
        return self._battery[1]

    def truth(self) -> SimTruth:
        """Ground truth now (angles in rad)."""
        return SimTruth(vid=self.vid, t=self.t, x=self.x, y=self.y, z=self.z, yaw=self.yaw,
                        vx=self.vx, vy=self.vy, vz=self.vz, roll=self.roll, pitch=self.pitch,
                        airborne=self.airborne, motors=self.thrust > 1e-3 or self.flight_command()[3] > 0,
                        vbat=self.battery.vbat, charge_used_ah=self.charge_used_ah)
