"""The simulated radio's link model, and a simulated Crazyflie over real UDP driven through the
gateway's cflib link code: setpoints move the physics, status replies count, malformed packets are
counted and dropped, the commander watchdog is noticed."""

from __future__ import annotations

import asyncio
import time

import pytest

from common.bus.messages import FlightSetpoint
from common.crazyflie import crtp
from common.crazyflie.thrust import hover_command
from common.deploy.radios import LinkModel, free_udp_ports
from services.radio_gateway.link import CrtpLink
from services.sim.crazyflie.endpoint import SimCrazyflie
from services.sim.crazyflie.physics import SimFlyingCar
from services.sim.crazyflie.radio import SimRadio


def test_link_model_budget_loss_and_latency() -> None:
    radio = SimRadio("r", LinkModel(budget_pps=500, latency_s=0.002, loss=0.0, max_queue_s=0.01))
    times = [radio.uplink(0.0) for _ in range(8)]  # a burst: one slot of 2 ms each, in order
    assert times[:6] == pytest.approx([0.002 + 0.002 * i for i in range(6)])
    assert times[6:] == [None, None] and radio.congested == 2  # would wait more than 10 ms
    assert radio.uplink(1.0) == pytest.approx(1.002)
    lossy = SimRadio("r", LinkModel(budget_pps=1e6, loss=0.1, seed=3))
    delivered = sum(lossy.uplink(i * 1e-3) is not None for i in range(20000))
    assert delivered / 20000 == pytest.approx(0.9, abs=0.01)
    assert sum(lossy.downlink(0.0) is not None for _ in range(20000)) / 20000 == pytest.approx(0.9, abs=0.01)


async def _vehicle(loss: float = 0.0) -> tuple[SimCrazyflie, int, list[tuple[str, str, str]]]:
    port = free_udp_ports(1)[0]
    events: list[tuple[str, str, str]] = []
    cf = SimCrazyflie(SimFlyingCar("v1", t=time.time()), SimRadio("r", LinkModel(loss=loss)),
                      lambda *e: events.append(e))
    await asyncio.get_running_loop().create_datagram_endpoint(lambda: cf, local_addr=("127.0.0.1", port))
    return cf, port, events


async def _until(predicate, timeout: float = 3.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.01)


def test_sim_crazyflie_flies_answers_status_and_drops_garbage() -> None:
    async def main() -> None:
        cf, port, events = await _vehicle()
        replies: list[bytes] = []
        loop = asyncio.get_running_loop()
        link = CrtpLink("v1", f"udp://127.0.0.1:{port}", lambda _v, raw: loop.call_soon_threadsafe(replies.append, raw),
                        lambda *_: None)
        try:
            climb = crtp.encode_setpoint(FlightSetpoint(roll=0, pitch=0, yawrate=0, thrust=hover_command(0.041) + 4000))
            link.send(crtp.encode_setpoint(FlightSetpoint(roll=0, pitch=0, yawrate=0, thrust=0)))
            for _ in range(50):  # 0.5 s of a climbing setpoint at 100 Hz
                link.send(climb)
                await asyncio.sleep(0.01)
            link.send(b"\x3c\x01\x02")  # a truncated setpoint: counted and dropped
            link.send(crtp.encode_wheels(0.1, 0.1))
            link.send(crtp.encode_status_request(54))
            await _until(lambda: replies)
            status = crtp.decode_downlink(replies[-1])
            assert isinstance(status, crtp.Status)
            assert status.echo_sent == 54 and status.received == 53 and status.setpoints == 52
            assert status.flags & crtp.FLAG_MOTORS and status.flags & crtp.FLAG_FLYING
            assert 3.0 < status.vbat_mv / 1000 < 4.3
            assert cf.malformed == 1 and cf.flight_setpoints == 51
            cf.advance(time.time())
            assert cf.car.z > 0.01 and cf.car.vz > 0.0
            assert cf.max_flight_gap < 0.1 and cf.watchdog_levels == 0
            await asyncio.sleep(0.6)  # no setpoint for more than 0.5 s while armed
            cf.advance(time.time())
            assert cf.watchdog_levels == 1 and events[0][:2] == ("v1", "sim_watchdog_level")
            link.send(crtp.encode_status_request(55))
            await _until(lambda: len(replies) > 1)
            assert crtp.decode_downlink(replies[-1]).flags & crtp.FLAG_WATCHDOG_LEVEL
        finally:
            link.close()
            cf.close()

    asyncio.run(main())
