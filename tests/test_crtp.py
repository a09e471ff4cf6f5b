"""CRTP packets: byte-for-byte what cflib sends, our wheel protocol round trips, malformed packets are
refused; and the cflib link path puts one packet per UDP datagram."""

from __future__ import annotations

import math
import socket
import threading

import pytest
from cflib.crazyflie.appchannel import Appchannel
from cflib.crazyflie.commander import Commander
from cflib.crtp.crtpstack import CRTPPacket

from common.bus.messages import FlightSetpoint
from common.crazyflie import crtp
from services.radio_gateway.link import CrtpLink


class _Capture:
    """Stands in for cflib's `Crazyflie` under its `Commander` / `Appchannel`: keeps what they send."""

    def __init__(self) -> None:
        self.packets: list[CRTPPacket] = []

    def send_packet(self, pk: CRTPPacket) -> None:
        self.packets.append(pk)

    def add_port_callback(self, *_args: object) -> None:
        pass

    def raw(self) -> bytes:
        pk = self.packets[-1]
        return bytes((pk.header,)) + bytes(pk.data)


@pytest.mark.parametrize("roll, pitch, yawrate, thrust", [(0.0, 0.0, 0.0, 0), (3.5, -7.25, 20.0, 48400),
                                                          (-25.0, 25.0, -90.0, 60000)])
def test_flight_setpoint_is_byte_for_byte_cflib_send_setpoint(roll: float, pitch: float, yawrate: float,
                                                               thrust: int) -> None:
    cf = _Capture()
    Commander(cf).send_setpoint(roll, pitch, yawrate, thrust)
    raw = crtp.encode_setpoint(FlightSetpoint(roll=roll, pitch=pitch, yawrate=yawrate, thrust=thrust))
    assert raw == cf.raw()
    back = crtp.decode_uplink(raw)
    assert back == FlightSetpoint(roll=roll, pitch=pitch, yawrate=yawrate, thrust=thrust)  # pitch sign restored


def test_stop_is_cflib_send_stop_setpoint_and_wheels_use_the_app_channel() -> None:
    cf = _Capture()
    Commander(cf).send_stop_setpoint()
    assert crtp.encode_stop() == cf.raw()
    assert isinstance(crtp.decode_uplink(cf.raw()), crtp.Stop)
    Appchannel(cf).send_packet(b"\x01")
    assert crtp.encode_wheels(0.1, -0.1)[0] == cf.packets[-1].header  # port 0x0D, channel 2


def test_wheel_protocol_round_trips() -> None:
    assert crtp.decode_uplink(crtp.encode_wheels(0.1234, -0.05)) == crtp.Wheels(123, -50)
    assert crtp.decode_uplink(crtp.encode_wheels(99.0, -99.0)) == crtp.Wheels(32767, -32768)  # clamped
    assert crtp.decode_uplink(crtp.encode_status_request(2**32 + 7)) == crtp.StatusRequest(7)
    st = crtp.Status(echo_sent=1000, received=990, setpoints=950, vbat_mv=3870, wheel_left_mm_s=-12,
                     wheel_right_mm_s=40, flags=crtp.FLAG_MOTORS | crtp.FLAG_FLYING)
    raw = crtp.encode_status(st)
    assert len(raw) == 22 and crtp.decode_downlink(raw) == st
    assert isinstance(crtp.decode_downlink(crtp.NULL_PACKET), crtp.Null)
    assert isinstance(crtp.decode_uplink(bytes((0xF3, 0x05, 0x01))), crtp.Null)  # safelink setup: link control


@pytest.mark.parametrize("raw", [
    b"",
    bytes(32),                                                   # 31 payload bytes
    crtp.encode_setpoint(FlightSetpoint(roll=0, pitch=0, yawrate=0, thrust=1))[:-1],
    bytes((crtp.header(3, 0),)) + bytes((0, 0, 0xC0, 0x7F)) * 3 + b"\x00\x00",   # NaN roll
    bytes((crtp.header(7, 0), 5)),                               # generic commander, not stop
    bytes((crtp.header(0x0D, 2), 2, crtp.MSG_WHEELS, 0, 0, 0, 0)),  # wheel protocol version 2
    bytes((crtp.header(0x0D, 2), 1, 0x7E)),                      # unknown message type
    bytes((crtp.header(0x0D, 2), 1)),                            # no type
    bytes((crtp.header(0x0D, 2), 1, crtp.MSG_WHEELS, 0, 0)),     # short WHEELS
    bytes((crtp.header(5, 1), 1, 2, 3)),                         # a port we do not speak
])
def test_malformed_uplink_packets_are_refused(raw: bytes) -> None:
    with pytest.raises(crtp.CrtpError):
        crtp.decode_uplink(raw)


def test_malformed_downlink_and_unencodable_setpoints_are_refused() -> None:
    for raw in (crtp.encode_wheels(0, 0), crtp.encode_status(crtp.Status(1, 1, 1, 1, 1, 1, 1))[:-1],
                crtp.encode_setpoint(FlightSetpoint(roll=0, pitch=0, yawrate=0, thrust=0))):
        with pytest.raises(crtp.CrtpError):
            crtp.decode_downlink(raw)
    for sp in (FlightSetpoint(roll=math.nan, pitch=0, yawrate=0, thrust=0),
               FlightSetpoint(roll=0, pitch=0, yawrate=0, thrust=70000),
               FlightSetpoint(roll=0, pitch=0, yawrate=0, thrust=-1)):
        with pytest.raises(ValueError):
            crtp.encode_setpoint(sp)
    with pytest.raises(ValueError):
        crtp.encode_wheels(math.inf, 0.0)


def test_cflib_udp_link_sends_one_packet_per_datagram_and_reads_replies() -> None:
    """The gateway's link code on cflib's UDP driver (the radio driver is the same code path)."""
    server = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    server.bind(("127.0.0.1", 0))
    server.settimeout(2.0)
    got: list[bytes] = []
    replied = threading.Event()

    def on_packet(vid: str, raw: bytes) -> None:
        got.append(raw)
        replied.set()

    link = CrtpLink("v1", f"udp://127.0.0.1:{server.getsockname()[1]}", on_packet, lambda *_: None)
    try:
        packets = [crtp.encode_setpoint(FlightSetpoint(roll=1.0, pitch=2.0, yawrate=3.0, thrust=40000)),
                   crtp.encode_wheels(0.05, 0.06), crtp.encode_status_request(3)]
        for raw in packets:
            assert link.send(raw)
        received = []
        for _ in packets:
            data, addr = server.recvfrom(64)
            received.append(data)
        assert received == packets
        status = crtp.encode_status(crtp.Status(3, 3, 2, 3900, 50, 60, 0))
        server.sendto(status, addr)
        assert replied.wait(2.0)
        assert got == [status]
    finally:
        link.close()
        server.close()
