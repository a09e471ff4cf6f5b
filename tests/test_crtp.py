"""CRTP packets: byte for byte what cflib 0.1.34 sends for the same call, our wheel protocol (version
2) round trips and matches the example bytes of firmware/wheels/PROTOCOL.md, malformed packets are
refused."""

from __future__ import annotations

import math

import pytest
from cflib.crazyflie.appchannel import Appchannel
from cflib.crazyflie.commander import Commander
from cflib.crazyflie.localization import Localization
from cflib.crazyflie.supervisor import Supervisor
from cflib.crtp.crtpstack import CRTPPacket

from common.bus.messages import FlightSetpoint
from common.crazyflie import crtp


class _Capture:
    """Stands in for cflib's `Crazyflie` under its `Commander` / `Appchannel` / ...: keeps what they
    send. Protocol version 12, as the current firmware reports."""

    def __init__(self) -> None:
        self.packets: list[CRTPPacket] = []
        self.platform = self

    def send_packet(self, pk: CRTPPacket) -> None:
        self.packets.append(pk)

    def add_port_callback(self, *_args: object) -> None:
        pass

    def add_header_callback(self, *_args: object, **_kw: object) -> None:
        pass

    def get_protocol_version(self) -> int:
        return 12

    def raw(self) -> bytes:
        pk = self.packets[-1]
        return bytes((pk.header,)) + bytes(pk.data)


@pytest.mark.parametrize("roll, pitch, yawrate, thrust", [(0.0, 0.0, 0.0, 0), (3.5, -7.25, 20.0, 48400),
                                                          (-25.0, 25.0, -90.0, 60000)])
def test_flight_setpoint_is_byte_for_byte_cflib_send_setpoint(roll: float, pitch: float, yawrate: float,
                                                               thrust: int) -> None:
    cf = _Capture()
    Commander(cf).send_setpoint(roll, pitch, yawrate, thrust)
    assert crtp.encode_setpoint(FlightSetpoint(roll=roll, pitch=pitch, yawrate=yawrate, thrust=thrust)) == cf.raw()


def test_stop_notify_position_supervisor_and_pose_are_cflibs() -> None:
    cf = _Capture()
    commander = Commander(cf)
    commander.send_stop_setpoint()
    assert crtp.encode_stop() == cf.raw()
    commander.send_notify_setpoint_stop()
    assert crtp.encode_notify_setpoint_stop() == cf.raw()
    commander.send_position_setpoint(1.0, -2.0, 0.5, 90.0)
    assert crtp.encode_position(1.0, -2.0, 0.5, 90.0) == cf.raw()
    supervisor = Supervisor(cf)
    supervisor.send_arming_request(True)
    assert crtp.encode_arming(True) == cf.raw()
    supervisor.send_crash_recovery_request()
    assert crtp.encode_crash_recovery() == cf.raw()
    supervisor.send_emergency_stop()
    assert crtp.encode_emergency_stop() == cf.raw()
    yaw = 0.7
    Localization(cf).send_extpose((1.0, 2.0, 0.3), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))
    assert crtp.encode_ext_pose(1.0, 2.0, 0.3, yaw) == cf.raw()
    Appchannel(cf).send_packet(b"\x02")
    assert crtp.encode_wheels(0.1, -0.1)[0] == cf.packets[-1].header  # port 0x0D, channel 2


def test_wheel_protocol_round_trips_and_matches_the_firmwares_example_bytes() -> None:
    assert crtp.encode_wheels(0.1, -0.05) == bytes.fromhex("de02016400ceff")
    assert crtp.encode_status_request(1234) == bytes.fromhex("de0202d2040000")
    assert crtp.decode_app_uplink(crtp.encode_wheels(0.1234, -0.05)[1:]) == crtp.Wheels(123, -50)
    assert crtp.decode_app_uplink(crtp.encode_wheels(99.0, -99.0)[1:]) == crtp.Wheels(32767, -32768)  # clamped
    assert crtp.decode_app_uplink(crtp.encode_status_request(2**32 + 7)[1:]) == crtp.StatusRequest(7)
    # STATUS A of PROTOCOL.md: driving, armed, never a flight setpoint
    a = crtp.Status(echo_seq=1234, received=1230, uptime_ms=61234, rejected=0, vbat_mv=3870, wheel_left_mm_s=100,
                    wheel_right_mm_s=-50, setpoint_age_ms=65535, flags=crtp.FLAG_ARMED)
    raw = bytes.fromhex("d20281d2040000ce04000032ef000000001e0f6400ceffffff10")
    assert crtp.encode_status(a) == raw and crtp.decode_downlink(raw) == a
    # STATUS C: hovering, last setpoint 8 ms ago, flags MOTORS | FLYING | ARMED
    c = crtp.Status(5000, 4990, 120500, 2, 3650, 0, 0, 8, crtp.FLAG_MOTORS | crtp.FLAG_FLYING | crtp.FLAG_ARMED)
    raw = bytes.fromhex("d2028188130000" "7e130000" "b4d60100" "0200" "420e" "0000" "0000" "0800" "1c")
    assert crtp.encode_status(c) == raw and crtp.decode_downlink(raw) == c
    assert isinstance(crtp.decode_downlink(crtp.NULL_PACKET), crtp.Null)


@pytest.mark.parametrize("payload", [
    b"",
    bytes((1, crtp.MSG_WHEELS, 0, 0, 0, 0)),  # wheel protocol version 1
    bytes((2, 0x7E)),                         # unknown message type
    bytes((2,)),                              # no type
    bytes((2, crtp.MSG_WHEELS, 0, 0)),        # short WHEELS
    bytes((2, crtp.MSG_STATUS_REQUEST, 0)),   # short STATUS_REQUEST
])
def test_malformed_app_packets_are_refused(payload: bytes) -> None:
    with pytest.raises(crtp.CrtpError):
        crtp.decode_app_uplink(payload)


def test_malformed_downlink_and_unencodable_setpoints_are_refused() -> None:
    for raw in (crtp.encode_wheels(0, 0), crtp.encode_status(crtp.Status(1, 1, 1, 1, 1, 1, 1, 1, 1))[:-1],
                crtp.encode_setpoint(FlightSetpoint(roll=0, pitch=0, yawrate=0, thrust=0)), b"", bytes(32)):
        with pytest.raises(crtp.CrtpError):
            crtp.decode_downlink(raw)
    for sp in (FlightSetpoint(roll=math.nan, pitch=0, yawrate=0, thrust=0),
               FlightSetpoint(roll=0, pitch=0, yawrate=0, thrust=70000),
               FlightSetpoint(roll=0, pitch=0, yawrate=0, thrust=-1)):
        with pytest.raises(ValueError):
            crtp.encode_setpoint(sp)
    with pytest.raises(ValueError):
        crtp.encode_wheels(math.inf, 0.0)
    with pytest.raises(ValueError):
        crtp.encode_position(math.nan, 0.0, 0.0, 0.0)
