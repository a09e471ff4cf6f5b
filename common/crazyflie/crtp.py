"""CRTP packets the fleet builds and reads (cflib 0.1.34 and crazyflie-firmware conventions).

One packet is a header byte then up to 30 payload bytes (cflib `crtpstack.CRTPPacket`; the UDP link
carries exactly one packet per datagram). Header: port in bits 7-4, bits 3-2 set by cflib (the
firmware leaves them clear; decoders ignore them), channel in bits 1-0.

- Flight: commander port 3, channel 0, ``<fffH`` roll, -pitch, yaw rate, thrust: byte for byte what
  cflib's `Commander.send_setpoint` sends (it negates pitch on the wire). Motors off: the generic
  commander's stop (port 7, channel 0, type 0), as `Commander.send_stop_setpoint`; the generic
  position setpoint (type 7) and full-state setpoint (type 6, onboard control mode); notify-setpoint-stop (port 7, channel 1, type 0) hands the commander
  back to the high-level commander, whose idle setpoints keep the firmware's watchdog fed.
- Supervisor (port 9, channel 1, protocol version 12): arming request, crash recovery, emergency stop.
- Localization (port 6): external position (channel 0) and pose (channel 1, type 8).
- Wheels and status: our wheel protocol, version 2, on the app channel (port 0x0D, channel 2, as
  cflib's `Appchannel`): firmware/wheels/PROTOCOL.md (docs/wheel_protocol.md).
- 0xFF alone is the null packet (link control port 15, channel 3); any link-control packet decodes
  as `Null`.

Decoders raise `CrtpError` on anything malformed; callers drop and count, never crash.
"""

from __future__ import annotations

import math
import struct

import msgspec

from common.bus.messages import FlightSetpoint, PositionSetpoint

PORT_CONSOLE = 0x00
PORT_PARAM = 0x02
PORT_COMMANDER = 0x03
PORT_MEM = 0x04
PORT_LOG = 0x05
PORT_LOCALIZATION = 0x06
PORT_COMMANDER_GENERIC = 0x07
PORT_HIGH_LEVEL = 0x08
PORT_SUPERVISOR = 0x09
PORT_PLATFORM = 0x0D
PORT_LINK = 0x0F
APP_CHANNEL = 2
"""cflib `platformservice.APP_CHANNEL`: the firmware hands it to the app layer."""
MAX_PAYLOAD = 30
NULL_PACKET = b"\xff"

WHEEL_PROTOCOL_VERSION = 2
MSG_WHEELS = 0x01
MSG_STATUS_REQUEST = 0x02
MSG_STATUS = 0x81

FLAG_WHEEL_WATCHDOG = 0x01
"""Status flag (latched): the wheel watchdog stopped the wheels (no wheel command for 0.5 s)."""
FLAG_RX_OVERFLOW = 0x02
"""Status flag (latched): the app channel's receive queue overflowed."""
FLAG_MOTORS = 0x04
"""Status flag: a propeller motor is commanded."""
FLAG_FLYING = 0x08
"""Status flag: the supervisor believes the vehicle flies."""
FLAG_ARMED = 0x10
FLAG_LOCKED = 0x20
"""Status flag: the supervisor is locked (reboot required)."""
FLAG_LOW_BATTERY = 0x40
FLAG_MEASURED = 0x80

SUPERVISOR_ARM, SUPERVISOR_RECOVER, SUPERVISOR_EMERGENCY_STOP = 0x01, 0x02, 0x03
GENERIC_STOP, GENERIC_FULL_STATE, GENERIC_POSITION = 0, 6, 7
META_NOTIFY_SETPOINT_STOP = 0
LOC_EXT_POSE = 8

_SETPOINT = struct.Struct("<fffH")
_FULL_STATE = struct.Struct("<BhhhhhhhhhIhhh")
_HEAD = struct.Struct("<BB")
_WHEELS = struct.Struct("<BBhh")
_STATUS_REQUEST = struct.Struct("<BBI")
_STATUS = struct.Struct("<BBIIIHHhhHB")
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
_H_GENERIC = header(PORT_COMMANDER_GENERIC, 0)
_H_META = header(PORT_COMMANDER_GENERIC, 1)
_H_SUPERVISOR = header(PORT_SUPERVISOR, 1)
_H_APP = header(PORT_PLATFORM, APP_CHANNEL)


class Wheels(msgspec.Struct, frozen=True):
    """Wheel rim speeds in mm/s (int16 on the wire), positive forward."""

    left_mm_s: int
    right_mm_s: int


class StatusRequest(msgspec.Struct, frozen=True):
    """`seq`: app-channel packets (WHEELS, STATUS_REQUEST) the gateway has sent this vehicle so far,
    this request included (mod 2^32)."""

    seq: int


class Status(msgspec.Struct, frozen=True):
    """Vehicle -> gateway: what the wheel app knows (firmware/wheels/PROTOCOL.md). `received`:
    app-channel packets taken since boot, this request included; `setpoint_age_ms`: since the
    firmware's commander last took a setpoint (saturates at 65535)."""

    echo_seq: int
    received: int
    uptime_ms: int
    rejected: int
    vbat_mv: int
    wheel_left_mm_s: int
    wheel_right_mm_s: int
    setpoint_age_ms: int
    flags: int


class Stop(msgspec.Struct, frozen=True):
    """The generic commander's stop setpoint: motors off."""


class Null(msgspec.Struct, frozen=True):
    """The empty link-control packet."""


Uplink = Wheels | StatusRequest
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
    return bytes((_H_GENERIC, GENERIC_STOP))


def encode_position(x: float, y: float, z: float, yaw_deg: float) -> bytes:
    """cflib `Commander.send_position_setpoint(x, y, z, yaw)`: metres, yaw in degrees."""
    if not _finite(x, y, z, yaw_deg):
        raise ValueError("non-finite position setpoint")
    return bytes((_H_GENERIC,)) + struct.pack("<Bffff", GENERIC_POSITION, x, y, z, yaw_deg)


def compress_quaternion(qx: float, qy: float, qz: float, qw: float) -> int:
    """The firmware's `quatcompress` ("smallest three", 32 bits), as cflib's
    `cflib.utils.encoding.compress_quaternion`: the largest component's index, then the other three
    as sign and 9-bit magnitude relative to 1/sqrt(2), the largest made positive."""
    q = (qx, qy, qz, qw)
    norm = math.sqrt(sum(c * c for c in q))
    q = tuple(c / norm for c in q)
    largest = max(range(4), key=lambda i: (abs(q[i]), -i))
    negate = q[largest] < 0
    comp = largest
    for i in range(4):
        if i != largest:
            mag = int(((1 << 9) - 1) * (abs(q[i]) * math.sqrt(2.0)) + 0.5)
            comp = comp << 10 | int((q[i] < 0) ^ negate) << 9 | mag
    return comp


def _mm(v: float) -> int:
    """m (or m/s, m/s^2) as the int16 millimetres of the full-state packet (cflib truncates)."""
    if not -32.768 <= v < 32.768:
        raise ValueError(f"{v} out of the full-state setpoint's int16 mm range")
    return int(v * 1000.0)


def encode_full_state(sp: PositionSetpoint) -> bytes:
    """The generic commander's full-state setpoint (type 6; crazyflie-firmware
    crtp_commander_generic.c `fullStateDecoder`): position, velocity and acceleration as int16 mm,
    mm/s, mm/s^2, the yaw as a compressed quaternion, body rates as int16 millirad/s (roll and
    pitch 0). Byte for byte cflib's `Commander.send_full_state_setpoint`, except that cflib scales
    the rates as if given in deg/s while the firmware reads millirad/s: here the yaw rate goes as
    the firmware reads it."""
    values = (sp.x, sp.y, sp.z, sp.vx, sp.vy, sp.vz, sp.ax, sp.ay, sp.az, sp.yaw, sp.yaw_rate)
    if not _finite(*values):
        raise ValueError(f"non-finite position setpoint {sp!r}")
    half = 0.5 * sp.yaw
    quat = compress_quaternion(0.0, 0.0, math.sin(half), math.cos(half))
    return bytes((_H_GENERIC,)) + _FULL_STATE.pack(GENERIC_FULL_STATE, *(_mm(v) for v in values[:9]), quat, 0, 0,
                                                   _mm(sp.yaw_rate))


def encode_notify_setpoint_stop(remain_valid_ms: int = 0) -> bytes:
    """cflib `Commander.send_notify_setpoint_stop()`: low-level setpoints end here."""
    return bytes((_H_META,)) + struct.pack("<BI", META_NOTIFY_SETPOINT_STOP, remain_valid_ms & _U32)


def encode_arming(arm: bool) -> bytes:
    """cflib `Supervisor.send_arming_request(arm)` (protocol version 12)."""
    return bytes((_H_SUPERVISOR, SUPERVISOR_ARM, int(arm)))


def encode_crash_recovery() -> bytes:
    """cflib `Supervisor.send_crash_recovery_request()`."""
    return bytes((_H_SUPERVISOR, SUPERVISOR_RECOVER))


def encode_emergency_stop() -> bytes:
    """cflib `Supervisor.send_emergency_stop()`: the motors stop and the supervisor locks."""
    return bytes((_H_SUPERVISOR, SUPERVISOR_EMERGENCY_STOP))


def encode_ext_pose(x: float, y: float, z: float, yaw: float) -> bytes:
    """cflib `Localization.send_extpose((x, y, z), quat)` of a yaw-only attitude (rad, CCW)."""
    if not _finite(x, y, z, yaw):
        raise ValueError("non-finite pose")
    half = 0.5 * yaw
    return bytes((header(PORT_LOCALIZATION, 1),)) + struct.pack("<Bfffffff", LOC_EXT_POSE, x, y, z, 0.0, 0.0,
                                                                 math.sin(half), math.cos(half))


def _clamp16(v: float) -> int:
    return int(min(max(round(v), -32768), 32767))


def encode_wheels(left_m_s: float, right_m_s: float) -> bytes:
    """Wheel protocol WHEELS: rim speeds in m/s, sent as int16 mm/s (clamped)."""
    if not _finite(left_m_s, right_m_s):
        raise ValueError("non-finite wheel speed")
    body = _WHEELS.pack(WHEEL_PROTOCOL_VERSION, MSG_WHEELS, _clamp16(left_m_s * 1000.0), _clamp16(right_m_s * 1000.0))
    return bytes((_H_APP,)) + body


def encode_status_request(seq: int) -> bytes:
    return bytes((_H_APP,)) + _STATUS_REQUEST.pack(WHEEL_PROTOCOL_VERSION, MSG_STATUS_REQUEST, seq & _U32)


def encode_status(st: Status) -> bytes:
    """A STATUS as the vehicle's app sends it (header 0xD2: the firmware leaves bits 3-2 clear)."""
    body = _STATUS.pack(WHEEL_PROTOCOL_VERSION, MSG_STATUS, st.echo_seq & _U32, st.received & _U32,
                        st.uptime_ms & _U32, st.rejected & 0xFFFF, min(max(st.vbat_mv, 0), 0xFFFF),
                        _clamp16(st.wheel_left_mm_s), _clamp16(st.wheel_right_mm_s),
                        min(max(st.setpoint_age_ms, 0), 0xFFFF), st.flags & 0xFF)
    return bytes((PORT_PLATFORM << 4 | APP_CHANNEL,)) + body


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


def decode_app_uplink(payload: bytes) -> Uplink:
    """An app-channel payload from the gateway, as the vehicle's wheel app reads it."""
    kind, payload = _app(payload)
    if kind == MSG_WHEELS:
        _, _, left, right = _exact(_WHEELS, payload, "WHEELS")
        return Wheels(left, right)
    if kind == MSG_STATUS_REQUEST:
        return StatusRequest(_exact(_STATUS_REQUEST, payload, "STATUS_REQUEST")[2])
    raise CrtpError(f"unknown uplink message type 0x{kind:02x}")


def decode_downlink(raw: bytes) -> Downlink:
    """An app-channel packet from the vehicle, as the gateway reads it (link control reads as `Null`)."""
    port, channel, payload = split(raw)
    if port == PORT_LINK:
        return Null()
    if port != PORT_PLATFORM or channel != APP_CHANNEL:
        raise CrtpError(f"unexpected downlink port {port} channel {channel}")
    kind, payload = _app(payload)
    if kind != MSG_STATUS:
        raise CrtpError(f"unknown downlink message type 0x{kind:02x}")
    return Status(*_exact(_STATUS, payload, "STATUS")[2:])
