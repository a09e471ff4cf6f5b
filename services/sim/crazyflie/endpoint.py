"""A simulated Crazyflie: a UDP endpoint speaking the CRTP packets of cflib's UDP driver (one packet
per datagram), the firmware's side of our wheel protocol, and `SimFlyingCar` physics.

The gateway cannot tell it from a real vehicle: the same commander setpoints (port 3), stop
(port 7) and wheel-protocol packets (port 0x0D channel 2) go in; status replies come out. Every
packet crosses the radio's link model (`SimRadio`) both ways. The physics advances in fixed steps
of `PhysicsParams.max_substep` (2 ms: 500 Hz) up to the wall clock, whenever a packet arrives and
whenever the simulator publishes truth; a setpoint takes effect at the step it arrives in, as it
would at the firmware's next control loop.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable

from common.bus.messages import FlightSetpoint, WheelSetpoint
from common.crazyflie import crtp
from common.crazyflie.firmware import FIRMWARE_MIN_THRUST, WATCHDOG_CUT_S, WATCHDOG_LEVEL_S
from services.sim.crazyflie.physics import SimFlyingCar
from services.sim.crazyflie.radio import SimRadio

log = logging.getLogger(__name__)

EventCallback = Callable[[str, str, str], None]
"""``on_event(vid, kind, detail)``: something the firmware would notice (watchdogs)."""

Address = tuple[str, int]


class SimCrazyflie(asyncio.DatagramProtocol):
    """One simulated vehicle behind `radio`. `clock` is wall time (epoch s): the car's clock too."""

    def __init__(self, car: SimFlyingCar, radio: SimRadio, on_event: EventCallback | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        self.car = car
        self.vid = car.vid
        self.radio = radio
        self.on_event = on_event
        self.clock = clock
        self.step_s = car.params.max_substep
        self.received = 0
        self.setpoints = 0
        self.flight_setpoints = 0
        self.malformed = 0
        self.last_flight_at: float | None = None
        self.max_flight_gap = 0.0
        """Longest gap (s) between two flight setpoints while the motors were armed."""
        self.watchdog_levels = 0
        self.watchdog_cuts = 0
        self.wheel_watchdogs = 0
        self.hardest_touchdown = 0.0
        """Fastest touchdown so far (m/s, `SimFlyingCar.last_impact_speed`): above ~1 m/s a crash."""
        self.blacked_out = 0
        """Packets (both ways) lost to an injected radio blackout (`blackout`)."""
        self._blackout_until = -math.inf
        self._armed = False
        self._wheels_on = False
        self._wheels_at = -math.inf
        self._latched_flags = 0
        self._watchdog_stage = 0
        self._transport: asyncio.DatagramTransport | None = None

    # ---- transport ------------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = transport  # type: ignore[assignment]  # a datagram endpoint's transport

    def blackout(self, until: float) -> None:
        """Fault injection (docs/reliability.md): every packet to or from this vehicle is lost until
        `until` (this clock), as when it flies out of the radio's range."""
        self._blackout_until = until

    def _blacked_out(self, now: float) -> bool:
        if now < self._blackout_until:
            self.blacked_out += 1
            return True
        return False

    def datagram_received(self, data: bytes, addr: Address) -> None:
        now = self.clock()
        if self._blacked_out(now):
            return
        at = self.radio.uplink(now)
        if at is not None:
            asyncio.get_running_loop().call_later(max(at - now, 0.0), self._deliver, data, addr)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()

    def _send(self, raw: bytes, addr: Address) -> None:
        if self._transport is not None and not self._transport.is_closing():
            self._transport.sendto(raw, addr)

    def _reply(self, raw: bytes, addr: Address) -> None:
        now = self.clock()
        if self._blacked_out(now):
            return
        at = self.radio.downlink(now)
        if at is not None:
            asyncio.get_running_loop().call_later(max(at - now, 0.0), self._send, raw, addr)

    # ---- firmware -------------------------------------------------------------------------

    def advance(self, now: float) -> None:
        """Step the physics in whole steps up to `now` and watch the commander watchdog."""
        steps = int((now - self.car.t) / self.step_s)
        if steps > 0:
            self.car.step(steps * self.step_s)
            self.hardest_touchdown = max(self.hardest_touchdown, self.car.last_impact_speed)
        self._watch(self.car.t)

    def _watch(self, t: float) -> None:
        if self._armed and self.last_flight_at is not None:
            age = t - self.last_flight_at
            if age > WATCHDOG_CUT_S and self._watchdog_stage < 2:
                self._watchdog_stage = 2
                self.watchdog_cuts += 1
                self._latched_flags |= crtp.FLAG_WATCHDOG_CUT
                self._event("sim_watchdog_cut", f"no setpoint for {age:.2f} s: motors stopped")
            elif age > WATCHDOG_LEVEL_S and self._watchdog_stage < 1:
                self._watchdog_stage = 1
                self.watchdog_levels += 1
                self._latched_flags |= crtp.FLAG_WATCHDOG_LEVEL
                self._event("sim_watchdog_level", f"no setpoint for {age:.2f} s: attitude levelled")
        if self._wheels_on and t - self._wheels_at > self.car.params.wheel_watchdog_s:
            self._wheels_on = False
            self.wheel_watchdogs += 1
            self._latched_flags |= crtp.FLAG_WHEEL_WATCHDOG

    def _event(self, kind: str, detail: str) -> None:
        log.warning("%s: %s (%s)", self.vid, kind, detail)
        if self.on_event is not None:
            self.on_event(self.vid, kind, detail)

    def _deliver(self, data: bytes, addr: Address) -> None:
        self.advance(self.clock())
        t = self.car.t
        try:
            packet = crtp.decode_uplink(data)
        except crtp.CrtpError as exc:
            self.malformed += 1
            if self.malformed == 1:
                log.warning("%s: dropped malformed packet %s: %s (further ones only counted)", self.vid,
                            data[:8].hex(), exc)
            return
        if isinstance(packet, crtp.Null):
            self._reply(crtp.NULL_PACKET, addr)
            return
        self.received += 1
        if isinstance(packet, crtp.StatusRequest):
            self._reply(crtp.encode_status(self._status(packet.sent)), addr)
            return
        self.setpoints += 1
        if isinstance(packet, FlightSetpoint):
            self._flight(packet, t)
        elif isinstance(packet, crtp.Stop):
            self._flight(FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=0), t)
        else:
            self.car.apply(WheelSetpoint(left=packet.left_mm_s / 1000.0, right=packet.right_mm_s / 1000.0), t)
            self._wheels_on = packet.left_mm_s != 0 or packet.right_mm_s != 0
            self._wheels_at = t

    def _flight(self, sp: FlightSetpoint, t: float) -> None:
        if self._armed and self.last_flight_at is not None:
            self.max_flight_gap = max(self.max_flight_gap, t - self.last_flight_at)
        self.car.apply(sp, t)
        self.flight_setpoints += 1
        self.last_flight_at = t
        self._armed = sp.thrust >= FIRMWARE_MIN_THRUST
        self._watchdog_stage = 0

    def _status(self, echo_sent: int) -> crtp.Status:
        car = self.car
        flags = self._latched_flags
        self._latched_flags = 0
        if car.flight_command()[3] > 0:  # what the firmware commands, not the props spinning down
            flags |= crtp.FLAG_MOTORS
        if car.airborne:
            flags |= crtp.FLAG_FLYING
        return crtp.Status(echo_sent=echo_sent, received=self.received, setpoints=self.setpoints,
                           vbat_mv=round(car.battery.vbat * 1000.0), wheel_left_mm_s=round(car.wheel_left * 1000.0),
                           wheel_right_mm_s=round(car.wheel_right * 1000.0), flags=flags)
