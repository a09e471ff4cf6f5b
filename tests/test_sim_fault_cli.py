"""`fleet sim fault` (issue 16 item 5): run as a process, as the operator, against a simulated fleet
running in this process behind the shipped access control. `power_off` drops a hovering vehicle to
the ground (ground truth) and silences it (nothing answers: the gateway loses its link) while its
neighbour on the same radio flies on; `power_on` boots it as a fresh power-on and the gateway
reconnects it. Bad input exits 2 without a traceback; only the operator role may inject."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from common.bus.keys import Keys
from common.bus.messages import SimTruth, Telemetry
from common.bus.pubsub import subscribe
from common.bus.session import InProcessRouter, open_session
from common.deploy.credentials import Credentials, make_credentials
from common.deploy.radios import GatewayParams, LinkModel, simulated_radios
from services.radio_gateway.gateway import RadioGateway
from services.sim.crazyflie.endpoint import SimCrazyflie
from services.sim.crazyflie.physics import SimFlyingCar
from services.sim.crazyflie.radio import SimRadio
from services.sim.crazyflie.service import SimService
from services.sim.fault import fault_from_args
from tests.support.fleet_faults import until
from tests.support.loadgen import LoadCommander, running

REPO = Path(__file__).resolve().parents[1]
KEYS = Keys("simfault")


def fleet_sim_fault(endpoint: str, creds: Credentials, *args: str, role: str = "mission",
                    ) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **creds.env(role)}
    return subprocess.run([sys.executable, "-m", "services.cli", "sim", "fault", *args, "--connect", endpoint,
                           "--fleet", KEYS.fleet], cwd=REPO, capture_output=True, text=True, timeout=60, env=env)


@pytest.mark.timeout(120)
def test_power_off_drops_and_silences_a_vehicle_and_power_on_boots_it(tmp_path: Path) -> None:
    creds = make_credentials(tmp_path / "secrets")
    with InProcessRouter(**creds.router_options()) as router:
        cfg = lambda role: router.client_config(**creds.options(role))  # noqa: E731
        spec = simulated_radios({"cf0": (0.0, 0.0, 0.0), "cf1": (0.6, 0.0, 0.0)}, per_radio=2,
                                gateway=GatewayParams(connect_timeout_s=2.0))
        sim = SimService(spec, cfg("sim"), keys=KEYS)
        gateway = RadioGateway("r0", spec, cfg("gateway"), keys=KEYS)
        hover = LoadCommander("e1", cfg("executor"), flyers=["cf0", "cf1"], keys=KEYS)
        telemetry: dict[str, Telemetry] = {}

        async def main() -> None:
            session = open_session(cfg("mission"))
            subscribe(session, KEYS.all_vehicles("telemetry"), Telemetry, lambda m, _k: telemetry.__setitem__(m.vid, m))
            # the executor role may not read ground truth: the stand-in's hover loop gets it from here
            subscribe(session, KEYS.all_sim_truth, SimTruth, lambda m, _k: hover.truth.__setitem__(m.vid, m))
            async with running(sim, gateway, hover):
                await until(lambda: len(sim.vehicles) == 2 and all(cf.car.z > 0.4 for cf in sim.vehicles.values()),
                            15.0, "both vehicles hovering")
                cf0, cf1 = sim.vehicles["cf0"], sim.vehicles["cf1"]
                # bad input: exit 2, one line, no traceback; the vehicle is unknown to the running simulator
                for bad, needle in ((["cf0", "explode"], "invalid choice"),
                                    (["cf0", "power_off", "--duration", "-1"], "must not be negative"),
                                    (["cf0", "mocap_dropout"], "needs a positive duration"),
                                    (["cf9", "power_off"], "no simulated vehicle 'cf9'")):
                    done = await asyncio.to_thread(fleet_sim_fault, router.endpoint, creds, *bad)
                    assert done.returncode == 2 and needle in done.stderr and "Traceback" not in done.stderr, done
                # another role may not inject: nothing published, nothing happens
                done = await asyncio.to_thread(fleet_sim_fault, router.endpoint, creds, "cf0", "power_off",
                                               "--wait", "1", role="executor")
                assert done.returncode == 1 and "Traceback" not in done.stderr, done
                assert cf0.powered and 0.4 < cf0.car.z < 0.6

                done = await asyncio.to_thread(fleet_sim_fault, router.endpoint, creds, "cf0", "power_off")
                assert done.returncode == 0 and "switched off" in done.stdout, done
                await until(lambda: not cf0.powered, 2.0, "cf0 switched off")
                off_at = time.time()
                await until(lambda: cf0.car.z == 0.0 and not cf0.car.truth().motors, 5.0, "cf0 on the ground")
                down_s = time.time() - off_at
                received = cf0.received
                await until(lambda: not telemetry["cf0"].link_ok, 3.0, "the gateway losing cf0's link")
                await asyncio.sleep(1.0)
                assert cf0.received == received, "a switched-off vehicle took packets"
                assert not cf0.powered and cf1.car.z > 0.4 and telemetry["cf1"].link_ok  # the neighbour flies on
                print(f"power_off: on the ground {down_s:.2f} s after it was switched off, "
                      f"at {cf0.car.last_impact_speed:.1f} m/s")

                done = await asyncio.to_thread(fleet_sim_fault, router.endpoint, creds, "cf0", "power_on")
                assert done.returncode == 0, done
                on_at = time.time()
                await until(lambda: cf0.firmware.running, 5.0, "cf0 booted")
                assert cf0.firmware.booted_at >= on_at - 0.5 and not cf0.firmware.supervisor.locked  # a fresh boot
                await until(lambda: telemetry["cf0"].link_ok and telemetry["cf0"].t > on_at, 20.0,
                            "the gateway reconnecting cf0")
                print(f"power_on: booted, reconnected {time.time() - on_at:.1f} s after the command")
            session.close()

        asyncio.run(main())


def test_a_timed_power_off_answers_nothing_then_boots_by_itself() -> None:
    clock = [1000.0]
    car = SimFlyingCar("cf0", t=clock[0])
    cf = SimCrazyflie(car, SimRadio("r0", LinkModel()), clock=lambda: clock[0])
    cf.advance(clock[0] + 0.1)
    clock[0] += 0.1
    cf.switch_off(until=clock[0] + 2.0)
    cf.datagram_received(b"\xff", ("127.0.0.1", 1))  # a scan: the radio chip is off too
    assert not cf.powered and cf.received == 0
    clock[0] += 1.9
    cf.advance(clock[0])
    assert not cf.powered
    clock[0] += 0.2
    cf.advance(clock[0])
    assert cf.powered and not cf.firmware.running  # booting
    clock[0] += 1.6
    cf.advance(clock[0])
    assert cf.firmware.running and cf.firmware.booted_at > 1002.0


def test_fault_arguments() -> None:
    assert fault_from_args("cf1", "power_off", None, None).duration_s == 0.0
    assert fault_from_args("cf1", "battery", None, 0.2).charge_used_ah == 0.2
    for args in (("cf1", "battery", None, None), ("cf1", "power_on", 3.0, None), ("cf/1", "power_off", None, None),
                 ("cf1", "radio_blackout", 0.0, None), ("cf1", "power_off", None, 0.1), ("cf1", "gust", 1.0, None),
                 ("cf1", "gust", None, None, (3.0, 0.0)), ("cf1", "power_off", 1.0, None, (3.0, 0.0)),
                 ("cf1", "gust", 1.0, None, (30.0, 0.0))):
        with pytest.raises(Exception, match="VID|--duration|--charge-used|--gust"):
            fault_from_args(*args)
    assert fault_from_args("cf1", "gust", 0.5, None, (3.0, -1.0)).gust == (3.0, -1.0)


def test_a_gust_pushes_a_flying_body_while_it_lasts_and_not_one_on_the_ground() -> None:
    flying = SimFlyingCar("cf0", pos=(0.0, 0.0, 1.0), t=0.0)  # motors off: it falls for 0.45 s
    parked = SimFlyingCar("cf1", t=0.0)
    for car in (flying, parked):
        car.push(4.0, 0.0, until=0.2)
        car.step(0.4)
    assert flying.airborne
    assert flying.vx == pytest.approx(4.0 * 0.2, rel=0.1)  # drag takes a little
    assert flying.x == pytest.approx(0.5 * 4.0 * 0.2**2 + 0.8 * 0.2, rel=0.1)
    assert parked.x == 0.0
