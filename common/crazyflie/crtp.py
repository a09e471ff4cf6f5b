"""CRTP packets between the gateway and a Crazyflie (real or simulated): encode and decode.

One packet is a header byte then up to 30 payload bytes (cflib `crtpstack.CRTPPacket`; the UDP link
carries exactly one packet per datagram). Header: port in bits 7-4, bits 3-2 set (cflib sets them
for the bootloader's sake; the radio reuses them for its safelink toggles, so decoders ignore them),
channel in bits 1-0.

- Flight: commander port 3, channel 0, ``<fffH`` roll, -pitch, yaw rate, thrust: byte for byte what
  cflib's `Commander.send_setpoint` sends (it negates pitch on the wire). Motors off: the generic
  commander's stop (port 7, channel 0, type 0), as `Commander.send_stop_setpoint`.
- Wheels and status: our wheel protocol on the app channel (port 0x0D, channel 2, as cflib's
  `Appchannel`), fixed and versioned in docs/wheel_protocol.md.
- 0xFF alone is the null packet (link control port 15, channel 3) cflib's drivers poll with; any
  link-control packet decodes as `Null`.

Decoders raise `CrtpError` on anything malformed; callers drop and count, never crash.
"""

from __future__ import annotations

import math
import struct

import msgspec

from common.bus.messages import FlightSetpoint

PORT_COMMANDER = 0x03
PORT_COMMANDER_GENERIC = 0x07
PORT_PLATFORM = 0x0D
PORT_LINK = 0x0F
APP_CHANNEL = 2
"""cflib `platformservice.APP_CHANNEL`: the firmware hands it to the app layer."""
MAX_PAYLOAD = 30
NULL_PACKET = b"\xff"

WHEEL_PROTOCOL_VERSION = 1
MSG_WHEELS = 0x01
MSG_STATUS_REQUEST = 0x02
MSG_STATUS = 0x81

FLAG_MOTORS = 0x01
"""Status flag: motors running."""
FLAG_FLYING = 0x02
"""Status flag: the vehicle believes it is airborne."""
FLAG_WATCHDOG_LEVEL = 0x04
"""Status flag: the commander watchdog levelled the attitude (no setpoint for 0.5 s) since the last status."""
FLAG_WATCHDOG_CUT = 0x08
"""Status flag: the commander watchdog stopped the motors (no setpoint for 2 s) since the last status."""
FLAG_WHEEL_WATCHDOG = 0x10
"""Status flag: the wheel watchdog stopped the wheels (no wheel command for 0.5 s) since the last status."""

_SETPOINT = struct.Struct("<fffH")
_STOP_TYPE = 0
_HEAD = struct.Struct("<BB")
_WHEELS = struct.Struct("<BBhh")
_STATUS_REQUEST = struct.Struct("<BBI")
_STATUS = struct.Struct("<BBIIIHhhB")
_U32 = 0xFFFFFFFF


class CrtpError(ValueError):
    """A packet that is not a valid one of ours (too short, wrong port, bad version, ...)."""


def header(port: int, channel: int) -> int:
    """The header byte cflib builds for `port` and `channel` (`CRTPPacket._update_header`)."""
    return (port & 0x0F) << 4 | 0x3 << 2 | (channel & 0x03)


def split(raw: bytes) -> tuple[int, int, bytes]:
    """(port, channel, payload) of a raw packet."""
    if not raw:
        raise CrtpError("empty packet")
    if len(raw) > MAX_PAYLOAD + 1:
        raise CrtpError(f"{len(raw) - 1} payload bytes > {MAX_PAYLOAD}")
    return raw[0] >> 4, raw[0] & 0x03, bytes(raw[1:])


_H_SETPOINT = header(PORT_COMMANDER, 0)
_H_STOP = header(PORT_COMMANDER_GENERIC, 0)
_H_APP = header(PORT_PLATFORM, APP_CHANNEL)


class Wheels(msgspec.Struct, frozen=True):
    """Wheel rim speeds in mm/s (int16 on the wire), positive forward."""

    left_mm_s: int
    right_mm_s: int


class StatusRequest(msgspec.Struct, frozen=True):
    """`sent`: packets the gateway has sent this vehicle so far, this request included (mod 2^32)."""

    sent: int


class Status(msgspec.Struct, frozen=True):
    """Vehicle -> gateway. `echo_sent`: the `sent` of the request answered; `received`: every packet
    from the gateway received so far (setpoints, stops, wheel commands, status requests), up to and
    including that request; `setpoints`: how many of them were flight, stop or wheel commands."""

    echo_sent: int
    received: int
    setpoints: int
    vbat_mv: int
    wheel_left_mm_s: int
    wheel_right_mm_s: int
    flags: int


class Stop(msgspec.Struct, frozen=True):
    """The generic commander's stop setpoint: motors off."""


class Null(msgspec.Struct, frozen=True):
    """The empty link-control packet."""


Uplink = FlightSetpoint | Stop | Wheels | StatusRequest | Null
Downlink = Status | Null


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def encode_setpoint(sp: FlightSetpoint) -> bytes:
    """cflib `Commander.send_setpoint(roll, pitch, yawrate, thrust)` on the wire (pitch negated)."""
    if not _finite(sp.roll, sp.pitch, sp.yawrate):
        raise ValueError(f"non-finite flight setpoint {sp!r}")
    if not 0 <= sp.thrust <= 0xFFFF:
        raise ValueError("thrust must be between 0 and 0xFFFF")
    return bytes((_H_SETPOINT,)) + _SETPOINT.pack(sp.roll, -sp.pitch, sp.yawrate, sp.thrust)


def encode_stop() -> bytes:
    """cflib `Commander.send_stop_setpoint()` on the wire."""
    return bytes((_H_STOP, _STOP_TYPE))


def _clamp16(v: float) -> int:
    return int(min(max(round(v), -32768), 32767))


def encode_wheels(left_m_s: float, right_m_s: float) -> bytes:
    """Wheel protocol WHEELS: rim speeds in m/s, sent as int16 mm/s (clamped)."""
    if not _finite(left_m_s, right_m_s):
        raise ValueError("non-finite wheel speed")
    body = _WHEELS.pack(WHEEL_PROTOCOL_VERSION, MSG_WHEELS, _clamp16(left_m_s * 1000.0), _clamp16(right_m_s * 1000.0))
    return bytes((_H_APP,)) + body


def encode_status_request(sent: int) -> bytes:
    return bytes((_H_APP,)) + _STATUS_REQUEST.pack(WHEEL_PROTOCOL_VERSION, MSG_STATUS_REQUEST, sent & _U32)


def encode_status(st: Status) -> bytes:
    body = _STATUS.pack(WHEEL_PROTOCOL_VERSION, MSG_STATUS, st.echo_sent & _U32, st.received & _U32,
                        st.setpoints & _U32, min(max(st.vbat_mv, 0), 0xFFFF), _clamp16(st.wheel_left_mm_s),
                        _clamp16(st.wheel_right_mm_s), st.flags & 0xFF)
    return bytes((_H_APP,)) + body


def _app(payload: bytes) -> tuple[int, bytes]:
    """(message type, payload) of a wheel-protocol packet, its version checked."""
    if len(payload) < _HEAD.size:
        raise CrtpError("app-channel packet shorter than its version and type")
    version, kind = _HEAD.unpack_from(payload)
    if version != WHEEL_PROTOCOL_VERSION:
        raise CrtpError(f"wheel protocol version {version}, expected {WHEEL_PROTOCOL_VERSION}")
    return kind, payload


def _exact(layout: struct.Struct, payload: bytes, what: str) -> tuple:
    if len(payload) != layout.size:
        raise CrtpError(f"{what} of {len(payload)} bytes, expected {layout.size}")
    return layout.unpack(payload)


def decode_uplink(raw: bytes) -> Uplink:
    """A packet from the gateway, as the vehicle's firmware reads it (link control reads as `Null`)."""
    port, channel, payload = split(raw)
    if port == PORT_LINK:
        return Null()
    if port == PORT_COMMANDER and channel == 0:
        roll, neg_pitch, yawrate, thrust = _exact(_SETPOINT, payload, "setpoint")
        if not _finite(roll, neg_pitch, yawrate):
            raise CrtpError("non-finite setpoint")
        return FlightSetpoint(roll=roll, pitch=-neg_pitch, yawrate=yawrate, thrust=thrust)
    if port == PORT_COMMANDER_GENERIC and channel == 0:
        if payload[:1] != bytes((_STOP_TYPE,)):
            raise CrtpError("generic commander packet other than stop")
        return Stop()
    if port == PORT_PLATFORM and channel == APP_CHANNEL:
        kind, payload = _app(payload)
        if kind == MSG_WHEELS:
            _, _, left, right = _exact(_WHEELS, payload, "WHEELS")
            return Wheels(left, right)
        if kind == MSG_STATUS_REQUEST:
            return StatusRequest(_exact(_STATUS_REQUEST, payload, "STATUS_REQUEST")[2])
        raise CrtpError(f"unknown uplink message type 0x{kind:02x}")
    raise CrtpError(f"unexpected uplink port {port} channel {channel}")


def decode_downlink(raw: bytes) -> Downlink:
    """A packet from the vehicle, as the gateway reads it (link control reads as `Null`)."""
    port, channel, payload = split(raw)
    if port == PORT_LINK:
        return Null()
    if port != PORT_PLATFORM or channel != APP_CHANNEL:
        raise CrtpError(f"unexpected downlink port {port} channel {channel}")
    kind, payload = _app(payload)
    if kind != MSG_STATUS:
        raise CrtpError(f"unknown downlink message type 0x{kind:02x}")
    return Status(*_exact(_STATUS, payload, "STATUS")[2:])
