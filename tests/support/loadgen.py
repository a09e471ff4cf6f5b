"""A stand-in executor that loads a gateway: it publishes a `Cmd` for each of its vehicles at a fixed
rate, as an executor does (tests and bench/radio_capacity.py; the real executor is
services/executor). It runs as service "executor", so its liveliness token makes it an owner.
`running(...)` runs such a set of services (sim, gateway, mocap, stand-ins) in one event loop.

Flying vehicles get level flight setpoints whose thrust holds `z_ref` by a PD loop on the simulator's
ground truth (`sim/truth/<vid>`, the stand-in has no mocap); driving vehicles get constant wheel
speeds. `silence(vid)` stops commanding one vehicle, as a dead executor would.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Iterable

from common.bus.keys import Keys
from common.bus.messages import Cmd, FlightSetpoint, SimTruth, WheelSetpoint
from common.bus.pubsub import Publisher
from common.bus.service import Service
from common.bus.session import ZenohConfig
from common.crazyflie.thrust import thrust_command, to_flight_setpoint
from common.domain.vehicle_model import G

_KP = 4.0  # 1/s^2: height error -> vertical acceleration
_KD = 3.0  # 1/s: vertical speed -> vertical acceleration


class LoadCommander(Service):
    """Commands `flyers` (hover at `z_ref` m) and `drivers` (`wheels` m/s) at `rate_hz` as `instance`."""

    def __init__(self, instance: str, zconfig: ZenohConfig, flyers: Iterable[str] = (), drivers: Iterable[str] = (),
                 keys: Keys | None = None, rate_hz: float = 100.0, z_ref: float = 0.5,
                 wheels: tuple[float, float] = (0.05, 0.05), mass: float = 0.041) -> None:
        super().__init__("executor", instance, zconfig, keys)
        self.flyers = list(flyers)
        self.drivers = list(drivers)
        self.period = 1.0 / rate_hz
        self.z_ref = z_ref
        self.wheels = WheelSetpoint(left=wheels[0], right=wheels[1])
        self.mass = mass
        self.truth: dict[str, SimTruth] = {}
        self.silenced: set[str] = set()

    def silence(self, vid: str) -> None:
        """Stop commanding `vid` (its commands go stale at the gateway)."""
        self.silenced.add(vid)

    async def main(self) -> None:
        self.subscribe(self.keys.all_sim_truth, SimTruth, lambda t, _k: self.truth.__setitem__(t.vid, t))
        pubs: dict[str, Publisher[Cmd]] = {vid: self.publisher(self.keys.vehicle(vid, "cmd"), Cmd)
                                           for vid in self.flyers + self.drivers}
        loop = asyncio.get_running_loop()
        due = loop.time()
        seq = 0
        while True:
            now = time.time()
            seq += 1
            for vid, pub in pubs.items():
                if vid in self.silenced:
                    continue
                setpoint = self._hover(vid) if vid in self.flyers else self.wheels
                pub.put(Cmd(vid=vid, owner=self.instance, seq=seq, t=now, setpoint=setpoint, mode="load"))
            due += self.period
            await asyncio.sleep(max(due - loop.time(), 0.0))

    def _hover(self, vid: str) -> FlightSetpoint:
        truth = self.truth.get(vid)
        z, vz = (truth.z, truth.vz) if truth else (0.0, 0.0)
        accel = _KP * (self.z_ref - z) - _KD * vz
        return to_flight_setpoint(0.0, 0.0, 0.0, thrust_command(self.mass * (G + min(max(accel, -3.0), 3.0))))


@contextlib.asynccontextmanager
async def running(*services: Service) -> AsyncIterator[None]:
    """Run `services` on this event loop for the body of the `async with`, then stop them all;
    RuntimeError if any of them failed (exit code 1)."""
    tasks = [asyncio.create_task(s.run(), name=f"{s.name}/{s.instance}") for s in services]
    try:
        yield
    finally:
        for s in services:
            s.stop()
        codes = await asyncio.gather(*tasks)
    failed = [f"{s.name}/{s.instance}" for s, code in zip(services, codes, strict=True) if code != 0]
    if failed:
        raise RuntimeError(f"services failed: {', '.join(failed)}")
