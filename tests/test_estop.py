"""`fleet estop` (issue 14): 8 simulated Crazyflies hovering on 4 radios; the operator's emergency stop
reaches every gateway, which sends the supervisor's emergency stop to every vehicle: motors off
(measured from the stop's publication to the last vehicle's motors off), supervisors locked, commands
refused; `fleet estop --release` reboots them and they fly again."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from pathlib import Path

from common.bus.keys import Keys
from common.bus.messages import EmergencyStop
from common.bus.pubsub import subscribe
from common.bus.session import InProcessRouter, open_session
from common.deploy.radios import simulated_radios
from services.radio_gateway.gateway import RadioGateway
from services.sim.crazyflie.service import SimService
from tests.support.fleet_faults import until
from tests.support.loadgen import LoadCommander, running

REPO = Path(__file__).resolve().parents[1]
KEYS = Keys("estop")
VIDS = [f"cf{i}" for i in range(8)]


def _fleet_estop(endpoint: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "services.cli", "estop", "--connect", endpoint, "--fleet", KEYS.fleet,
                           *args], cwd=REPO, capture_output=True, text=True, timeout=60)


def test_fleet_estop_stops_eight_vehicles_on_four_radios_and_release_reboots_them() -> None:
    with InProcessRouter() as router:
        cfg = router.client_config()
        spec = simulated_radios({vid: (0.4 * i, 0.0, 0.0) for i, vid in enumerate(VIDS)}, per_radio=2)
        sim = SimService(spec, cfg, keys=KEYS)
        gateways = [RadioGateway(name, spec, cfg, keys=KEYS) for name in spec.radios]
        hover = LoadCommander("e1", cfg, flyers=VIDS, keys=KEYS)
        stops: list[EmergencyStop] = []
        off_at: dict[str, float] = {}

        async def main() -> None:
            session = open_session(cfg)
            subscribe(session, KEYS.estop, EmergencyStop, lambda m, _k: stops.append(m))
            async with running(sim, *gateways, hover):
                cars = lambda: [sim.vehicles[v] for v in VIDS]  # noqa: E731
                await until(lambda: len(sim.vehicles) == 8 and all(cf.car.z > 0.4 for cf in cars()), 15.0,
                            "eight vehicles hovering")
                done = asyncio.create_task(asyncio.to_thread(_fleet_estop, router.endpoint, "--reason", "test"))
                deadline = time.time() + 20.0
                while len(off_at) < 8:
                    now = time.time()
                    for cf in cars():
                        if cf.vid not in off_at and cf.firmware.motor_command == 0:
                            off_at[cf.vid] = now
                    await asyncio.sleep(0.002)
                    late = now - (stops[0].t if stops else now) > 3.0 or now > deadline
                    assert not late, (f"not stopped: {sorted(set(VIDS) - set(off_at))}; stop seen: {bool(stops)}; "
                                      f"fleet estop: {done.result() if done.done() else 'running'}")
                stopped = await done
                assert stopped.returncode == 0 and "stopped: " + ", ".join(sorted(VIDS)) in stopped.stdout, stopped.stdout
                await asyncio.sleep(0.5)
                assert all(cf.car.z == 0.0 for cf in cars())  # an emergency stop: they dropped
                assert all(gw.counters.total("refused:emergency_stop") > 0 for gw in gateways)  # hover refused
                release = await asyncio.to_thread(_fleet_estop, router.endpoint, "--release")
                assert release.returncode == 0, release.stderr
                await until(lambda: all(not cf.firmware.supervisor.locked and cf.firmware.running for cf in cars()),
                            10.0, "every vehicle rebooted")
                await until(lambda: all(cf.car.z > 0.3 for cf in cars()), 15.0, "every vehicle flying again")
            session.close()

        asyncio.run(main())
    last = max(off_at.values()) - stops[0].t
    print(f"fleet estop: motors off {sorted(round(t - stops[0].t, 3) for t in off_at.values())} s after the stop "
          f"was published; the last {last:.3f} s")
    assert last < 0.5


def test_fleet_estop_fails_when_no_gateway_listens() -> None:
    with InProcessRouter() as router:
        out = _fleet_estop(router.endpoint)
    assert out.returncode == 1 and "no gateway is listening" in out.stderr, (out.stdout, out.stderr)
