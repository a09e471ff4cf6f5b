"""The simulated radio's link model, and a simulated Crazyflie over real UDP with a bare socket as the
client: the wheel app answers version 2 of the wheel protocol with what an app can know, its
watchdog stops the wheels, malformed packets are counted, cflib's scan is answered, and the
request/reply traffic cflib waits for is never lost while streams are."""

from __future__ import annotations

import asyncio
import socket
import threading
import time

import pytest

from common.bus.messages import FlightSetpoint
from common.crazyflie import crtp
from common.deploy.radios import LinkModel, free_udp_ports
from services.sim.crazyflie.endpoint import SimCrazyflie, reliable
from services.sim.crazyflie.physics import SimFlyingCar
from services.sim.crazyflie.radio import SimRadio


def test_link_model_budget_loss_and_latency() -> None:
    radio = SimRadio("r", LinkModel(budget_pps=500, latency_s=0.002, loss=0.0, max_queue_s=0.01))
    times = [radio.uplink(0.0) for _ in range(8)]  # a burst: one slot of 2 ms each, in order
    assert times[:6] == pytest.approx([0.002 + 0.002 * i for i in range(6)])
    assert times[6:] == [None, None] and radio.congested == 2  # would wait more than 10 ms
    assert radio.uplink(0.0, reliable=True) == pytest.approx(0.002 + 0.002 * 6)  # a request waits its turn
    assert radio.uplink(1.0) == pytest.approx(1.002)
    lossy = SimRadio("r", LinkModel(budget_pps=1e6, loss=0.1, seed=3))
    delivered = sum(lossy.uplink(i * 1e-3) is not None for i in range(20000))
    assert delivered / 20000 == pytest.approx(0.9, abs=0.01)
    assert sum(lossy.downlink(0.0) is not None for _ in range(20000)) / 20000 == pytest.approx(0.9, abs=0.01)
    assert all(lossy.uplink(30.0 + i * 1e-3, reliable=True) is not None for i in range(1000))


def test_what_cflib_waits_for_is_reliable_and_streams_are_not() -> None:
    assert reliable(bytes((0x5C, 3))) and reliable(bytes((0x2D, 0, 0))) and reliable(bytes((0xFD, 0)))
    assert reliable(bytes((0x9D, 1, 1))) and reliable(bytes((0xDD, 0))) and reliable(bytes((0x8C, 7)))
    assert not reliable(crtp.encode_stop()) and not reliable(bytes((0x52, 1, 0, 0, 0)))  # setpoints, log data
    assert not reliable(crtp.encode_wheels(0.1, 0.1)) and not reliable(bytes((0xFC, 0)))  # app channel, pings


def test_a_packet_read_late_takes_effect_at_its_delivery_time() -> None:
    """A simulator starved for a while advances its vehicles to the wall clock before it gets to
    the packets that reached them meanwhile: each still takes effect at its delivery time, not when
    the simulator got to it (here a stop's: the vehicle used to drive on for the whole stall)."""
    async def main() -> tuple[float, float]:
        clock = [1000.0]
        cf = SimCrazyflie(SimFlyingCar("v1", t=clock[0]), SimRadio("r", LinkModel(loss=0.0)), clock=lambda: clock[0])
        addr = ("127.0.0.1", 9)

        def to(t: float) -> None:
            clock[0] = t
            cf.advance(t)

        while not cf.firmware.running:  # boots
            to(clock[0] + 0.01)
        for _ in range(100):  # drives for a second, each command delivered in its turn (2 ms of radio)
            cf.datagram_received(crtp.encode_wheels(0.1, 0.1), addr, clock[0])
            await asyncio.sleep(0.003)
            to(clock[0] + 0.01)
        assert cf.car.wheel_left > 0.09
        cf.datagram_received(crtp.encode_wheels(0.0, 0.0), addr, clock[0])  # the stop reaches the vehicle
        x_stop = cf.car.x
        to(clock[0] + 0.5)  # ... while the simulator's loop is starved: it next advances to the wall clock
        await asyncio.sleep(0.003)  # then the delivery it had scheduled
        return x_stop, cf.car.x

    x_stop, x_end = asyncio.run(main())
    assert x_end - x_stop < 0.01, f"drove on {100 * (x_end - x_stop):.1f} cm after its stop arrived"


async def _vehicle(loss: float = 0.0) -> tuple[SimCrazyflie, int]:
    port = free_udp_ports(1)[0]
    cf = SimCrazyflie(SimFlyingCar("v1", t=time.time()), SimRadio("r", LinkModel(loss=loss)))
    cf.listen(("127.0.0.1", port))
    return cf, port


def test_the_wheel_app_drives_answers_status_v2_and_its_watchdog_stops_the_wheels() -> None:
    async def main() -> None:
        cf, port = await _vehicle()
        client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        client.setblocking(False)
        client.connect(("127.0.0.1", port))
        loop = asyncio.get_running_loop()

        async def reply() -> bytes:
            """The next packet on the link or the app channel (console lines, e.g. "SUP: Ready to fly", skipped)."""
            while True:
                raw = await asyncio.wait_for(loop.sock_recv(client, 64), 2.0)
                if raw[0] >> 4 in (crtp.PORT_LINK, crtp.PORT_PLATFORM):
                    return raw

        try:
            client.send(crtp.NULL_PACKET)  # cflib's scan
            assert await reply() == crtp.NULL_PACKET
            for _ in range(20):
                client.send(crtp.encode_wheels(0.1, 0.1))
                await asyncio.sleep(0.01)
            client.send(bytes((0xDE, 1, crtp.MSG_WHEELS, 0, 0, 0, 0)))  # version 1: rejected
            client.send(crtp.encode_status_request(22))
            status = crtp.decode_downlink(await reply())
            assert isinstance(status, crtp.Status)
            assert (status.echo_seq, status.received, status.rejected) == (22, 22, 1)
            # armed and not flying, the stopped high-level commander pushes a null setpoint at 100 Hz
            # (`crtpCommanderHighLevelGetSetpoint()`): the age the supervisor watches stays below a period or two
            assert status.wheel_left_mm_s == 100 and status.setpoint_age_ms <= 20
            assert status.flags & crtp.FLAG_ARMED and not status.flags & (crtp.FLAG_MOTORS | crtp.FLAG_LOCKED)
            assert 3000 < status.vbat_mv < 4300 and status.uptime_ms > 0
            cf.advance(time.time())
            assert cf.car.wheel_left > 0.05
            await asyncio.sleep(0.7)  # no WHEELS for more than 0.5 s
            cf.advance(time.time())
            client.send(crtp.encode_status_request(23))
            status = crtp.decode_downlink(await reply())
            assert status.flags & crtp.FLAG_WHEEL_WATCHDOG and status.wheel_left_mm_s == 0
            assert cf.wheel_watchdogs == 1 and cf.car.wheel_left < 0.01
        finally:
            client.close()
            cf.close()

    asyncio.run(main())


def test_a_stock_crazyflie_has_no_app_and_malformed_packets_are_counted() -> None:
    async def main() -> None:
        port = free_udp_ports(1)[0]
        cf = SimCrazyflie(SimFlyingCar("v1", t=time.time()), SimRadio("r", LinkModel(loss=0.0)), wheels=False)
        cf.listen(("127.0.0.1", port))
        client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        client.connect(("127.0.0.1", port))
        try:
            client.send(crtp.encode_status_request(1))
            client.send(bytes((0x3C, 1, 2)))  # a truncated RPYT setpoint
            client.send(bytes((0x7C, 7, 0)))  # a truncated position setpoint
            await asyncio.sleep(0.2)
            assert cf.firmware.malformed == 2 and cf.firmware.app is None and cf.received == 3
        finally:
            client.close()
            cf.close()

    asyncio.run(main())


def test_a_busy_simulator_takes_every_waiting_setpoint_at_once_at_the_time_it_arrived() -> None:
    """Setpoints that arrive while the simulator's event loop is busy wait in the kernel; once it
    looks, it takes them all, in order, each at the time the kernel received it (module docstring of
    `endpoint`): the setpoint in force is the last one sent, stamped when it was sent. (Read one per
    loop iteration, as asyncio's datagram transport does, a loop kept busy took them seconds late.)"""
    async def main() -> None:
        cf, port = await _vehicle()
        client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        client.connect(("127.0.0.1", port))
        loop = asyncio.get_running_loop()
        thrusts = [0] + [20000 + 100 * i for i in range(100)]  # (a zero first: the RPYT thrust lock)

        def send() -> None:
            for thrust in thrusts:
                client.send(crtp.encode_setpoint(FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=thrust)))
                time.sleep(0.004)

        busy = True

        def churn() -> None:  # a simulator with much to do: every loop iteration takes 5 ms
            if busy:
                time.sleep(0.005)
                loop.call_soon(churn)

        try:
            sender = threading.Thread(target=send)
            sender.start()
            sender.join()  # the event loop is stalled while they arrive
            last_sent = time.time()
            loop.call_soon(churn)
            await asyncio.sleep(0.05)
            busy = False
            assert cf.received == len(thrusts)
            assert cf.firmware.commander.setpoint.thrust == thrusts[-1]
            assert last_sent - 0.05 < cf.firmware.commander.timestamp < last_sent + 0.01
        finally:
            client.close()
            cf.close()

    asyncio.run(main())
