"""The gateway against the firmware model (issue 14): a flying car flies, lands, drives, takes off
again; the supervisor never locks because the gateway feeds it stops until it reports the vehicle
landed and then hands over with notify-setpoint-stop. With the stop sequence of before (three stops,
then silence) the same flight locks the vehicle and its second take-off never happens."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.messages import Cmd, SimTruth, StopSetpoint, VehicleEvent, WheelSetpoint
from common.bus.pubsub import subscribe
from common.bus.service import Service
from common.bus.session import ZenohConfig
from common.crazyflie.thrust import thrust_command, to_flight_setpoint
from common.deploy.radios import simulated_radios
from common.domain.vehicle_model import G
from services.radio_gateway.gateway import RadioGateway
from services.radio_gateway.vehicle import VehicleChannel
from services.sim.crazyflie.firmware.supervisor import State
from services.sim.crazyflie.service import SimService
from tests.support.fleet_faults import until
from tests.support.loadgen import running

KEYS = Keys()


class Script(Service):
    """An executor for one vehicle following `phase(now)`: ("fly", z) hovers at z by a PD on the
    truth, ("stop",) motors off, ("drive", v) wheels."""

    def __init__(self, zconfig: ZenohConfig, vid: str, phase: Callable[[float], tuple]) -> None:
        super().__init__("executor", "e1", zconfig, KEYS)
        self.vid, self.phase = vid, phase
        self.truth: SimTruth | None = None

    async def main(self) -> None:
        self.subscribe(KEYS.sim_truth(self.vid), SimTruth, lambda t, _k: setattr(self, "truth", t))
        pub = self.publisher(KEYS.vehicle(self.vid, "cmd"), Cmd)
        seq = 0
        while True:
            now = time.time()
            seq += 1
            step = self.phase(now)
            if step[0] == "fly":
                z, vz = (self.truth.z, self.truth.vz) if self.truth else (0.0, 0.0)
                accel = min(max(4.0 * (step[1] - z) - 3.0 * vz, -3.0), 3.0)
                sp = to_flight_setpoint(0.0, 0.0, 0.0, thrust_command(0.041 * (G + accel)))
            elif step[0] == "stop":
                sp = StopSetpoint()
            else:
                sp = WheelSetpoint(left=step[1], right=step[1])
            pub.put(Cmd(vid=self.vid, owner="e1", seq=seq, t=now, setpoint=sp))
            await asyncio.sleep(0.01)


def _fly_drive_fly(cfg: ZenohConfig, session: zenoh.Session) -> tuple[SimService, list[VehicleEvent], float]:
    spec = simulated_radios({"cf1": (0.0, 0.0, 0.0)}, per_radio=1)
    sim, gw = SimService(spec, cfg), RadioGateway("r0", spec, cfg)
    marks: dict[str, float] = {}

    def phase(now: float) -> tuple:
        t = now - marks.get("t0", now)
        if "t0" not in marks or t < 3.0:
            return ("fly", 0.4)
        if "down" not in marks:
            return ("fly", -0.2)  # descend until the truth shows it on the ground
        if now - marks["down"] < 3.0:
            return ("stop",) if now - marks["down"] < 0.1 else ("drive", 0.05)
        return ("fly", 0.4)

    script = Script(cfg, "cf1", phase)
    events: list[VehicleEvent] = []

    async def main() -> float:
        subscribe(session, KEYS.vehicle("cf1", "event"), VehicleEvent, lambda e, _k: events.append(e))
        async with running(sim, gw, script):
            await until(lambda: "cf1" in sim.vehicles and gw.connections["cf1"].state == "open", 10.0, "a connection")
            marks["t0"] = time.time()
            car = sim.vehicles["cf1"].car
            await until(lambda: car.z > 0.3, 5.0, "the first take-off")
            await asyncio.sleep(2.0)
            await until(lambda: car.z == 0.0, 6.0, "the landing")
            marks["down"] = time.time()
            await asyncio.sleep(3.0)  # stop, then drive while the supervisor settles
            second = time.time()
            deadline = second + 1.5  # the climb to 0.3 m takes under a second
            while car.z < 0.3 and time.time() < deadline:
                await asyncio.sleep(0.05)
            return car.z

    return sim, events, asyncio.run(main())


def test_fly_drive_fly_never_locks_the_supervisor(zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    sim, events, z = _fly_drive_fly(ZenohConfig.client(zenoh_router), zsession())
    fw = sim.vehicles["cf1"].firmware
    states = [b for _t, _a, b in fw.supervisor.transitions]
    print("supervisor:", [s.name for s in states], "events:", [e.kind for e in events])
    assert z > 0.3, "the second take-off did not happen"
    assert fw.locks == 0 and State.WARNING_LEVEL_OUT not in states and State.LANDED in states
    assert sim.vehicles["cf1"].car.x > 0.05  # it drove between the flights


def test_the_old_stop_sequence_locks_the_vehicle(zenoh_router: str, zsession: Callable[..., zenoh.Session],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """Three stops then silence (before this issue): what the firmware since 2023.06 punishes."""
    monkeypatch.setattr(VehicleChannel, "_settle_packet", lambda self, now: None)
    sim, events, z = _fly_drive_fly(ZenohConfig.client(zenoh_router), zsession())
    assert z == 0.0 and sim.vehicles["cf1"].firmware.supervisor.transitions
    kinds = [e.kind for e in events]
    assert "sim_locked" in kinds and "vehicle_locked" in kinds and "rebooting" in kinds  # reported, recovered
