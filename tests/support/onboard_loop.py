"""A simulated flying car in onboard control mode behind the simulated firmware, for
`closed_loop.run` (it has the `SimFlyingCar` surface the loop uses): its parameters set as the
gateway sets them (`ONBOARD_PARAMS`), each setpoint in as the CRTP packet the gateway would send
(`common.crazyflie.crtp`), the firmware's periodic work every 10 ms, and each motion-capture pose
streamed to it as external pose, as the gateway does, `latency_s` after its capture. No radio loss here: the fleet tests and `bench.control_modes` have the link model.
"""

from __future__ import annotations

import math
import random
from collections import deque

from common.bus.messages import (
    FlightSetpoint,
    PositionSetpoint,
    Setpoint,
    SimTruth,
    StopSetpoint,
    WheelSetpoint,
)
from common.crazyflie import crtp
from common.deploy.radios import ONBOARD_PARAMS
from services.sim.crazyflie.firmware.system import TICK_S, CrazyflieFirmware
from services.sim.crazyflie.physics import SimFlyingCar


def packet(sp: Setpoint) -> bytes:
    """The gateway's packet for `sp`."""
    if isinstance(sp, FlightSetpoint):
        return crtp.encode_setpoint(sp)
    if isinstance(sp, PositionSetpoint):
        return crtp.encode_full_state(sp)
    if isinstance(sp, WheelSetpoint):
        return crtp.encode_wheels(sp.left, sp.right)
    assert isinstance(sp, StopSetpoint)
    return crtp.encode_stop()


class FirmwareCar:
    """`car` run by `CrazyflieFirmware`, its poses streamed (noise `pos_std`, none during `dropouts`)."""

    def __init__(self, car: SimFlyingCar, pos_std: float = 0.001, latency_s: float = 0.01,
                 dropouts: tuple[tuple[float, float], ...] = (), seed: int = 0) -> None:
        self.car = car
        self.vid = car.vid
        self.firmware = CrazyflieFirmware(car, seed=seed)
        for name, value in {**ONBOARD_PARAMS, "ctrlMel.mass": car.model.mass}.items():
            self.firmware.params.set(name, value)
        self.pos_std, self.latency_s, self.dropouts = pos_std, latency_s, dropouts
        self._rng = random.Random(seed)
        self._in_flight: deque[tuple[float, bytes]] = deque()
        self._next_tick = car.t + TICK_S
        self._settle = False
        self.kinds: set[str] = set()
        """The setpoint types the firmware received (message tags)."""

    @property
    def t(self) -> float:
        return self.car.t

    @property
    def battery(self):  # noqa: ANN201 - the car's BatteryState
        return self.car.battery

    def truth(self) -> SimTruth:
        return self.car.truth()

    def apply(self, sp: Setpoint, now: float) -> None:
        """`sp` as its packet; after a flight, stops while the supervisor believes the vehicle
        flies, then one notify-setpoint-stop: the gateway's settling (docs/radio.md), simplified."""
        self.kinds.add(type(sp).__name__)
        self.firmware.receive(packet(sp), now)
        if isinstance(sp, PositionSetpoint | FlightSetpoint):
            self._settle = True
        elif self._settle and isinstance(sp, WheelSetpoint):
            flying = self.firmware.supervisor.is_flying
            self.firmware.receive(crtp.encode_stop() if flying else crtp.encode_notify_setpoint_stop(), now)
            self._settle = flying

    def step(self, dt: float) -> None:
        end = self.car.t + dt
        while self._next_tick <= end + 1e-9:
            self._advance(self._next_tick)
            if not any(a <= self._next_tick < b for a, b in self.dropouts):
                c, g = self.car, self._rng.gauss
                self._in_flight.append((self._next_tick + self.latency_s, crtp.encode_ext_pose(
                    c.x + g(0.0, self.pos_std), c.y + g(0.0, self.pos_std), c.z + g(0.0, self.pos_std), c.yaw)))
            while self._in_flight and self._in_flight[0][0] <= self._next_tick + 1e-9:
                self.firmware.receive(self._in_flight.popleft()[1], self._next_tick)
            self.firmware.tick(self._next_tick)
            self._next_tick += TICK_S
        self._advance(end)

    def _advance(self, t: float) -> None:
        step = self.car.params.max_substep
        n = math.floor((t - self.car.t) / step + 1e-6)
        if n > 0:
            self.car.step(n * step)
