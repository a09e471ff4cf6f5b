"""One vehicle's health as the gateway knows it, from what the firmware itself streams (`link.py`):
the gateway's log block arrives every `period_s` with the battery (`pm.vbatMV`, `pm.state`), the
supervisor's state bits (`supervisor.info`) and the link's RSSI. With the wheel app (flying cars)
its STATUS replies add the app channel's own accounting (firmware/wheels/PROTOCOL.md).

The link is up from the first log block and lost when none came for `timeout_s`: 10 blocks at
the default 10 Hz, all lost or all late (at 30 % of the blocks lost, 0.3^10 per block period:
about once in 5 vehicle-hours; `bench.link_judgement`). Arrival times are stamped by cflib's receiving thread, not when the gateway's loop gets to
them, so a gateway whose loop stalled does not take its own stall for the vehicle's silence; a
stall of the whole process (the receiving thread too) is excused explicitly (`excuse`).
`link_quality` is the fraction of the blocks expected over the last `window_s` that arrived.
"""

from __future__ import annotations

from collections import deque

from common.crazyflie import crtp

Event = tuple[str, str]
APP_TIMEOUTS = 2.0
"""A flying car's wheel app is judged silent after this many link timeouts without a STATUS..."""
APP_UNANSWERED = 10
"""... and at least this many STATUS requests sent since the last one."""
"""(kind, detail) of a `VehicleEvent` to publish."""
LINK_EVENTS = frozenset({"link_lost", "link_up"})
"""The events that change `Telemetry.link_ok`."""

# supervisor.info bits (crazyflie-firmware supervisor.c, docs/firmware_model.md)
CAN_ARM, ARMED, AUTO_ARM, CAN_FLY, FLYING, TUMBLED, LOCKED, CRASHED = (1 << i for i in range(8))
PM_LOW_POWER = 3
"""`pm.state` of a battery below `pm.lowVoltage` for 5 s."""


class LinkHealth:
    """Battery, supervisor and link of one vehicle; `started` opens the first timeout."""

    def __init__(self, started: float, timeout_s: float, period_s: float, window_s: float = 5.0) -> None:
        self.timeout_s = timeout_s
        self.period_s = period_s
        self.window_s = window_s
        self.sent = 0
        """Packets handed to the vehicle's link."""
        self.app_seq = 0
        """App-channel packets (WHEELS, STATUS_REQUEST) handed to it: the STATUS_REQUEST counter."""
        self.vbat = 0.0
        self.pm_state = 0
        self.supervisor: int | None = None
        """The latest `supervisor.info`, None before the first log block."""
        self.rssi = 0.0
        self.link_ok = False
        self.heard = False
        self.app_lost = 0
        """App-channel packets lost, from the wheel app's replies (`echo_seq - received`)."""
        self.setpoint_age_ms: int | None = None
        self.stale_replies = 0
        self.app_asked = 0
        """STATUS requests sent since the last STATUS came."""
        self.app_ok: bool | None = None
        """The wheel app answers its STATUS requests (None: not judged yet; `check_app`)."""
        self._app_at: float | None = None
        self._started = self._since = self._app_from = started
        self._blocks: deque[float] = deque()
        self._echo = -1

    # ---- inputs ---------------------------------------------------------------------------------
    def on_log(self, values: dict[str, float], at: float) -> list[Event]:
        """Fold in a log block that arrived at `at`; the events it causes."""
        self._since = max(self._since, at)
        self._blocks.append(at)
        while self._blocks and at - self._blocks[0] > self.window_s:
            self._blocks.popleft()
        if "pm.vbatMV" in values:
            self.vbat = values["pm.vbatMV"] / 1000.0
        self.pm_state = int(values.get("pm.state", self.pm_state))
        self.rssi = float(values.get("radio.rssi", self.rssi))
        events: list[Event] = []
        if "supervisor.info" in values:
            events += self._supervisor(int(values["supervisor.info"]))
        if not self.link_ok:
            self.link_ok = self.heard = True
            events.append(("link_up", f"log blocks after {self.sent} packets sent"))
        return events

    def _supervisor(self, info: int) -> list[Event]:
        before = self.supervisor or 0
        self.supervisor = info
        events: list[Event] = []
        for bit, kind, text in ((LOCKED, "vehicle_locked", "supervisor locked: reboot required"),
                                (CRASHED, "vehicle_crashed", "supervisor: crashed, recovery required"),
                                (TUMBLED, "vehicle_tumbled", "supervisor: tumbled")):
            if info & bit and not before & bit:
                events.append((kind, text))
        return events

    def on_status(self, st: crtp.Status, now: float) -> list[Event]:
        """Fold in a wheel-app STATUS; an old or impossible one is counted and ignored."""
        lost = (st.echo_seq - st.received + 2**31) % 2**32 - 2**31
        if st.echo_seq <= self._echo or lost < 0:
            self.stale_replies += 1
            return []
        self._echo = st.echo_seq
        self._app_at = now
        self.app_asked = 0
        self.app_lost = lost
        self.setpoint_age_ms = st.setpoint_age_ms
        if not self.heard:
            self.vbat = st.vbat_mv / 1000.0
        events: list[Event] = []
        if self.app_ok is False:
            events.append(("wheel_app_up", "the wheel app answers again"))
        self.app_ok = True
        if st.flags & crtp.FLAG_WHEEL_WATCHDOG:
            events.append(("wheel_watchdog", "wheel watchdog stopped the wheels (no wheel command for 0.5 s)"))
        return events

    def excuse(self, now: float) -> None:
        """The gateway's process was stalled: silence before `now` is not the vehicle's."""
        self._since = max(self._since, now - self.period_s)
        if self._app_at is not None:
            self._app_at = max(self._app_at, now - self.period_s)
        self._app_from = max(self._app_from, now - self.period_s)

    def check(self, now: float) -> list[Event]:
        """The link-lost event, once: no log block for `timeout_s`."""
        if not self.link_ok or now - self._since <= self.timeout_s:
            return []
        self.link_ok = False
        return [("link_lost", f"no log block for {now - self._since:.2f} s")]

    def check_app(self, now: float) -> list[Event]:
        """A flying car's wheel-app event, once: the link is up (log blocks) but no STATUS came for
        `APP_TIMEOUTS` link timeouts and `APP_UNANSWERED` requests (the app is missing, or speaks
        another protocol version; a radio whose budget flight takes sends no requests to miss)."""
        since = self._app_at if self._app_at is not None else self._app_from
        if (not self.link_ok or self.app_ok is False or now - since <= APP_TIMEOUTS * self.timeout_s
                or self.app_asked < APP_UNANSWERED):
            return []
        self.app_ok = False
        return [("wheel_app_silent", f"no wheel-app STATUS for {now - since:.1f} s while the link is up: "
                                     "no wheel app, or not protocol v2 (firmware/wheels/PROTOCOL.md)")]

    def reset(self, now: float, forget: bool = True) -> None:
        """A new connection (after a reopen or a reboot): judge it afresh; what the old one said of the
        supervisor is stale (`forget`; kept while the connection is still being made)."""
        self._since = now
        self._blocks.clear()
        self._echo = -1
        self._app_at = None
        self._app_from = now
        self.app_asked = 0
        if forget:
            self.supervisor = None

    # ---- what it says -----------------------------------------------------------------------------
    def silent_for(self, now: float) -> float:
        return now - self._since

    def reporting(self, now: float) -> bool:
        """Telemetry is worth publishing: a block came, or the first timeout passed without one."""
        return self.heard or now - self._started > self.timeout_s

    def bit(self, mask: int) -> bool | None:
        """A supervisor bit, None while unknown."""
        return None if self.supervisor is None else bool(self.supervisor & mask)

    @property
    def link_quality(self) -> float:
        """Fraction of the log blocks expected in the last window that arrived (0 when lost)."""
        if not self.link_ok or not self._blocks:
            return 0.0
        expected = (self._blocks[-1] - self._blocks[0]) / self.period_s + 1.0
        return min(1.0, len(self._blocks) / expected)
