"""What the gateway sends one vehicle, and its safety rules (paper 000 §VI-C).

Modes:

- FLIGHT: the owner's latest flight setpoint, resent every tick it gets a slot (a fresh one replaces
  it), so the firmware's commander watchdog (0.5 s level, 2 s motors off) never starves. The first
  flight packet after the motors were off is a zero-thrust setpoint: the firmware keeps the thrust
  locked until it sees one (crazyflie-firmware crtp_commander_rpyt.c, `thrustLocked`).
- DRIVE: the latest wheel command, through the driving command switch, when it changes and at
  least every `wheel_refresh_s` (the wheel watchdog stops after 0.5 s).
- LANDING: the command went stale (older than `stale_s`) in flight: the gateway's own
  hover-then-land (`SafeLanding`, from the median vertical thrust of the owner's last setpoints,
  `HOVER_WINDOW`: the last one alone may be braking the end of a takeoff), then STOPPING. A fresh flight command takes back over; a wheel
  command or a stop is refused until the vehicle has landed (`Refused`): its sender lost track of
  it (e.g. an executor whose router went away believes its blind descent is over), and either
  would drop an airborne vehicle (no flight setpoints: the firmware cuts the motors).
- STOPPING: `stop_repeats` commander stops (motors off) and as many zero wheel commands (one lost
  packet would leave the wheels turning until the wheel watchdog), then IDLE.
  Entered on a StopSetpoint, after a landing, or when a wheel command goes stale.
- IDLE: nothing to send but status requests.

A status reply that shows the motors running while the vehicle is driving or idle (every stop of
its landing was lost: a congested radio drops whole batches) brings the stops back
(`motors_restopped`), instead of leaving the motors spinning until the firmware's watchdog.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from enum import StrEnum

from common.bus.messages import FlightSetpoint, Pose, Setpoint, StopSetpoint, WheelSetpoint
from common.crazyflie import crtp
from common.crazyflie.firmware import FIRMWARE_MIN_THRUST
from common.crazyflie.thrust import thrust_command, thrust_newtons
from common.deploy.radios import GatewayParams
from services.radio_gateway.landing import SafeLanding
from services.radio_gateway.linkstats import Event, LinkStats

_UNLOCK = FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=0)

HOVER_WINDOW = 100
"""Flight setpoints (1 s at 100 Hz) whose median vertical thrust is the hover thrust a safety landing
starts from (without a pose it can only set a thrust). The median ignores the brief transients a
mean keeps: a takeoff starts about 20 % above the hover and the executor brakes its end up to 29 %
below it; the last setpoint alone made 1.4 m/s touchdowns, a 1 s mean climbs away."""
HOVER_MARGIN = 0.03
"""The safety landing starts this fraction below that hover thrust: a blind descent that errs must
err downwards (a vehicle climbing open loop falls when the motors stop)."""


class Refused(ValueError):
    """A command this channel will not take now; `reason` names it in the gateway's counters."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason


class Drive(StrEnum):
    IDLE = "idle"
    FLIGHT = "flight"
    LANDING = "landing"
    DRIVE = "drive"
    STOPPING = "stopping"


class VehicleChannel:
    """One vehicle's command state, safety and link statistics on the gateway."""

    def __init__(self, vid: str, params: GatewayParams, now: float) -> None:
        self.vid = vid
        self.params = params
        self.mode = Drive.IDLE
        self.stats = LinkStats(now, params.link_timeout_s, params.lost_after_requests)
        self.landing: SafeLanding | None = None
        self.cmd_at = -float("inf")
        self.took_over = False
        """The gateway is landing or stopped the vehicle because its command went stale."""
        self._flight: FlightSetpoint | None = None
        self._thrusts: deque[float] = deque(maxlen=HOVER_WINDOW)  # vertical thrust (N) of recent setpoints
        self._flight_raw = b""
        self._unlock = False
        self._stops_left = 0
        self._wheels = (0.0, 0.0)
        self._wheels_sent: tuple[float, float] | None = None
        self._wheels_sent_at = -float("inf")
        self._wheel_zeros_left = 0
        self._last_stop_sent = 0  # `stats.sent` when the last commander stop went out

    # ---- commands -------------------------------------------------------------------------

    def command(self, setpoint: Setpoint, now: float) -> list[Event]:
        """Take the owner's setpoint (ValueError, nothing changed, if it cannot go on the wire;
        `Refused` during the safety landing unless it is a flight setpoint)."""
        if self.mode == Drive.LANDING and not isinstance(setpoint, FlightSetpoint):
            raise Refused("while_landing", f"{type(setpoint).__name__} during the safety landing: "
                                           "landing on, motors off once landed")
        events: list[Event] = []
        if isinstance(setpoint, FlightSetpoint):
            raw = crtp.encode_setpoint(setpoint)
            if self.mode == Drive.LANDING:
                events.append(("cmd_resumed", "fresh flight command during the safety landing"))
            elif self.mode != Drive.FLIGHT:
                self._unlock = True
                self._thrusts.clear()  # a new flight
                if self.mode == Drive.DRIVE:  # a driver taking off: zero wheels, repeated like a stop
                    self._wheels = (0.0, 0.0)
                    self._wheel_zeros_left = self.params.stop_repeats
            self._flight, self._flight_raw = setpoint, raw
            if setpoint.thrust >= FIRMWARE_MIN_THRUST:
                self._thrusts.append(thrust_newtons(setpoint.thrust) * math.cos(math.radians(setpoint.roll))
                                     * math.cos(math.radians(setpoint.pitch)))
            self._stops_left = 0  # flying again: pending stops are void (other modes finish them)
            self._enter(Drive.FLIGHT)
        elif isinstance(setpoint, WheelSetpoint):
            crtp.encode_wheels(setpoint.left, setpoint.right)
            if self.mode == Drive.LANDING:
                events.append(("cmd_resumed", "fresh wheel command during the safety landing"))
            self._wheels = (setpoint.left, setpoint.right)
            self._wheel_zeros_left = 0
            self._enter(Drive.DRIVE)
        elif isinstance(setpoint, StopSetpoint) and self.mode not in (Drive.STOPPING, Drive.IDLE):
            self._stop()
        self.cmd_at = now
        self.took_over = False
        return events

    def _hover_setpoint(self) -> FlightSetpoint | None:
        """Level, `HOVER_MARGIN` below the median recent vertical thrust (the last setpoint if none)."""
        if not self._thrusts:
            return self._flight
        hover = statistics.median(self._thrusts)
        return FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=thrust_command((1.0 - HOVER_MARGIN) * hover))

    def _enter(self, mode: Drive) -> None:
        self.mode = mode
        self.landing = None

    def _stop(self) -> None:
        self._enter(Drive.STOPPING)
        self._stops_left = self.params.stop_repeats
        self._wheels = (0.0, 0.0)
        self._wheel_zeros_left = self.params.stop_repeats

    def stale(self, now: float) -> bool:
        return now - self.cmd_at > self.params.stale_s

    def on_status(self, status: crtp.Status, now: float) -> list[Event]:
        """Fold in a status reply; stop again motors that run while nothing here flies them."""
        stale_before = self.stats.stale_replies
        events = self.stats.on_status(status, now)
        fresh = self.stats.stale_replies == stale_before
        after_stops = status.echo_sent > self._last_stop_sent  # asked after the last stop went out
        if (fresh and after_stops and status.flags & crtp.FLAG_MOTORS and self.mode in (Drive.DRIVE, Drive.IDLE)
                and self._stops_left == 0):
            self._stops_left = self.params.stop_repeats
            events.append(("motors_restopped", "status shows the motors running while driving or idle: stop sent again"))
        return events

    def on_pose(self, pose: Pose, now: float) -> None:
        if self.landing is not None:
            self.landing.on_pose(pose, now)

    def supervise(self, now: float) -> list[Event]:
        """Safety rules at `now`, before the tick's packets are chosen; the events they cause."""
        events = self.stats.check(now)
        age = now - self.cmd_at
        if self.mode == Drive.FLIGHT and self.stale(now):
            self.landing = SafeLanding(now, self._hover_setpoint(), self.params.landing, 1.0 / self.params.tick_hz)
            self.mode = Drive.LANDING
            self.took_over = True
            events.append(("stale_cmd_landing", f"no command for {age:.2f} s in flight: hover, then land"))
        elif self.mode == Drive.DRIVE and self.stale(now):
            self._stop()
            self.took_over = True
            events.append(("stale_cmd_stop", f"no command for {age:.2f} s while driving: wheels stopped"))
        return events

    # ---- packets --------------------------------------------------------------------------

    @property
    def wants_flight_slot(self) -> bool:
        return self.mode in (Drive.FLIGHT, Drive.LANDING) or self._stops_left > 0

    def flight_packet(self, now: float) -> tuple[bytes | None, list[Event]]:
        """The commander packet for this tick's slot (None: nothing to send) and any events."""
        if self.mode == Drive.FLIGHT:
            if self._unlock:
                self._unlock = False
                return self._count(crtp.encode_setpoint(_UNLOCK)), []
            return self._count(self._flight_raw), []
        if self.mode == Drive.LANDING:
            assert self.landing is not None
            sp = self.landing.step(now)
            if sp is not None:
                self._flight = sp
                return self._count(crtp.encode_setpoint(sp)), []
            how = "under position control" if self.landing.closed_loop else "open loop"
            self._stop()
            events = [("landed", f"safety landing complete ({how}): motors off")]
        else:
            events = []
        if self._stops_left > 0:
            self._stops_left -= 1
            if self._stops_left == 0 and self.mode == Drive.STOPPING and not self._wheel_zeros_left:
                self.mode = Drive.IDLE
            raw = self._count(crtp.encode_stop())
            self._last_stop_sent = self.stats.sent
            return raw, events
        return None, events

    def wheel_due(self, now: float) -> bool:
        """Whether the driving command switch should carry a wheel packet for this vehicle."""
        if self._wheel_zeros_left:
            return True
        if self.mode != Drive.DRIVE:
            return False
        return self._wheels != self._wheels_sent or now - self._wheels_sent_at >= self.params.wheel_refresh_s

    def wheel_packet(self, now: float) -> bytes | None:
        """The latest wheel command (None if no longer due)."""
        if not self.wheel_due(now):
            return None
        self._wheels_sent, self._wheels_sent_at = self._wheels, now
        if self._wheel_zeros_left:
            self._wheel_zeros_left -= 1
            if not self._wheel_zeros_left and self.mode == Drive.STOPPING and self._stops_left == 0:
                self.mode = Drive.IDLE
        return self._count(crtp.encode_wheels(*self._wheels))

    def status_request(self, now: float) -> bytes:
        return crtp.encode_status_request(self.stats.request(now))

    def _count(self, raw: bytes) -> bytes:
        self.stats.sent += 1
        return raw
