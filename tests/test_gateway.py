"""The gateway end to end: a real in-process zenoh router, the gateway, simulated Crazyflies over real
UDP on 127.0.0.1 (cflib's UDP driver), stand-in executors publishing `Cmd` at 100 Hz, and for the
safety landing the simulated motion capture."""

from __future__ import annotations

import asyncio
import logging
import signal
import socket
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.liveliness import watch_alive
from common.bus.messages import Cmd, CmdBatch, FlightSetpoint, Telemetry, VehicleEvent
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import ZenohConfig
from common.deploy.radios import LinkModel, RadiosFile, RadioSpec, VehicleLink, dump_radios, simulated_radios
from common.domain.ownership import owner_of
from services.mocap_bridge.bridge import MocapBridge
from services.mocap_bridge.config import MocapConfig
from services.radio_gateway.gateway import RadioGateway
from services.sim.crazyflie.service import SimService
from tests.support.fleet_faults import until
from tests.support.loadgen import LoadCommander, running

REPO = Path(__file__).resolve().parents[1]
KEYS = Keys()
FLYERS = ["cf0", "cf1", "cf2", "cf3"]
DRIVERS = ["cf4", "cf5"]


class Watch:
    """Telemetry and events of every vehicle, as any other process sees them."""

    def __init__(self, session: zenoh.Session) -> None:
        self.telemetry: dict[str, Telemetry] = {}
        self.history: dict[str, list[Telemetry]] = defaultdict(list)
        self.events: list[VehicleEvent] = []
        subscribe(session, KEYS.all_vehicles("telemetry"), Telemetry, self._on_telemetry)
        subscribe(session, KEYS.all_vehicles("event"), VehicleEvent, lambda m, _k: self.events.append(m))

    def _on_telemetry(self, tel: Telemetry, _key: str) -> None:
        self.telemetry[tel.vid] = tel
        self.history[tel.vid].append(tel)

    def kinds(self, vid: str) -> list[str]:
        return [e.kind for e in self.events if e.vid == vid]


def _starts(vids: list[str]) -> dict[str, tuple[float, float, float]]:
    return {vid: (0.4 * i, 0.0, 0.0) for i, vid in enumerate(vids)}


async def _setpoint_rates(sim: SimService, vids: list[str], seconds: float) -> dict[str, float]:
    """Flight setpoints each simulated vehicle received per second, over `seconds`."""
    before = {vid: sim.vehicles[vid].flight_setpoints for vid in vids}
    t0 = time.monotonic()
    await asyncio.sleep(seconds)
    dt = time.monotonic() - t0
    return {vid: (sim.vehicles[vid].flight_setpoints - before[vid]) / dt for vid in vids}


def _airborne(sim: SimService, vids: list[str], z: float = 0.35) -> Callable[[], bool]:
    return lambda: all(v in sim.vehicles and sim.vehicles[v].car.z > z for v in vids)


@pytest.mark.flight
def test_four_vehicles_fly_at_50hz_or_more_while_two_drive_on_one_radio(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    cfg = ZenohConfig.client(zenoh_router)
    spec = simulated_radios(_starts(FLYERS + DRIVERS), per_radio=6)
    sim, gw = SimService(spec, cfg), RadioGateway("r0", spec, cfg)
    cmd = LoadCommander("e1", cfg, flyers=FLYERS, drivers=DRIVERS)
    session = zsession()

    async def main() -> None:
        watch = Watch(session)
        async with running(sim, gw, cmd):
            await until(_airborne(sim, FLYERS), 6.0, "the flyers to climb")
            x0 = {vid: sim.vehicles[vid].car.x for vid in DRIVERS}
            echoes = {vid: cf.firmware.echoes for vid, cf in sim.vehicles.items()}
            rates = await _setpoint_rates(sim, FLYERS, 3.0)
            # cflib's 10 Hz link-statistics pings are stopped once a link connects: no airtime for them
            assert {vid: cf.firmware.echoes for vid, cf in sim.vehicles.items()} == echoes
            print("per-vehicle setpoint rates (Hz):", {v: round(r, 1) for v, r in rates.items()})
            assert min(rates.values()) >= 50.0
            for vid in FLYERS:
                cf = sim.vehicles[vid]
                assert cf.max_flight_gap < 0.1 and cf.watchdog_levels == 0 and abs(cf.car.z - 0.5) < 0.1
                tel = watch.telemetry[vid]
                assert tel.link_ok and tel.cmd_rate_hz >= 50.0 and 3.0 < tel.vbat < 4.3 and tel.gateway == "r0"
                assert tel.sent > 0 and tel.dropped < 0.05 * tel.sent and tel.owner == "e1" and tel.link_quality > 0.9
                assert tel.supervisor & 0x18 == 0x18 and tel.rssi > 0  # can fly, flying (supervisor.info)
            for vid in DRIVERS:
                cf = sim.vehicles[vid]
                assert cf.car.x - x0[vid] > 0.1  # 0.05 m/s for 3 s
                assert cf.car.z == 0.0 and cf.wheel_watchdogs == 0 and watch.telemetry[vid].link_ok
            assert set(watch.kinds("cf0")) <= {"link_open", "link_up", "link_closed", "link_error"}
            assert "link_up" in watch.kinds("cf0")
            assert gw.counters.total("refused:") == 0 and gw.counters.total() == 0

    asyncio.run(main())


def test_a_stale_commander_makes_the_vehicle_land_and_a_driver_stop(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    cfg = ZenohConfig.client(zenoh_router)
    spec = simulated_radios(_starts(["cf0", "cf1", "cf2"]), per_radio=3)
    sim, gw, mocap = SimService(spec, cfg), RadioGateway("r0", spec, cfg), MocapBridge(MocapConfig(), cfg)
    cmd = LoadCommander("e1", cfg, flyers=["cf0", "cf1"], drivers=["cf2"])
    session = zsession()

    async def main() -> None:
        watch = Watch(session)
        async with running(sim, gw, mocap, cmd):
            await until(_airborne(sim, ["cf0", "cf1"]), 6.0, "the flyers to climb")
            cmd.silence("cf0")
            cmd.silence("cf2")
            lowest = 0.0
            landed = lambda: "landed" in watch.kinds("cf0")  # noqa: E731
            async with asyncio.timeout(8.0):
                while not landed():
                    lowest = min(lowest, sim.vehicles["cf0"].car.vz)
                    await asyncio.sleep(0.01)
            await asyncio.sleep(0.3)
            cf0, cf1, cf2 = (sim.vehicles[v] for v in ("cf0", "cf1", "cf2"))
            truth = cf0.car.truth()
            assert truth.z == 0.0 and not truth.airborne and not truth.motors
            assert cf0.car.last_impact_speed < 0.35 and lowest > -0.4  # a gentle landing
            assert cf0.watchdog_levels == 0  # the gateway never let the firmware watchdog act
            assert abs(cf1.car.z - 0.5) < 0.1 and cf1.watchdog_levels == 0
            assert cf2.car.wheel_left == pytest.approx(0.0, abs=1e-3) and cf2.wheel_watchdogs == 0
            events = {e.kind: e for e in watch.events if e.vid in ("cf0", "cf2")}
            assert "under position control" in events["landed"].detail
            assert "stale_cmd_landing" in watch.kinds("cf0") and "stale_cmd_stop" in watch.kinds("cf2")
            assert watch.telemetry["cf0"].stale_cmd and not watch.telemetry["cf1"].stale_cmd

    asyncio.run(main())


def test_refused_commands_are_counted_and_logged_once(
        zenoh_router: str, zsession: Callable[..., zenoh.Session], caplog: pytest.LogCaptureFixture) -> None:
    """A vehicle of another radio, a cmd naming another vehicle, a sender that is not the owner, a
    malformed cmd, a malformed packet from a vehicle: all dropped and counted, nothing crashes."""
    cfg = ZenohConfig.client(zenoh_router)
    rogue = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rogue.bind(("127.0.0.1", 0))
    rogue.settimeout(0.05)
    base = simulated_radios({"cf0": (0.0, 0.0, 0.0), "x9": (1.0, 0.0, 0.0)}, per_radio=1)
    spec = RadiosFile(radios={**base.radios, "r9": RadioSpec(
        vehicles={"rogue": VehicleLink(uri=f"udp://127.0.0.1:{rogue.getsockname()[1]}")})})
    sim = SimService(spec, cfg, radios=["r0", "r1"])
    gw, gw9 = RadioGateway("r0", spec, cfg), RadioGateway("r9", spec, cfg)
    cmd = LoadCommander("e1", cfg, flyers=["cf0", "x9"])
    session = zsession()
    caplog.set_level(logging.INFO, logger="services.radio_gateway.gateway")

    async def answer_garbage() -> None:
        while True:
            try:
                _data, addr = await asyncio.to_thread(rogue.recvfrom, 64)
                rogue.sendto(b"\xd2\x02\x81\x00", addr)  # a status cut short, on the app channel
            except TimeoutError:
                pass

    async def main() -> None:
        cmd_key = KEYS.vehicle("cf0", "cmd")
        async with running(sim, gw, gw9, cmd):
            garbage = asyncio.create_task(answer_garbage())
            await until(_airborne(sim, ["cf0"], 0.2), 6.0, "cf0 to climb")
            hover = FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=0)
            for _ in range(5):
                session.put(cmd_key, msgspec.msgpack.encode(Cmd(vid="cf7", owner="e1", seq=1, t=0.0, setpoint=hover)))
                session.put(cmd_key, msgspec.msgpack.encode(Cmd(vid="cf0", owner="intruder", seq=1, t=0.0,
                                                                setpoint=hover)))
                session.put(cmd_key, b"\x93not a cmd")
            await asyncio.sleep(1.5)
            garbage.cancel()
            assert sim.vehicles["x9"].received == 0 and sim.vehicles["cf0"].car.z > 0.2
            assert gw.counters["refused:unassigned:x9"] > 50
            assert gw.counters["refused:vid_mismatch:cf0"] == 5 and gw.counters["refused:not_owner:cf0"] == 5
            assert gw.counters["drop:malformed:Cmd:fleet/default/vehicle/cf0/cmd"] == 5
            assert not gw9.channels["rogue"].health.link_ok and gw9.connections["rogue"].state != "open"
        rogue.close()
        refusals = [r.getMessage() for r in caplog.records if "r0: refused cmd for x9" in r.getMessage()]
        assert len(refusals) == 1

    asyncio.run(main())


def test_only_the_current_owner_is_obeyed(zenoh_router: str) -> None:
    cfg = ZenohConfig.client(zenoh_router)
    spec = simulated_radios({"cf0": (0.0, 0.0, 0.0)}, per_radio=1)
    sim, gw = SimService(spec, cfg), RadioGateway("r0", spec, cfg)
    low = LoadCommander("e1", cfg, flyers=["cf0"], z_ref=0.3)
    high = LoadCommander("e2", cfg, flyers=["cf0"], z_ref=0.7)
    owner, other = (low, high) if owner_of("cf0", ["e1", "e2"]) == "e1" else (high, low)

    async def main() -> None:
        async with running(sim, gw, low, high):
            await until(_airborne(sim, ["cf0"], 0.2), 6.0, "cf0 to climb")
            car = sim.vehicles["cf0"].car
            await until(lambda: gw.owners["cf0"] == owner.instance and abs(car.z - owner.z_ref) < 0.03, 8.0,
                        "the owner's height")
            await asyncio.sleep(0.5)
            assert abs(car.z - owner.z_ref) < 0.03
            assert gw.counters["refused:not_owner:cf0"] > 40
            owner.stop()  # the owner dies: its vehicle passes to the other executor
            await until(lambda: abs(car.z - other.z_ref) < 0.03, 8.0, "the new owner's height")
            assert gw.owners["cf0"] == other.instance and sim.vehicles["cf0"].watchdog_levels == 0

    asyncio.run(main())


@pytest.mark.flight
def test_ten_percent_loss_still_delivers_45hz_without_firmware_watchdog(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    cfg = ZenohConfig.client(zenoh_router)
    spec = simulated_radios(_starts(FLYERS + DRIVERS), per_radio=6, link=LinkModel(loss=0.10, seed=7))
    sim = SimService(spec, cfg)
    gw = RadioGateway("r0", spec, cfg, subscribe_each=True)
    cmd = LoadCommander("e1", cfg, flyers=FLYERS, drivers=DRIVERS)
    session = zsession()

    async def main() -> None:
        watch = Watch(session)
        async with running(sim, gw, cmd):
            await until(_airborne(sim, FLYERS), 6.0, "the flyers to climb")
            rates = await _setpoint_rates(sim, FLYERS, 3.0)
            print("per-vehicle setpoint rates at 10 % loss (Hz):", {v: round(r, 1) for v, r in rates.items()})
            assert min(rates.values()) >= 45.0
            gaps = {vid: sim.vehicles[vid].max_flight_gap for vid in FLYERS}
            # the watchdog levels after 0.5 s; on a loaded machine a run of lost packets and a late
            # gateway tick made 0.106 s (CI, 2026-12-02), so the bound is well below that, not 0.1 s
            assert max(gaps.values()) < 0.25, gaps
            for vid in FLYERS + DRIVERS:
                cf = sim.vehicles[vid]
                assert cf.watchdog_levels == cf.watchdog_cuts == cf.wheel_watchdogs == 0
                assert watch.telemetry[vid].link_ok
            assert sum(watch.telemetry[vid].dropped for vid in FLYERS + DRIVERS) > 0  # the wheel app counts losses
            quality = [t.link_quality for t in watch.history["cf0"][-10:]]
            assert 0.7 < sum(quality) / len(quality) < 0.985, quality  # 10 % of the log blocks lost
            kinds: dict[str, int] = defaultdict(int)
            for e in watch.events:
                kinds[e.kind] += 1
            assert set(kinds) <= {"link_open", "link_up", "link_closed"}, kinds  # closed: the sim not up yet
            assert sim.radios["r0"].lost > 0

    asyncio.run(main())


async def _links_up(watch: Watch, vids: list[str]) -> None:
    await until(lambda: all(v in watch.telemetry and watch.telemetry[v].link_ok for v in vids), 20.0, "the links up")


def test_telemetry_goes_out_at_its_rate_however_often_command_batches_wake_the_gateway(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    """Two executors' command batches each control cycle (a radio's vehicles spread over both) make
    the gateway tick about twice a period: each vehicle's telemetry still goes out at `status_hz`
    (5 Hz), not at twice it (counted in ticks, the soak's went out at 10.6 Hz)."""
    cfg = ZenohConfig.client(zenoh_router)
    vids = ["cf0", "cf1"]
    spec = simulated_radios(_starts(vids), per_radio=2)
    sim, gw = SimService(spec, cfg), RadioGateway("r0", spec, cfg)
    session = zsession()
    batches = Publisher(session, KEYS.gateway_cmd("r0"), CmdBatch)

    async def main() -> dict[str, int]:
        watch = Watch(session)
        async with running(sim, gw):
            await _links_up(watch, vids)
            loop = asyncio.get_running_loop()
            before = {vid: len(watch.history[vid]) for vid in vids}
            due, end = loop.time(), loop.time() + 3.0
            while loop.time() < end:  # e1's batch, then e2's 5 ms later, every 10 ms
                for owner in ("e1", "e2"):
                    batches.put(CmdBatch(owner=owner, t=time.time(), cmds=[]))
                    due += 0.005
                    await asyncio.sleep(max(due - loop.time(), 0.0))
            return {vid: len(watch.history[vid]) - before[vid] for vid in vids}

    heard = asyncio.run(main())
    rate = spec.gateway.status_hz
    assert all(2.0 * rate <= n <= 4.0 * rate for n in heard.values()), heard  # 3 s at 5 Hz: 15 (ticks: 30)


@pytest.mark.timeout(90)
def test_one_gateway_process_serves_several_radios_each_its_own_gateway(
        zenoh_router: str, zsession: Callable[..., zenoh.Session], tmp_path: Path) -> None:
    """`fleet gateway --radio r0 --radio r1`: one process, a gateway per radio named after it (its
    liveliness token, its vehicles' telemetry), every link up; a signal stops the process cleanly."""
    vids = ["cf0", "cf1", "cf2", "cf3"]
    spec = simulated_radios(_starts(vids), per_radio=2)
    path = tmp_path / "radios.yaml"
    path.write_text(dump_radios(spec))
    sim = SimService(spec, ZenohConfig.client(zenoh_router))
    session = zsession()
    argv = [sys.executable, "-m", "services.cli", "gateway", "--config", str(path), "--radio", "r0", "--radio", "r1",
            "--subscribe-each", "--connect", zenoh_router, "--fleet", KEYS.fleet]

    async def main() -> dict[str, str]:
        watch = Watch(session)
        alive = await watch_alive(session, KEYS, "gateway")
        async with running(sim):
            gateway = subprocess.Popen(argv, cwd=REPO, stderr=subprocess.PIPE, text=True)
            try:
                await alive.wait_until(lambda s: s == {"r0", "r1"}, 60)
                await _links_up(watch, vids)
                served = {vid: watch.telemetry[vid].gateway for vid in vids}
                gateway.send_signal(signal.SIGTERM)
                await alive.wait_until(lambda s: not s, 10)
                _, stderr = gateway.communicate(timeout=10)
            finally:
                gateway.kill()
        assert gateway.returncode == 0, stderr
        assert "Traceback" not in stderr
        return served

    assert asyncio.run(main()) == {vid: radio for radio, r in spec.radios.items() for vid in r.vehicles}
