"""What the gateway sends one vehicle, and its safety rules (paper 000 §VI-C).

Modes:

- FLIGHT: the owner's latest flight setpoint, resent every tick it gets a slot (a fresh one replaces
  it), so the firmware's commander watchdog (0.5 s level, 2 s motors off) never starves. An
  attitude setpoint older than `level_s` goes out levelled at the hover thrust (roll, pitch and yaw
  rate 0, the thrust `_hover_setpoint`'s: the median vertical thrust of the owner's last second of
  setpoints, 3 % under), as the watchdog would level it later: an attitude is its owner's command
  for one control period. A braking tilt resent through a stalled executor's silence swung a held
  flyer back at 0.3-0.7 m/s (levelled: 0.1, its controller's own swing back), and a climbing
  thrust resent for 0.2 s took a flyer 17 cm over its level (docs/radio.md). The first
  `stop_repeats` flight packets after the motors were off, or after a new connection, are zero-thrust
  setpoints: the firmware keeps the thrust locked after boot until it sees one (crazyflie-firmware
  crtp_commander_rpyt.c, `thrustLocked`), and one lost packet must not keep it locked.
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
- IDLE: nothing to send but status requests (vehicles with the wheel app).

After a flight ends (its stops went out) the vehicle is *settled*, whatever the mode: since firmware
2023.06 the supervisor believes a vehicle flies for 2 s after its motors were last above idle, and a
low-level setpoint followed by silence in that time trips the commander watchdog (0.5 s: level
out) and then its timeout (2 s: motors off, Locked until a reboot; docs/firmware_model.md). So the
gateway keeps sending stops every `settle_period_s` while the supervisor reports the vehicle flying
(or for `settle_max_s` if it reports nothing), then notify-setpoint-stop (`stop_repeats` times):
the high-level commander, idle, takes over and keeps the watchdog fed with its own null setpoints.

A vehicle that needs arming (a Crazyflie 2.1 Brushless: `supervisor.info` says it can be armed, is
not, and does not arm itself) gets an arming request when a flight command arrives; a crashed one a
crash-recovery request. A STATUS of the wheel app that shows the motors running while the vehicle
is driving or idle (every stop of its landing was lost: a congested radio drops whole batches)
brings the stops back (`motors_restopped`). An operator's emergency stop (`emergency_stop`) sends
the supervisor's emergency stop `estop_repeats` times before anything else and refuses every
command until `clear_emergency_stop`.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from enum import StrEnum

from common.bus.messages import FlightSetpoint, Pose, PositionSetpoint, Setpoint, StopSetpoint, WheelSetpoint
from common.crazyflie import crtp
from common.crazyflie.firmware import FIRMWARE_MIN_THRUST
from common.crazyflie.thrust import thrust_command, thrust_newtons
from common.deploy.radios import GatewayParams
from services.radio_gateway.health import (
    ARMED,
    AUTO_ARM,
    CAN_ARM,
    CRASHED,
    FLYING,
    LOCKED,
    TUMBLED,
    Event,
    LinkHealth,
)
from services.radio_gateway.landing import HandBack, OnboardLanding, SafeLanding

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


UNLOCK_CHECK_S = 0.5
"""Thrust commanded this long without the supervisor reporting flight means the thrust is locked."""
REQUEST_EVERY_S = 0.5
"""How often an arming or crash-recovery request is repeated while the supervisor has not obeyed."""
PACE = 0.9
"""A vehicle's flight slots are at least this many ticks apart unless a new setpoint came."""
ESTOP_AGAIN_S = 0.2
"""How often an emergency stop is sent again while the supervisor does not report Locked."""


class VehicleChannel:
    """One vehicle's command state, safety and health on the gateway. `wheels`: it has the wheel
    app (a flying car); without it wheel commands are refused and no STATUS is asked for. `flies`:
    its capabilities include flight; without it flight setpoints are refused (a drive-only car).
    `onboard`: onboard control mode (docs/radio.md): it takes full-state setpoints instead of
    attitude ones, and its motion-capture pose is streamed to it (`extpose_packet`)."""

    def __init__(self, vid: str, params: GatewayParams, now: float, wheels: bool = True, flies: bool = True,
                 onboard: bool = False) -> None:
        self.vid = vid
        self.params = params
        self.wheels = wheels
        self.flies = flies
        self.onboard = onboard
        self.mode = Drive.IDLE
        self.health = LinkHealth(now, params.link_timeout_s, params.log_period_s)
        self.landing: SafeLanding | OnboardLanding | None = None
        self._position: PositionSetpoint | None = None  # the owner's last full-state setpoint (onboard)
        self._ext_pose: Pose | None = None  # the newest pose not yet streamed (onboard)
        self.cmd_at = -float("inf")
        self.took_over = False
        """The gateway is landing or stopped the vehicle because its command went stale."""
        self._hand_back = HandBack(params.resume_s, params.stale_s / 2)
        self._flight: FlightSetpoint | None = None
        self._thrusts: deque[float] = deque(maxlen=HOVER_WINDOW)  # vertical thrust (N) of recent setpoints
        self._flight_raw = b""
        self._level_raw: bytes | None = None  # the owner's attitude levelled, once it is older than `level_s`
        self._unlocks_left = 0
        self._lifting_since: float | None = None
        self._stops_left = 0
        self._wheels = (0.0, 0.0)
        self._wheels_sent: tuple[float, float] | None = None
        self._wheels_sent_at = -float("inf")
        self._wheel_zeros_left = 0
        self._last_stop_seq = 0  # `health.app_seq` when the last commander stop went out
        self._flew = False
        self._settle_from: float | None = None  # when the stops of the last flight ended
        self._settle_sent = -float("inf")
        self._notifies_left = 0
        self._requested = -float("inf")
        self._flight_new = False  # a flight setpoint came that has not gone out yet
        self._slot_at = -float("inf")  # when this vehicle last took a flight slot
        self._min_gap = PACE / params.tick_hz
        self.estop_left = 0
        self.estopped = False
        self._estop_sent = -float("inf")
        self.sent_setpoints = 0
        """Flight and wheel packets handed to the link (the Telemetry's command rate)."""
        self._rate_samples: deque[tuple[float, int]] = deque()

    # ---- commands -------------------------------------------------------------------------

    def command(self, setpoint: Setpoint, now: float) -> list[Event]:
        """Take the owner's setpoint (ValueError, nothing changed, if it cannot go on the wire;
        `Refused` during the safety landing unless it is a flight setpoint)."""
        if self.estopped:
            raise Refused("emergency_stop", "the operator's emergency stop: commands refused until it is released")
        if isinstance(setpoint, WheelSetpoint) and not self.wheels:
            raise Refused("no_wheels", f"{self.vid} has no wheels (capabilities without drive)")
        flight = isinstance(setpoint, (FlightSetpoint, PositionSetpoint))
        if flight and not self.flies:
            raise Refused("no_flight", f"{self.vid} does not fly (capabilities without fly)")
        if isinstance(setpoint, FlightSetpoint) and self.onboard:
            raise Refused("attitude_onboard", f"{self.vid} is in onboard control mode: position setpoints only")
        if isinstance(setpoint, PositionSetpoint) and not self.onboard:
            raise Refused("position_offboard", f"{self.vid} is in offboard control mode: attitude setpoints only")
        if self.mode == Drive.LANDING and not flight:
            raise Refused("while_landing", f"{type(setpoint).__name__} during the safety landing: "
                                           "landing on, motors off once landed")
        events: list[Event] = []
        if isinstance(setpoint, (FlightSetpoint, PositionSetpoint)):
            attitude = isinstance(setpoint, FlightSetpoint)
            raw = crtp.encode_setpoint(setpoint) if attitude else crtp.encode_full_state(setpoint)
            if self.mode == Drive.LANDING and not self._hand_back.command(now):
                self.cmd_at = now  # the landing goes on until the owner's commands come steadily
                return events
            if attitude:
                self._flight = setpoint
            else:
                self._position = setpoint
            if self.mode == Drive.LANDING:
                events.append(("cmd_resumed", "fresh flight command during the safety landing"))
            elif self.mode != Drive.FLIGHT:
                # the thrust lock is the RPYT decoder's (crtp_commander_rpyt.c): generic setpoints have none
                self._unlocks_left = 0 if self.onboard else self.params.stop_repeats
                self._thrusts.clear()  # a new flight
                if self.mode == Drive.DRIVE:  # a driver taking off: zero wheels, repeated like a stop
                    self._wheels = (0.0, 0.0)
                    self._wheel_zeros_left = self.params.stop_repeats
            self._flight_raw, self._level_raw = raw, None
            self._flight_new = True
            if isinstance(setpoint, FlightSetpoint) and setpoint.thrust >= FIRMWARE_MIN_THRUST:
                self._thrusts.append(thrust_newtons(setpoint.thrust) * math.cos(math.radians(setpoint.roll))
                                     * math.cos(math.radians(setpoint.pitch)))
            self._stops_left = 0  # flying again: pending stops are void (other modes finish them)
            self._settle_from, self._notifies_left = None, 0
            self._flew = True
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

    def connected(self, was_flying: bool) -> None:
        """A new connection (a reopened link, a rebooted vehicle): its firmware's thrust lock may be
        on again (it is after every boot), so the next flight packets are the zero-thrust ones that
        release it; not for a vehicle its supervisor last reported flying (a lock needs a reboot,
        which would have brought it down)."""
        if not was_flying and not self.onboard:
            self._unlocks_left = self.params.stop_repeats
        if self.estopped:  # the stop may not have reached it before the link went
            self.estop_left = self.params.estop_repeats

    def command_rate(self, now: float) -> float:
        """Flight and wheel packets handed to the link per second, over about the last second."""
        samples = self._rate_samples
        samples.append((now, self.sent_setpoints))
        while len(samples) > 2 and now - samples[1][0] >= 1.0:
            samples.popleft()
        (t0, c0), (t1, c1) = samples[0], samples[-1]
        return (c1 - c0) / (t1 - t0) if t1 > t0 else 0.0

    def stale(self, now: float) -> bool:
        return now - self.cmd_at > self.params.stale_s

    def on_status(self, status: crtp.Status, now: float) -> list[Event]:
        """Fold in a wheel-app STATUS; stop again motors that run while nothing here flies them."""
        stale_before = self.health.stale_replies
        events = self.health.on_status(status, now)
        fresh = self.health.stale_replies == stale_before
        after_stops = status.echo_seq > self._last_stop_seq  # asked after the last stop went out
        if (fresh and after_stops and status.flags & crtp.FLAG_MOTORS and self.mode in (Drive.DRIVE, Drive.IDLE)
                and self._stops_left == 0):
            self._stops_left = self.params.stop_repeats
            events.append(("motors_restopped", "status shows the motors running while driving or idle: stop sent again"))
        return events

    def on_pose(self, pose: Pose, now: float) -> None:
        """A motion-capture pose of this vehicle: streamed to it in onboard mode, and the safety
        landing's."""
        if self.onboard:
            self._ext_pose = pose
        if self.landing is not None:
            self.landing.on_pose(pose, now)

    @property
    def wants_poses(self) -> bool:
        return self.onboard or self.landing is not None

    def extpose_due(self) -> bool:
        """Onboard mode: a pose not yet streamed, the link up and no emergency stop."""
        return self._ext_pose is not None and self.health.link_ok and not self.estopped

    def extpose_packet(self) -> bytes:
        """The newest pose as the localization service's external pose (cflib `send_extpose`)."""
        pose, self._ext_pose = self._ext_pose, None
        assert pose is not None
        return self._count(crtp.encode_ext_pose(pose.x, pose.y, pose.z, pose.yaw))

    def supervise(self, now: float) -> list[Event]:
        """Safety rules at `now`, before the tick's packets are chosen; the events they cause."""
        events = self.health.check(now)
        if self.wheels:
            events += self.health.check_app(now)
        age = now - self.cmd_at
        if self.mode == Drive.FLIGHT and self.stale(now):
            if self.onboard and self._position is not None:
                self.landing = OnboardLanding(now, self._position, self.params.landing)
            else:
                self.landing = SafeLanding(now, self._hover_setpoint(), self.params.landing,
                                           1.0 / self.params.tick_hz)
            self.mode = Drive.LANDING
            self.took_over = True
            self._hand_back.since = None  # (the owner's commands count from the take-over on)
            events.append(("stale_cmd_landing", f"no command for {age:.2f} s in flight: hover, then land"))
        elif self.mode == Drive.DRIVE and self.stale(now):
            self._stop()
            self.took_over = True
            events.append(("stale_cmd_stop", f"no command for {age:.2f} s while driving: wheels stopped"))
        return events

    # ---- packets --------------------------------------------------------------------------

    def emergency_stop(self) -> None:
        """The operator's emergency stop: the supervisor's, `estop_repeats` times, then nothing."""
        self.estopped = True
        self.estop_left = self.params.estop_repeats
        self._enter(Drive.IDLE)
        self._stops_left = self._wheel_zeros_left = self._notifies_left = 0
        self._settle_from = None

    def clear_emergency_stop(self) -> None:
        self.estopped = False
        self.estop_left = 0

    def estop_packet(self, now: float) -> bytes | None:
        """The emergency stop's packets: `estop_repeats` at once, then one every `ESTOP_AGAIN_S`
        until the supervisor reports Locked (a stop lost on the radio is sent again)."""
        if self.estop_left <= 0:
            if not self.estopped or self.health.bit(LOCKED) or now - self._estop_sent < ESTOP_AGAIN_S:
                return None
            self.estop_left = 1
        self.estop_left -= 1
        self._estop_sent = now
        return self._count(crtp.encode_emergency_stop())

    def request_packet(self, now: float) -> tuple[bytes | None, list[Event]]:
        """An arming request (flight wanted, the supervisor can arm and does not arm itself) or a
        crash-recovery request (crashed, no longer tumbled), at most every `REQUEST_EVERY_S`."""
        h = self.health
        if self.estopped or now - self._requested < REQUEST_EVERY_S or h.supervisor is None:
            return None, []
        if self.mode in (Drive.FLIGHT, Drive.LANDING) and h.bit(CAN_ARM) and not h.bit(ARMED) and not h.bit(AUTO_ARM):
            self._requested = now
            return self._count(crtp.encode_arming(True)), [("arming", "supervisor can arm: arming request sent")]
        if h.bit(CRASHED) and not h.bit(TUMBLED):
            self._requested = now
            return self._count(crtp.encode_crash_recovery()), [("crash_recovery", "crash-recovery request sent")]
        return None, []

    @property
    def settling(self) -> bool:
        return self._settle_from is not None or self._notifies_left > 0

    @property
    def wants_flight_slot(self) -> bool:
        return self.mode in (Drive.FLIGHT, Drive.LANDING) or self._stops_left > 0 or self.settling

    def flight_due(self, now: float) -> bool:
        """A flight slot is wanted now: a new flight setpoint came, or the last slot is a tick old
        (the last setpoint repeated, the landing's and the stops' own pace). The gateway ticks
        at `tick_hz` and also as soon as a command batch arrives, so a setpoint goes out when it
        comes and nothing goes out twice as often as the ticks."""
        if not self.wants_flight_slot:
            return False
        return (self._flight_new and self.mode == Drive.FLIGHT) or now - self._slot_at >= self._min_gap

    def _settle_packet(self, now: float) -> bytes | None:
        """After a flight: stops while the supervisor still believes it flies, then notify-setpoint-stop."""
        if self._settle_from is not None:
            flying = self.health.bit(FLYING)
            waited = now - self._settle_from
            if (flying is None and waited < self.params.settle_max_s) or (flying and waited < 2 * self.params.settle_max_s):
                if now - self._settle_sent < self.params.settle_period_s - 1e-6:
                    return None
                self._settle_sent = now
                return self._count(crtp.encode_stop())
            self._settle_from = None
            self._notifies_left = self.params.stop_repeats
        if self._notifies_left > 0:
            self._notifies_left -= 1
            return self._count(crtp.encode_notify_setpoint_stop())
        return None

    def _check_unlocked(self, now: float) -> None:
        """Thrust commanded for `UNLOCK_CHECK_S` and the supervisor still says not flying: the
        zero-thrust packets were all lost (a congested radio drops whole runs): send them again."""
        lifting = self._flight is not None and self._flight.thrust >= FIRMWARE_MIN_THRUST
        if not lifting or self._unlocks_left:
            self._lifting_since = None
            return
        if self._lifting_since is None:
            self._lifting_since = now
        elif now - self._lifting_since > UNLOCK_CHECK_S and self.health.bit(FLYING) is False:
            self._unlocks_left = self.params.stop_repeats
            self._lifting_since = None

    def flight_packet(self, now: float) -> tuple[bytes | None, list[Event]]:
        """The commander packet for this tick's slot (None: nothing to send) and any events."""
        self._slot_at, self._flight_new = now, False
        if self.mode == Drive.FLIGHT:
            self.sent_setpoints += 1
            self._check_unlocked(now)
            if self._unlocks_left > 0:  # repeated: one lost packet must not leave the thrust locked
                self._unlocks_left -= 1
                return self._count(crtp.encode_setpoint(_UNLOCK)), []
            return self._count(self._resent(now)), []
        if self.mode == Drive.LANDING:
            assert self.landing is not None
            sp = self.landing.step(now)
            if isinstance(sp, PositionSetpoint):
                return self._count(crtp.encode_full_state(sp)), []
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
            self._last_stop_seq = self.health.app_seq
            if self._stops_left == 0 and self._flew:
                self._flew = False
                self._settle_from, self._settle_sent = now, now
            return raw, events
        return self._settle_packet(now), events

    def _resent(self, now: float) -> bytes:
        """The owner's flight setpoint as it goes out at `now`: an attitude older than `level_s`
        levelled at the hover thrust the safety landing starts from (`_hover_setpoint`; module
        docstring)."""
        sp = self._flight
        if self.onboard or sp is None or now - self.cmd_at <= self.params.level_s or sp.thrust < FIRMWARE_MIN_THRUST:
            return self._flight_raw
        if self._level_raw is None:
            hover = self._hover_setpoint()
            assert hover is not None
            self._level_raw = crtp.encode_setpoint(hover)
        return self._level_raw

    def wheel_due(self, now: float) -> bool:
        """Whether the driving command switch should carry a wheel packet for this vehicle."""
        if self._wheel_zeros_left:
            return True
        if self.mode != Drive.DRIVE:
            return False
        return self._wheels != self._wheels_sent or now - self._wheels_sent_at >= self.params.wheel_refresh_s

    @property
    def wheels_to_stop(self) -> bool:
        """A wheel command that stops wheels last sent turning is due: the driving command switch
        carries it ahead of its queue (`Scheduler._drive`)."""
        return self._wheels == (0.0, 0.0) and self._wheels_sent is not None and any(self._wheels_sent)

    def wheel_packet(self, now: float) -> bytes | None:
        """The latest wheel command (None if no longer due)."""
        if not self.wheel_due(now):
            return None
        self._wheels_sent, self._wheels_sent_at = self._wheels, now
        if self._wheel_zeros_left:
            self._wheel_zeros_left -= 1
            if not self._wheel_zeros_left and self.mode == Drive.STOPPING and self._stops_left == 0:
                self.mode = Drive.IDLE
        self.sent_setpoints += 1
        return self._count_app(crtp.encode_wheels(*self._wheels))

    def status_request(self, now: float) -> bytes:
        self.health.app_seq += 1
        self.health.app_asked += 1
        return self._count(crtp.encode_status_request(self.health.app_seq))

    def _count_app(self, raw: bytes) -> bytes:
        self.health.app_seq += 1
        return self._count(raw)

    def _count(self, raw: bytes) -> bytes:
        self.health.sent += 1
        return raw
