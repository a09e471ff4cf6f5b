"""The reference a flight controller tracks: one sample of position, velocity, acceleration, yaw and
mode (paper 000 §VI-B), shared by the executor's trajectory and the gateway's safety landing."""

from __future__ import annotations

import math

import msgspec

from common.flight.modes import Mode


def wrap_angle(a: float) -> float:
    """Angle in (-pi, pi]."""
    return a - 2.0 * math.pi * math.floor((a + math.pi) / (2.0 * math.pi))


class RefSample(msgspec.Struct, frozen=True, gc=False):
    """The reference at time `t` (s since mission start): position, velocity, acceleration (m, m/s,
    m/s^2, world frame), yaw (rad, CCW from +x) and yaw rate, and the planned mode. (A struct, not a
    frozen dataclass: one or two are made per vehicle and control tick, ten times faster.)"""

    t: float
    x: float
    y: float
    z: float
    vx: float
    vy: float
    vz: float
    ax: float
    ay: float
    az: float
    yaw: float
    yaw_rate: float
    mode: Mode
