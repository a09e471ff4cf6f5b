"""The gateway's packets read as the firmware reads them, independently of the encoder under test
(`common.crazyflie.crtp`): RPYT setpoints, stops, notify-setpoint-stop, full-state setpoints (the
simulated firmware's decoder), external poses, supervisor requests, and the wheel protocol's
app-channel messages."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from common.bus.messages import FlightSetpoint
from common.crazyflie import crtp
from services.sim.crazyflie.firmware.commander import generic


@dataclass(frozen=True)
class Notify:
    """notify-setpoint-stop (port 7, channel 1)."""


@dataclass(frozen=True)
class Null:
    """A link-layer null packet (header 0xff, nothing else): the stock vehicle's keep-alive."""


@dataclass(frozen=True)
class Supervisor:
    """A supervisor request (port 9, channel 1): 1 arm, 2 crash recovery, 3 emergency stop."""

    cmd: int


@dataclass(frozen=True)
class ExtPose:
    """An external pose (port 6, channel 1, type 8): position and quaternion."""

    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]


def decode(raw: bytes) -> object:
    """The gateway's packets, read as the firmware reads them (independently of the encoder)."""
    port, ch, payload = raw[0] >> 4, raw[0] & 3, raw[1:]
    if port == 15 and ch == 3 and not payload:
        return Null()
    if port == 3:
        roll, pitch, yawrate, thrust = struct.unpack("<fffH", payload)
        return FlightSetpoint(roll=roll, pitch=-pitch, yawrate=yawrate, thrust=thrust)
    if port == 7 and ch == 0 and payload[:1] == b"\x06":
        return generic(payload)  # full state, as the simulated firmware reads it
    if port == 7:
        return crtp.Stop() if ch == 0 and payload == b"\0" else Notify()
    if port == 6 and ch == 1 and payload[0] == 8:
        values = struct.unpack("<7f", payload[1:29])
        return ExtPose(values[:3], values[3:])
    if port == 9:
        return Supervisor(payload[0])
    return crtp.decode_app_uplink(payload)
