"""`fleet gateway`: one process per Crazyradio (paper 000 §VI-C, Fig. 4 "radio server").

It owns the vehicles of one radio of the radios file, takes each one's latest `Cmd` from
`vehicle/<vid>/cmd`, and every tick sends one batch within the radio's packet budget (`Scheduler`):
flight setpoints round-robin, wheel commands serialised through the driving command switch,
supervisor requests, the wheel app's status requests. Each vehicle is a cflib `Crazyflie`
(`link.py`) whose firmware streams a log block (battery, supervisor state, RSSI); the gateway
publishes `Telemetry` per vehicle and `VehicleEvent`s (link up / lost / reopened, stale-command
landing or stop, landed, supervisor locked or crashed, reboots, emergency stop).

Who is obeyed: a vehicle of this radio, and only its owner, `owner_of(vid, live executors)` from the
gateway's own liveliness watch of service "executor"; anything else is refused, counted under
``refused:<reason>:<vid>`` and logged once per vehicle and reason. A vehicle whose command goes
stale lands (flying) or stops (driving) under the gateway's control (`VehicleChannel`).

Links: no log block for `link_timeout_s` means the link is lost (`Telemetry.link_ok`); the vehicle
keeps getting its setpoints, so a short blackout is flown through. A link that fails to open,
drops, or stays silent for `pause_after_s` is closed and reopened after `reopen_s`, doubling up to
`reopen_max_s`: a dead vehicle does not eat its neighbours' airtime (cflib's radio driver retries an
unacknowledged packet without back-off). A
vehicle whose supervisor locked (reboot required) is rebooted through its radio chip and
reconnected, unless the operator's emergency stop locked it: `fleet estop` (key `estop`, operator
role) makes every gateway send the supervisor's emergency stop to every vehicle, refuse commands,
and, on `--release`, reboot them. Counters and link figures go out on `stats/gateway/<instance>`.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from dataclasses import dataclass

from common.bus.keys import Keys
from common.bus.messages import Cmd, CmdBatch, EmergencyStop, PoseFrame, Telemetry, VehicleEvent
from common.bus.pubsub import Subscription, call_in_loop, subscribe
from common.bus.service import Service
from common.bus.session import ZenohConfig
from common.bus.stats import percentile_figures, publish_stats
from common.crazyflie import crtp
from common.deploy.radios import RadiosFile
from common.domain.ownership import owner_of
from services.radio_gateway.health import FLYING, LINK_EVENTS, LOCKED, Event
from services.radio_gateway.link import RadioSender, VehicleLink
from services.radio_gateway.scheduler import Scheduler
from services.radio_gateway.vehicle import Refused, VehicleChannel

log = logging.getLogger(__name__)

STALL_S = 0.2
"""A tick this late means the gateway's process stalled: the silence it saw is excused."""


@dataclass
class Connection:
    """The gateway's view of one link: open, closed (and when to try again), or being rebooted."""

    state: str = "closed"
    due: float = 0.0
    backoff: float = 0.0
    rebooting: bool = False


class RadioGateway(Service):
    """The gateway of radio `radio` in `spec`. `instance` defaults to the radio's name.

    `subscribe_each`: subscribe to each own vehicle's cmd key instead of ``vehicle/*/cmd``. The
    wildcard lets the gateway see (and refuse, count and log) commands for vehicles it does not
    serve; with many gateways it costs each of them a decode of every command of the fleet, so
    large fleets subscribe per vehicle (docs/radio.md)."""

    def __init__(self, radio: str, spec: RadiosFile, zconfig: ZenohConfig, instance: str | None = None,
                 keys: Keys | None = None, subscribe_each: bool = False) -> None:
        if radio not in spec.radios:
            raise ValueError(f"no radio {radio!r} in the radios file (has {', '.join(spec.radios)})")
        super().__init__("gateway", instance or radio, zconfig, keys)
        self.radio = radio
        self.spec = spec.radios[radio]
        self.params = spec.gateway
        self.subscribe_each = subscribe_each
        now = time.time()
        self.channels = {vid: VehicleChannel(vid, self.params, now, wheels=link.wheels, flies=link.flies,
                                             onboard=link.onboard)
                         for vid, link in self.spec.vehicles.items()}
        self.scheduler = Scheduler(list(self.channels.values()),
                                   self.spec.link.budget_pps, self.params, now)
        self.owners: dict[str, str | None] = dict.fromkeys(self.channels)
        self.connections = {vid: Connection() for vid in self.channels}
        self._logged: set[tuple[str, str]] = set()
        self._links: dict[str, VehicleLink] = {}
        self._poses: Subscription[PoseFrame] | None = None
        self._pose_t = 0.0  # capture time of the newest frame behind the commands taken this tick
        self._pose_arrived = 0.0  # and when the mocap bridge had it
        self.latency: deque[float] = deque(maxlen=20000)
        """Capture time of the frame an executor's batch fused -> its setpoints handed to the radio (s)."""
        self.software_latency: deque[float] = deque(maxlen=20000)
        """The same from the frame's arrival at the mocap bridge (the capture system's latency excluded)."""
        self.ticks = 0

    # ---- lifecycle ------------------------------------------------------------------------

    async def main(self) -> None:
        loop = asyncio.get_running_loop()
        self._telemetry = self.publishers(lambda vid: self.keys.vehicle(vid, "telemetry"), Telemetry)
        self._events = self.publishers(lambda vid: self.keys.vehicle(vid, "event"), VehicleEvent)
        alive = await self.watch_alive("executor", lambda _i, _a, live: self._set_executors(live))
        self._set_executors(alive.instances)
        self.subscribe(self.keys.estop, EmergencyStop, self._on_estop)
        cmds = [self.subscribe(key, Cmd) for key in  # pulled by each tick
                ([self.keys.vehicle(vid, "cmd") for vid in self.channels] if self.subscribe_each
                 else [self.keys.all_vehicles("cmd")])]
        batches = self.subscribe(self.keys.gateway_cmd(self.instance), CmdBatch)
        in_loop = lambda fn: lambda *a: call_in_loop(loop, fn, *a)  # noqa: E731
        period_ms = round(self.params.log_period_s * 1000)
        self._links = {vid: VehicleLink(vid, link.uri, link.firmware_params(self.params.params, self.params.landing.mass),
                                        period_ms,
                                        in_loop(self._on_log), in_loop(self._on_packet), in_loop(self._on_link_state))
                       for vid, link in self.spec.vehicles.items()}
        sender = RadioSender(self.radio, in_loop(self._on_link_error), self.counters)
        self.spawn(publish_stats(self, self._figures), name="stats")
        try:
            await self._run(sender, cmds, batches)
        finally:
            sender.close()
            if self._poses is not None:
                self._poses.close()
            await asyncio.gather(*(asyncio.to_thread(link.close) for link in self._links.values()))

    async def _run(self, sender: RadioSender, cmds: list[Subscription[Cmd]], batches: Subscription[CmdBatch]) -> None:
        """The tick loop: the commands that arrived, links, safety, one batch, pose subscriptions,
        telemetry. Commands are taken right before the staleness check: a tick that runs late (a
        starved process) must not take its owner's waiting commands for missing ones. A tick runs
        every period, and at once when an executor's command batch arrives (its setpoints go out
        without waiting for the next tick; `VehicleChannel.flight_due` keeps the pace): with the
        radio's vehicles spread over two executors, up to twice a period. Telemetry goes out every
        1 / `status_hz` s of the clock, not every so many ticks (counted in ticks, it went out at
        10.6 Hz a vehicle instead of 5: twice the puts, and twice the decoding in every process
        that hears telemetry)."""
        loop = asyncio.get_running_loop()
        period = 1.0 / self.params.tick_hz
        telemetry_period = 1.0 / self.params.status_hz
        due = loop.time()
        telemetry_due = time.time()
        while True:
            late = loop.time() - due
            for got, _key in batches.drain():
                self._on_batch(got)
            for sub in cmds:
                for cmd, key in sub.drain():
                    self._on_cmd(cmd, key)
            now = time.time()
            self.ticks += 1
            for vid, ch in self.channels.items():
                if late > STALL_S:
                    ch.health.excuse(now)
                self._publish_events(vid, ch.supervise(now))
                self._manage_link(vid, now)
            batch, events = self.scheduler.tick(now)
            for vid, event in events:
                self._publish_events(vid, [event])
            if batch:
                sender.submit([(self._links[vid], raw) for vid, raw in batch])
            if self._pose_t:
                handed = time.time()
                self.latency.append(handed - self._pose_t)
                self.software_latency.append(handed - (self._pose_arrived or self._pose_t))
                self._pose_t = self._pose_arrived = 0.0
            self._sync_pose_subscriptions()
            if now >= telemetry_due:
                self._publish_telemetry(now)
                telemetry_due = max(telemetry_due + telemetry_period, now)
            due += period
            delay = due - loop.time()
            if delay < -period:  # fell behind: the token bucket already caps the catch-up
                due = loop.time()
                delay = 0.0
            if await batches.wait(delay):
                due = loop.time()  # ticking now: the next regular tick a period later

    # ---- links ------------------------------------------------------------------------------

    def _manage_link(self, vid: str, now: float) -> None:
        """Open a closed link when due; reboot a locked vehicle (unless the operator stopped it)."""
        conn, ch = self.connections[vid], self.channels[vid]
        if conn.state == "closed" and now >= conn.due and not conn.rebooting:
            conn.state, conn.due = "opening", now + self.params.connect_timeout_s
            ch.health.reset(now, forget=False)
            self.spawn(asyncio.to_thread(self._links[vid].open), name=f"open {vid}")
        elif conn.state == "opening" and now >= conn.due:  # over UDP cflib waits forever for a lost reply
            conn.state = "closing"
            self.spawn(self._close_then(vid, f"not connected within {self.params.connect_timeout_s:.0f} s"),
                       name=f"give up {vid}")
        elif conn.state == "open" and ch.health.bit(LOCKED) and not ch.estopped and not conn.rebooting:
            self._reboot(vid, "supervisor locked")
        elif conn.state == "open" and not ch.health.link_ok:
            if ch.health.silent_for(now) > self.params.pause_after_s:
                self._pause(vid, f"no log block for {ch.health.silent_for(now):.1f} s")
            elif now >= conn.due:  # probe: the log block again (the firmware drops it after 1 s of silence)
                conn.due = now + self.params.link_timeout_s
                self.spawn(asyncio.to_thread(self._links[vid].refresh_log), name=f"probe {vid}")

    def _reopen_later(self, vid: str, now: float, why: str) -> None:
        conn = self.connections[vid]
        conn.backoff = min(max(conn.backoff * 2.0, self.params.reopen_s), self.params.reopen_max_s)
        conn.state, conn.due = "closed", now + conn.backoff
        self._publish_events(vid, [("link_closed", f"{why}: reopening in {conn.backoff:.0f} s")])

    def _on_link_state(self, vid: str, state: str, detail: str) -> None:
        conn, now = self.connections[vid], time.time()
        if state == "connected":  # the first probe only if no log block came for a link timeout
            conn.state, conn.due = "open", now + self.params.link_timeout_s
            ch = self.channels[vid]
            was_flying = bool(ch.health.bit(FLYING))
            ch.health.reset(now)
            ch.connected(was_flying)
            self._publish_events(vid, [("link_open", detail)])
        elif state in ("failed", "lost") and conn.state != "closing" and not conn.rebooting:
            self.spawn(asyncio.to_thread(self._links[vid].close), name=f"close {vid}")
            self._reopen_later(vid, now, f"link {state}: {detail}")
        elif state == "info":
            log.info("%s: %s: %s", self.instance, vid, detail)

    def _pause(self, vid: str, why: str) -> None:
        """A link judged lost: close it (no more airtime for it) and reopen with back-off."""
        conn = self.connections[vid]
        if conn.state == "open":
            conn.state = "closing"
            self.spawn(self._close_then(vid, why), name=f"pause {vid}")

    async def _close_then(self, vid: str, why: str) -> None:
        await asyncio.to_thread(self._links[vid].close)
        self._reopen_later(vid, time.time(), why)

    def _reboot(self, vid: str, why: str) -> None:
        conn = self.connections[vid]
        conn.rebooting, conn.state = True, "closing"
        self._publish_events(vid, [("rebooting", f"{why}: rebooting through the radio")])
        self.spawn(self._do_reboot(vid), name=f"reboot {vid}")

    async def _do_reboot(self, vid: str) -> None:
        conn = self.connections[vid]
        try:
            await asyncio.to_thread(self._links[vid].reboot)
            self._publish_events(vid, [("rebooted", f"reconnecting in {self.params.boot_s:.1f} s")])
        except Exception as exc:  # cflib's PowerSwitch raises plain Exceptions
            self._publish_events(vid, [("reboot_failed", str(exc))])
        finally:
            conn.rebooting, conn.state, conn.backoff = False, "closed", 0.0
            conn.due = time.time() + self.params.boot_s

    # ---- inputs ---------------------------------------------------------------------------

    def _set_executors(self, live: frozenset[str]) -> None:
        for vid in self.channels:
            owner = owner_of(vid, live)
            if owner != self.owners[vid]:
                log.info("%s: %s owned by %s", self.instance, vid, owner or "no executor")
            self.owners[vid] = owner

    def _refuse(self, reason: str, vid: str, detail: str) -> None:
        """Count; log the first of each (reason, vehicle): other radios' vehicles at INFO (normal when
        several gateways share the fleet), anything else at WARNING."""
        self.counters.inc(f"refused:{reason}:{vid}")
        if (reason, vid) not in self._logged:
            self._logged.add((reason, vid))
            log.log(logging.INFO if reason == "unassigned" else logging.WARNING,
                    "%s: refused cmd for %s: %s (further ones only counted)", self.instance, vid, detail)

    def _on_batch(self, batch: CmdBatch) -> None:
        if batch.pose_t > self._pose_t:
            self._pose_t, self._pose_arrived = batch.pose_t, batch.pose_arrived
        for cmd in batch.cmds:
            self._command(cmd.vid, cmd)

    def _on_cmd(self, cmd: Cmd, key: str) -> None:
        parsed = self.keys.parse_vehicle(key)
        self._command(parsed[0] if parsed else cmd.vid, cmd)

    def _command(self, vid: str, cmd: Cmd) -> None:
        ch = self.channels.get(vid)
        if ch is None:
            self._refuse("unassigned", vid, f"{vid} is not on radio {self.radio}")
            return
        if cmd.vid != vid:
            self._refuse("vid_mismatch", vid, f"a cmd on {vid}'s key names vehicle {cmd.vid!r}")
            return
        owner = self.owners[vid]
        if cmd.owner != owner:
            self._refuse("not_owner", vid, f"sent by {cmd.owner!r}, owner is {owner or 'no live executor'}")
            return
        try:
            events = ch.command(cmd.setpoint, time.time())
        except Refused as exc:
            self._refuse(exc.reason, vid, str(exc))
            return
        except ValueError as exc:
            self._refuse("bad_setpoint", vid, str(exc))
            return
        self._publish_events(vid, events)

    def _on_log(self, vid: str, at: float, values: dict[str, float]) -> None:
        if self.connections[vid].state == "open":
            self.connections[vid].backoff = 0.0
        self._publish_events(vid, self.channels[vid].health.on_log(values, at))

    def _on_packet(self, vid: str, raw: bytes) -> None:
        try:
            packet = crtp.decode_downlink(raw)
        except crtp.CrtpError as exc:
            if self.counters.inc(f"drop:malformed:crtp:{vid}") == 1:
                log.warning("%s: dropped malformed packet from %s: %s (further ones only counted)",
                            self.instance, vid, exc)
            return
        if isinstance(packet, crtp.Status):
            self._publish_events(vid, self.channels[vid].on_status(packet, time.time()))

    def _on_link_error(self, vid: str, message: str) -> None:
        if self.counters.inc(f"link_error:{vid}") == 1:
            log.warning("%s: link of %s: %s (further errors only counted)", self.instance, vid, message)
            self._publish_events(vid, [("link_error", message)])

    def _on_frame(self, frame: PoseFrame, _key: str) -> None:
        now = time.time()
        for p in frame.poses:
            ch = self.channels.get(p.vid)
            if ch is not None and ch.wants_poses:
                ch.on_pose(frame.pose(p), now)

    def _on_estop(self, stop: EmergencyStop, _key: str) -> None:
        for vid, ch in self.channels.items():
            if stop.release:
                if ch.estopped:
                    ch.clear_emergency_stop()
                    self._reboot(vid, "emergency stop released")
            elif not ch.estopped:
                ch.emergency_stop()
                self._publish_events(vid, [("emergency_stop", stop.reason or "operator's emergency stop")])

    # ---- outputs --------------------------------------------------------------------------

    def _figures(self) -> dict[str, float]:
        chans = self.channels.values()
        return {"vehicles": len(self.channels), "ticks": self.ticks, "links_ok": sum(ch.health.link_ok for ch in chans),
                "taken_over": sum(ch.took_over for ch in chans),
                "skipped": sum(v for k, v in self.counters.items() if k.startswith("skipped:")),
                "flight_skipped": self.scheduler.flight_skipped, **percentile_figures("pose_to_radio", self.latency),
                **percentile_figures("frame_to_radio", self.software_latency)}

    def _sync_pose_subscriptions(self) -> None:
        """Motion-capture frames while a vehicle needs them: in onboard control mode (streamed to
        it), during a safety landing."""
        landing = any(ch.wants_poses for ch in self.channels.values())
        if landing and self._poses is None:
            self._poses = subscribe(self.session, self.keys.mocap_frame, PoseFrame, self._on_frame,
                                    counters=self.counters)
        elif not landing and self._poses is not None:
            self._poses.close()
            self._poses = None

    def _publish_events(self, vid: str, events: list[Event]) -> None:
        for kind, detail in events:
            log.info("%s: %s %s: %s", self.instance, vid, kind, detail)
            now = time.time()
            self._events.put(vid, VehicleEvent(vid=vid, t=now, kind=kind, detail=detail))
            if kind in LINK_EVENTS:  # the owner reacts on telemetry: tell it now, not at the next sample
                self._put_telemetry(vid, self.channels[vid], now)

    def _publish_telemetry(self, now: float) -> None:
        for vid, ch in self.channels.items():
            if ch.health.reporting(now):
                self._put_telemetry(vid, ch, now)

    def _put_telemetry(self, vid: str, ch: VehicleChannel, now: float) -> None:
        h, link = ch.health, self._links.get(vid)
        self._telemetry.put(vid, Telemetry(
            vid=vid, t=now, gateway=self.instance, vbat=h.vbat, link_quality=h.link_quality, sent=h.sent,
            dropped=h.app_lost, cmd_rate_hz=ch.command_rate(now), link_ok=h.link_ok, owner=self.owners[vid] or "",
            stale_cmd=ch.took_over, skipped=sum(v for k, v in self.counters.items() if k.startswith("skipped:")
                                               and k.endswith(f":{vid}")),
            supervisor=-1 if h.supervisor is None else h.supervisor, pm_state=h.pm_state, rssi=h.rssi,
            capabilities=self.spec.vehicles[vid].capabilities, firmware=link.firmware if link else "",
            estopped=ch.estopped, wheel_app_ok=h.app_ok is not False, control=self.spec.vehicles[vid].control))
