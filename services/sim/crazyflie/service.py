"""`fleet sim`: the simulated Crazyflies of a radios file, one UDP endpoint each, in real time.

Every ``udp://`` vehicle of the selected radios becomes a `SimCrazyflie` at its configured start,
behind its radio's link model (`SimRadio`, shared by the radio's vehicles). Ground truth goes out on
`sim/truth/<vid>` at `truth_hz`, and every vehicle's of one tick together on `sim/truths`
(`SimTruthFrame`, what a mission judges separation on); each tick is also a capture of the simulated motion-capture
system (`SimMocap`, the radios file's `mocap` model): one frame of every body on `sim/mocap`.
Firmware watchdog trips go out as `VehicleEvent`s on `vehicle/<vid>/event`. The gateway talks to
these exactly as to real vehicles (paper 000 §VI-C).

Fault injection (docs/reliability.md): a `SimFault` on `sim/fault/<vid>` blacks out the vehicle's
radio link for a while (`radio_blackout`), hides its body from the motion capture
(`mocap_dropout`), sets its battery's used charge (`battery`), switches the vehicle off for a while
or until further notice (`power_off`) or on again (`power_on`); nothing happens unless one is
published (`fleet sim fault`). Counters and figures go out on `stats/sim/<instance>`.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Collection
from dataclasses import replace

from common.bus.keys import Keys
from common.bus.messages import MocapFrame, SimFault, SimTruth, SimTruthFrame, VehicleEvent
from common.bus.service import Service
from common.bus.session import ZenohConfig
from common.bus.stats import publish_stats
from common.deploy.radios import MocapModel, RadiosFile, udp_address
from common.domain.vehicle_model import VehicleModel
from services.sim.crazyflie.endpoint import SimCrazyflie
from services.sim.crazyflie.firmware.system import CF21, CF21_BRUSHLESS
from services.sim.crazyflie.mocap import SimMocap
from services.sim.crazyflie.physics import PhysicsParams, SimFlyingCar, unit_thrust
from services.sim.crazyflie.radio import SimRadio

log = logging.getLogger(__name__)


class SimService(Service):
    """Simulated vehicles of `spec` (only the radios named in `radios`, default all)."""

    def __init__(self, spec: RadiosFile, zconfig: ZenohConfig, instance: str = "sim", keys: Keys | None = None,
                 radios: Collection[str] | None = None, truth_hz: float = 100.0,
                 params: PhysicsParams | None = None, model: VehicleModel | None = None,
                 mocap: MocapModel | None = None, thrust_spread: float = 0.0) -> None:
        super().__init__("sim", instance, zconfig, keys)
        unknown = set(radios or ()) - set(spec.radios)
        if unknown:
            raise ValueError(f"no radio {sorted(unknown)} in the radios file")
        if truth_hz <= 0:
            raise ValueError("truth_hz must be positive")
        if not 0.0 <= thrust_spread < 0.5:
            raise ValueError("thrust_spread must be in [0, 0.5)")
        self.thrust_spread = thrust_spread
        self.spec = spec
        self.selected = [r for r in spec.radios if radios is None or r in radios]
        self.period = 1.0 / truth_hz
        self.params = params or PhysicsParams()
        self.model = model or VehicleModel()
        self.radios: dict[str, SimRadio] = {}
        self.vehicles: dict[str, SimCrazyflie] = {}
        self.mocap_model = mocap or spec.mocap

    async def main(self) -> None:
        self._truth = self.publishers(self.keys.sim_truth, SimTruth)
        self._truths = self.publisher(self.keys.sim_truths, SimTruthFrame)
        self._events = self.publishers(lambda vid: self.keys.vehicle(vid, "event"), VehicleEvent)
        frames = self.publisher(self.keys.sim_mocap, MocapFrame)
        self.mocap = SimMocap(self.mocap_model, frames.put)
        try:
            await self._open()
            self.subscribe(self.keys.all_sim_faults, SimFault, self._on_fault)
            self.spawn(publish_stats(self, self._figures), name="stats")
            await self._publish_truth()
        finally:
            self.mocap.closed = True
            for cf in self.vehicles.values():
                cf.close()

    async def _open(self) -> None:
        now = time.time()
        for name in self.selected:
            spec = self.spec.radios[name]
            radio = self.radios[name] = SimRadio(name, spec.link)
            for vid, link in spec.vehicles.items():
                if not link.uri.startswith("udp://"):
                    log.info("sim: %s is a real vehicle (%s), not simulated", vid, link.uri)
                    continue
                params = replace(self.params, thrust_scale=self.params.thrust_scale * unit_thrust(vid, self.thrust_spread))
                car = SimFlyingCar(vid, self.model, params, pos=link.start, yaw=link.yaw, t=now)
                platform = CF21_BRUSHLESS if link.firmware == "cf21-brushless" else CF21
                cf = SimCrazyflie(car, radio, self._on_event, platform=platform, wheels=link.wheels)
                cf.listen(udp_address(link.uri))
                self.vehicles[vid] = cf  # listed once its radio endpoint is bound: a client may connect
        log.info("sim: %d vehicles on radios %s", len(self.vehicles), ", ".join(self.selected))

    async def _publish_truth(self) -> None:
        """Advance every vehicle to now, publish its truth and capture a motion-capture frame, every `period` s."""
        loop = asyncio.get_running_loop()
        due = loop.time()
        while True:
            now = time.time()
            for cf in self.vehicles.values():
                cf.advance(now)
            truths = [cf.car.truth() for cf in self.vehicles.values()]
            self.mocap.capture(now, truths)  # (it leaves latency_s after `now`, whatever the truths cost)
            for truth in truths:
                self._truth.put(truth.vid, truth)
            self._truths.put(SimTruthFrame(t=now, truths=truths))
            due += self.period
            delay = due - loop.time()
            if delay < -self.period:  # fell behind (loaded machine): skip, do not burst
                self.counters.inc("truth_behind")
                due = loop.time()
                delay = 0.0
            await asyncio.sleep(delay)

    def _on_fault(self, fault: SimFault, _key: str) -> None:
        cf = self.vehicles.get(fault.vid)
        if cf is None:
            return
        log.warning("sim: fault injected into %s: %s", fault.vid, fault)
        self.counters.inc(f"fault:{fault.kind}:{fault.vid}")
        if fault.kind == "mocap_dropout":
            self.mocap.blind(fault.vid, time.time() + fault.duration_s)
        elif fault.kind == "radio_blackout":
            cf.blackout(time.time() + fault.duration_s)
        elif fault.kind == "power_off":
            cf.switch_off(time.time() + fault.duration_s if fault.duration_s > 0 else None)
        elif fault.kind == "power_on":
            cf.switch_on()
        elif fault.kind == "gust":
            cf.car.push(*fault.gust, time.time() + fault.duration_s)
        else:
            cf.car.charge_used_ah = fault.charge_used_ah

    def _figures(self) -> dict[str, float]:
        cfs = self.vehicles.values()
        return {"vehicles": len(self.vehicles), "watchdog_levels": sum(cf.watchdog_levels for cf in cfs),
                "watchdog_cuts": sum(cf.watchdog_cuts for cf in cfs),
                "radio_lost": sum(r.lost for r in self.radios.values()),
                "radio_congested": sum(r.congested for r in self.radios.values()),
                "radio_delivered": sum(r.delivered for r in self.radios.values()),
                "touchdown_max_mps": max((cf.hardest_touchdown for cf in cfs), default=0.0),
                "attitude_setpoints": sum(cf.flight_setpoints for cf in cfs),
                "ext_poses_fused": sum(cf.firmware.estimator.ext_count for cf in cfs),
                **{f"touchdown_mps:{vid}": cf.hardest_touchdown for vid, cf in self.vehicles.items()}}

    def _on_event(self, vid: str, kind: str, detail: str) -> None:
        self._events.put(vid, VehicleEvent(vid=vid, t=time.time(), kind=kind, detail=detail))
