"""`fleet gateway`: one process per Crazyradio (paper 000 §VI-C, Fig. 4 "radio server").

It owns the vehicles of one radio of the radios file, takes each one's latest `Cmd` from
`vehicle/<vid>/cmd`, and every tick sends one batch within the radio's packet budget (`Scheduler`):
flight setpoints round-robin, wheel commands serialised through the driving command switch, status
requests. It publishes `Telemetry` per vehicle (battery, link quality, packets sent / acked /
dropped, achieved command rate) and `VehicleEvent`s (link up / lost, stale-command landing or stop,
landed, firmware watchdog trips).

Who is obeyed: a vehicle of this radio, and only its owner, `owner_of(vid, live executors)` from the
gateway's own liveliness watch of service "executor"; anything else is refused, counted under
``refused:<reason>:<vid>`` and logged once per vehicle and reason. A vehicle whose command goes
stale lands (flying) or stops (driving) under the gateway's control (`VehicleChannel`).
Counters (refusals, drops, radio_behind) and link figures go out on `stats/gateway/<instance>`.
"""

from __future__ import annotations

import asyncio
import logging
import time

from common.bus.keys import Keys
from common.bus.messages import Cmd, Pose, Telemetry, VehicleEvent
from common.bus.pubsub import Publisher, Subscription, call_in_loop, subscribe
from common.bus.service import Service
from common.bus.session import ZenohConfig
from common.bus.stats import publish_stats
from common.crazyflie import crtp
from common.deploy.radios import RadiosFile
from common.domain.ownership import owner_of
from services.radio_gateway.link import CrtpLink, RadioSender
from services.radio_gateway.linkstats import LINK_EVENTS, Event
from services.radio_gateway.scheduler import Scheduler
from services.radio_gateway.vehicle import Refused, VehicleChannel

log = logging.getLogger(__name__)


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
        self.channels = {vid: VehicleChannel(vid, self.params, now) for vid in self.spec.vehicles}
        self.scheduler = Scheduler(list(self.channels.values()), self.spec.link.budget_pps, self.params, now)
        self.owners: dict[str, str | None] = dict.fromkeys(self.channels)
        self._logged: set[tuple[str, str]] = set()
        self._links: dict[str, CrtpLink] = {}
        self._telemetry: dict[str, Publisher[Telemetry]] = {}
        self._events: dict[str, Publisher[VehicleEvent]] = {}
        self._poses: dict[str, Subscription[Pose]] = {}

    # ---- lifecycle ------------------------------------------------------------------------

    async def main(self) -> None:
        loop = asyncio.get_running_loop()
        for vid in self.channels:
            self._telemetry[vid] = self.publisher(self.keys.vehicle(vid, "telemetry"), Telemetry)
            self._events[vid] = self.publisher(self.keys.vehicle(vid, "event"), VehicleEvent)
        alive = await self.watch_alive("executor", lambda _i, _a, live: self._set_executors(live))
        self._set_executors(alive.instances)
        cmds = [self.subscribe(key, Cmd) for key in  # pulled by each tick
                ([self.keys.vehicle(vid, "cmd") for vid in self.channels] if self.subscribe_each
                 else [self.keys.all_vehicles("cmd")])]
        on_packet = lambda vid, raw: call_in_loop(loop, self._on_packet, vid, raw)  # noqa: E731
        on_error = lambda vid, msg: call_in_loop(loop, self._on_link_error, vid, msg)  # noqa: E731
        self._links = {vid: CrtpLink(vid, link.uri, on_packet, on_error) for vid, link in self.spec.vehicles.items()}
        sender = RadioSender(self.radio, on_error, self.counters)
        self.spawn(publish_stats(self, self._figures), name="stats")
        try:
            await self._run(sender, cmds)
        finally:
            sender.close()
            for sub in self._poses.values():
                sub.close()
            await asyncio.gather(*(asyncio.to_thread(link.close) for link in self._links.values()))

    async def _run(self, sender: RadioSender, cmds: list[Subscription[Cmd]]) -> None:
        """The tick loop: the commands that arrived, safety, one batch, pose subscriptions,
        telemetry. Commands are taken right before the staleness check: a tick that runs late (a
        starved process) must not take its owner's waiting commands for missing ones."""
        loop = asyncio.get_running_loop()
        period = 1.0 / self.params.tick_hz
        telemetry_every = max(1, round(self.params.tick_hz / self.params.status_hz))
        due = loop.time()
        ticks = 0
        while True:
            for sub in cmds:
                for cmd, key in sub.drain():
                    self._on_cmd(cmd, key)
            now = time.time()
            for ch in self.channels.values():
                self._publish_events(ch.vid, ch.supervise(now))
            batch, events = self.scheduler.tick(now)
            for vid, event in events:
                self._publish_events(vid, [event])
            if batch:
                sender.submit([(self._links[vid], raw) for vid, raw in batch])
            self._sync_pose_subscriptions()
            if ticks % telemetry_every == 0:
                self._publish_telemetry(now)
            ticks += 1
            due += period
            delay = due - loop.time()
            if delay < -period:  # fell behind: the token bucket already caps the catch-up
                due = loop.time()
                delay = 0.0
            await asyncio.sleep(delay)

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

    def _on_cmd(self, cmd: Cmd, key: str) -> None:
        parsed = self.keys.parse_vehicle(key)
        vid = parsed[0] if parsed else cmd.vid
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

    def _on_pose(self, pose: Pose, key: str) -> None:
        parsed = self.keys.parse_vehicle(key)
        if parsed is not None and parsed[0] in self.channels:
            self.channels[parsed[0]].on_pose(pose, time.time())

    # ---- outputs --------------------------------------------------------------------------

    def _figures(self) -> dict[str, float]:
        chans = self.channels.values()
        return {"vehicles": len(self.channels), "links_ok": sum(ch.stats.link_ok for ch in chans),
                "taken_over": sum(ch.took_over for ch in chans),
                "packets_dropped": sum(ch.stats.dropped for ch in chans)}

    def _sync_pose_subscriptions(self) -> None:
        """Poses only matter during a safety landing: subscribe while one lasts."""
        for vid, ch in self.channels.items():
            if ch.landing is not None and vid not in self._poses:
                self._poses[vid] = subscribe(self.session, self.keys.vehicle(vid, "pose"), Pose, self._on_pose,
                                             counters=self.counters)
            elif ch.landing is None and vid in self._poses:
                self._poses.pop(vid).close()

    def _publish_events(self, vid: str, events: list[Event]) -> None:
        for kind, detail in events:
            log.info("%s: %s %s: %s", self.instance, vid, kind, detail)
            now = time.time()
            self._events[vid].put(VehicleEvent(vid=vid, t=now, kind=kind, detail=detail))
            if kind in LINK_EVENTS:  # the owner reacts on telemetry: tell it now, not at the next sample
                self._put_telemetry(vid, self.channels[vid], now)

    def _publish_telemetry(self, now: float) -> None:
        for vid, ch in self.channels.items():
            if ch.stats.reporting(now):
                self._put_telemetry(vid, ch, now)

    def _put_telemetry(self, vid: str, ch: VehicleChannel, now: float) -> None:
        st = ch.stats
        self._telemetry[vid].put(Telemetry(
            vid=vid, t=now, gateway=self.instance, vbat=st.vbat, link_quality=st.link_quality, sent=st.sent,
            acked=st.acked, dropped=st.dropped, cmd_rate_hz=st.cmd_rate_hz, link_ok=st.link_ok,
            owner=self.owners[vid] or "", stale_cmd=ch.took_over))
