"""Actuation model of the flying car, shared by the flight controller and the simulator.

Rotors (paper 000 §VI-A: a Crazyflie 2.0 on a wheel base). Thrust of one motor in N against the
16-bit PWM command, identified on a thrust stand by Förster, "System Identification of the
Crazyflie 2.0 Nano Quadrocopter", ETH Zürich, 2015 (the curve Bitcraze links from its
"PWM to thrust" page)::

    f(pwm) = 2.130295e-11 pwm^2 + 1.032633e-6 pwm + 5.484560e-4,   pwm in [0, 65535]

Four motors give 0.557 N at the cflib ceiling of 60000: a thrust-to-weight ratio of 1.39 for the
41 g flying car of Table I, which hovers at a command of about 48 400.

`commander.send_setpoint(roll, pitch, yawrate, thrust)` conventions (cflib 0.1.34 negates pitch on
the wire; the firmware's crtp_commander_rpyt.c negates the legacy yaw rate): in the body frame
x forward, y left, z up, a positive roll tilts the right side down (accelerates to -y), a positive
pitch tilts the nose down (accelerates to +x), both right-handed; a positive yaw rate turns
clockwise seen from above, i.e. the right-handed yaw rate is -yawrate.

The on-board attitude loop is modelled as first-order lags (roll/pitch angle, yaw rate). Its time
constants are not in paper 000 or Förster 2015; 0.1 s / 0.15 s are assumptions of the order of the
Crazyflie's stock PID attitude loop, and the closed-loop tests run the simulator with perturbed
values to show the flight controller does not depend on them exactly.

Wheel base (§VI-A: two small motors on a carbon tube and a ball caster): the paper gives no
geometry; the track width and wheel speed limit below are assumptions (the limit is twice
Table II's 0.1 m/s driving speed, so a late vehicle can catch up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from common.bus.messages import FlightSetpoint
from common.domain.vehicle_model import G

N_MOTORS = 4
PWM_MAX = 65535
THRUST_CMD_MIN = 10001
"""cflib's "next to no power" command; below it the controller sends StopSetpoint instead."""
THRUST_CMD_MAX = 60000
"""cflib's "full power" command: the ceiling the flight controller commands."""
_A2, _A1, _A0 = 2.130295e-11, 1.032633e-6, 5.484560e-4  # Förster 2015, N per motor vs PWM

TAU_ROLL_PITCH = 0.10
"""s, first-order lag of the on-board attitude loop from roll/pitch setpoint to angle (assumed)."""
TAU_YAW_RATE = 0.15
"""s, first-order lag from yaw-rate setpoint to yaw rate (assumed)."""
MAX_TILT_DEG = 25.0
"""deg, the largest roll/pitch the flight controller commands (keeps vertical thrust >= 0.9 T)."""
DRAG = 0.009
"""kg/s, linear aerodynamic drag: Förster 2015's K_aero,xy = 9.1785e-7 kg/rad times the summed rotor
speed at the 41 g hover command (4 x 2355 rad/s by his omega = 0.04076521 pwm + 380.8359)."""


def thrust_newtons(cmd: float) -> float:
    """Total thrust in N of four motors at PWM command `cmd` (Förster 2015); 0 with motors off."""
    if cmd <= 0:
        return 0.0
    pwm = min(float(cmd), PWM_MAX)
    return N_MOTORS * ((_A2 * pwm + _A1) * pwm + _A0)


def thrust_command(newtons: float) -> int:
    """The PWM command whose total thrust is `newtons`, clipped to cflib's [10001, 60000]."""
    per_motor = newtons / N_MOTORS - _A0
    if per_motor <= 0:
        return THRUST_CMD_MIN
    pwm = (-_A1 + math.sqrt(_A1 * _A1 + 4.0 * _A2 * per_motor)) / (2.0 * _A2)
    return int(min(max(round(pwm), THRUST_CMD_MIN), THRUST_CMD_MAX))


def hover_command(mass: float) -> int:
    """PWM command that holds `mass` kg in hover (41 g -> about 48 400)."""
    return thrust_command(mass * G)


def max_thrust() -> float:
    """Total thrust in N at cflib's ceiling command."""
    return thrust_newtons(THRUST_CMD_MAX)


def to_flight_setpoint(roll: float, pitch: float, yaw_rate: float, cmd: int) -> FlightSetpoint:
    """Right-handed body angles (rad) and yaw rate (rad/s, CCW positive) -> send_setpoint units."""
    return FlightSetpoint(roll=math.degrees(roll), pitch=math.degrees(pitch),
                          yawrate=-math.degrees(yaw_rate), thrust=int(cmd))


def from_flight_setpoint(sp: FlightSetpoint) -> tuple[float, float, float]:
    """send_setpoint units -> right-handed roll, pitch (rad) and CCW yaw rate (rad/s)."""
    return math.radians(sp.roll), math.radians(sp.pitch), -math.radians(sp.yawrate)


@dataclass(frozen=True, slots=True)
class WheelBase:
    """Differential drive of the wheel base (assumed geometry, see module docstring).

    track: distance between the two wheels (m); max_speed: wheel rim speed limit (m/s);
    tau: first-order lag of a wheel's speed behind its setpoint (s).
    """

    track: float = 0.06
    max_speed: float = 0.2
    tau: float = 0.05
