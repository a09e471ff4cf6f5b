"""One radio's packet schedule (paper 000 §VI-C: one Crazyradio served two Crazyflies reliably, and
the slower driving commands had to be serialised through a "driving command switch").

Every tick (`tick_hz`) the radio earns ``budget_pps / tick_hz`` packet slots (a token bucket that
holds at most two ticks' worth) and spends them, as one batch, in this order:

0. an operator's emergency stop, to every vehicle, ahead of everything (it may overdraw the bucket);
1. the driving command switch: one FIFO of vehicles whose wheel command is due, served at most
   `drive_hz` packets per second for all drivers together, one packet at a time; a command that
   stops wheels last sent turning goes ahead of the queue and of the switch's rate (at 80 vehicles
   on a loaded machine, drivers held by the fleet's guards rolled on into the vehicle they had
   stopped for while their stop queued behind the others' refreshes, eight drivers to a radio);
2. flight: one commander packet per flying (or landing, stopping, settling) vehicle, and for each
   vehicle in onboard control mode its newest motion-capture pose not yet sent (external pose,
   before its setpoint: the onboard estimator flies on it), round-robin from where the last tick
   stopped, with the slots left. When the budget is short, every flying vehicle's rate drops
   equally instead of some starving;
3. supervisor requests (arming, crash recovery) and the wheel app's status requests, `status_hz`
   per vehicle with the app, staggered: with the slots flight left (they wait, setpoints do not); a
   vehicle without the app gets a null packet instead, so that a parked stock Crazyflie's link
   stays active (the firmware resets its log blocks after `CONFIG_RADIO_ACTIVITY_TIMEOUT_MS`
   without a radio packet; over a Crazyradio cflib polls anyway, over UDP it does not, and its
   link-statistics pings, which kept such a link alive, are stopped).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

from common.crazyflie import crtp
from common.deploy.radios import GatewayParams
from services.radio_gateway.health import Event
from services.radio_gateway.vehicle import VehicleChannel

Packet = tuple[str, bytes]
"""(vid, raw packet)."""


class Scheduler:
    """Chooses each tick's batch for the vehicles of one radio (the order of `channels` is fixed)."""

    def __init__(self, channels: Sequence[VehicleChannel], budget_pps: float, params: GatewayParams,
                 now: float) -> None:
        self.channels = list(channels)
        self.budget_pps = budget_pps
        self.params = params
        self._max_tokens = 2.0 * max(budget_pps / params.tick_hz, 1.0)
        self.tokens = self._max_tokens  # an idle radio
        self._last = now
        self._drive_credit = 1.0
        self.switch: deque[str] = deque()
        self._status_period = 1.0 / params.status_hz
        n = max(len(self.channels), 1)
        self._status_due = {ch.vid: now + i * self._status_period / n for i, ch in enumerate(self.channels)}
        self._rr = 0
        self._by_vid = {ch.vid: ch for ch in self.channels}
        self.flight_skipped = 0
        """Flight slots wanted but not granted for lack of budget (a measure of overload)."""

    def tick(self, now: float) -> tuple[list[Packet], list[tuple[str, Event]]]:
        """This tick's batch and the (vid, event)s that choosing it caused."""
        elapsed = min(max(now - self._last, 0.0), 1.0)
        self._last = now
        self.tokens = min(self.tokens + self.budget_pps * elapsed, self._max_tokens)
        self._drive_credit = min(self._drive_credit + self.params.drive_hz * elapsed, 1.0)
        batch: list[Packet] = []
        events: list[tuple[str, Event]] = []
        self._estop(now, batch)
        self._drive(now, batch)
        self._flight(now, batch, events)
        self._requests(now, batch, events)
        self._status(now, batch)
        return batch, events

    def _estop(self, now: float, batch: list[Packet]) -> None:
        for ch in self.channels:
            raw = ch.estop_packet(now)
            if raw is not None:
                self.tokens -= 1.0
                batch.append((ch.vid, raw))

    def _requests(self, now: float, batch: list[Packet], events: list[tuple[str, Event]]) -> None:
        for ch in self.channels:
            if self.tokens < 1.0:
                return
            raw, caused = ch.request_packet(now)
            events.extend((ch.vid, e) for e in caused)
            if raw is not None:
                self.tokens -= 1.0
                batch.append((ch.vid, raw))

    def _take(self) -> bool:
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True

    def _drive(self, now: float, batch: list[Packet]) -> None:
        for ch in self.channels:  # stops first, whatever the switch's rate
            if ch.wheels_to_stop and self.tokens >= 1.0:
                raw = ch.wheel_packet(now)
                if raw is not None:
                    self.tokens -= 1.0
                    batch.append((ch.vid, raw))
        queued = set(self.switch)
        self.switch.extend(ch.vid for ch in self.channels if ch.vid not in queued and ch.wheel_due(now))
        while self.switch and self._drive_credit >= 1.0 and self.tokens >= 1.0:
            vid = self.switch.popleft()
            raw = self._by_vid[vid].wheel_packet(now)
            if raw is None:  # no longer due (a flight command took over)
                continue
            self.tokens -= 1.0
            self._drive_credit -= 1.0
            batch.append((vid, raw))

    def _status(self, now: float, batch: list[Packet]) -> None:
        for ch in self.channels:
            due = self._status_due[ch.vid]
            if now >= due and self._take():
                batch.append((ch.vid, ch.status_request(now) if ch.wheels else crtp.NULL_PACKET))
                self._status_due[ch.vid] = max(due + self._status_period, now)

    def _flight(self, now: float, batch: list[Packet], events: list[tuple[str, Event]]) -> None:
        n = len(self.channels)
        order = [self.channels[(self._rr + k) % n] for k in range(n)]
        wanted = [(k, ch, pose) for k, ch in enumerate(order) for pose in (True, False)
                  if (ch.extpose_due() if pose else ch.flight_due(now))]
        for i, (k, ch, pose) in enumerate(wanted):
            if not self._take():
                self.flight_skipped += len(wanted) - i
                self._rr = (self._rr + k) % n
                return
            if pose:
                batch.append((ch.vid, ch.extpose_packet()))
                continue
            raw, caused = ch.flight_packet(now)
            events.extend((ch.vid, e) for e in caused)
            if raw is None:
                self.tokens += 1.0
                continue
            batch.append((ch.vid, raw))
        self._rr = (self._rr + 1) % n if n else 0
