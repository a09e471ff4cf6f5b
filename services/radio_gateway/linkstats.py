"""Per-vehicle link accounting from our status replies (docs/wheel_protocol.md).

Every packet the gateway hands to a vehicle's link is counted in `sent`. A status request carries
that count; the vehicle answers with it (`echo_sent`) and with how many packets it has received up
to and including the request. Packets stay in order on the link, so every packet sent before the
request was either received by then or lost: `dropped = echo_sent - received` exactly, whatever the
latency. Rates and link quality come from the replies of the last `window_s`.

A link is lost when no reply came for `timeout_s` *and* at least `lost_after` status requests went
unanswered for `reply_wait_s`. Silence alone is not enough: a gateway whose process stalled for a
second sent no requests meanwhile, and must not take its own stall for the vehicle's (docs/radio.md).
The scheduler probes a silent vehicle faster (`GatewayParams.probe_hz`), so a lossy link that is
still up answers one of many requests before the timeout.
"""

from __future__ import annotations

from collections import deque

from common.crazyflie import crtp

Event = tuple[str, str]
"""(kind, detail) of a `VehicleEvent` to publish."""
LINK_EVENTS = frozenset({"link_lost", "link_up"})
"""The events that change `Telemetry.link_ok`."""

_WATCHDOG_FLAGS = ((crtp.FLAG_WATCHDOG_CUT, "firmware watchdog stopped the motors (no setpoint for 2 s)"),
                   (crtp.FLAG_WATCHDOG_LEVEL, "firmware watchdog levelled the attitude (no setpoint for 0.5 s)"),
                   (crtp.FLAG_WHEEL_WATCHDOG, "wheel watchdog stopped the wheels (no wheel command for 0.5 s)"))


class LinkStats:
    """Counts, battery and health of one vehicle's link; `started` opens the first timeout."""

    def __init__(self, started: float, timeout_s: float, lost_after: int = 1, reply_wait_s: float = 0.1,
                 window_s: float = 1.0) -> None:
        self.timeout_s = timeout_s
        self.lost_after = lost_after
        self.reply_wait_s = reply_wait_s
        self.window_s = window_s
        self.sent = 0
        self.acked = 0
        self.dropped = 0
        self.vbat = 0.0
        self.flags = 0
        self.link_ok = False
        self.heard = False
        self.stale_replies = 0
        self._started = self._since = started
        self._echo = -1
        self._window: deque[tuple[float, int, int, int]] = deque()  # t, echo_sent, received, setpoints
        self._asked: deque[tuple[int, float]] = deque()  # (sent, t) of the requests not answered yet

    def request(self, now: float) -> int:
        """Count a status request sent at `now`; the `sent` it carries. Only a live link's requests
        are kept for `check` (a lost one's would pile up for as long as the vehicle is gone)."""
        self.sent += 1
        if self.link_ok:
            self._asked.append((self.sent, now))
        return self.sent

    def on_status(self, st: crtp.Status, now: float) -> list[Event]:
        """Fold in a reply received at `now`; the events it causes."""
        if st.echo_sent <= self._echo or st.received > st.echo_sent:
            self.stale_replies += 1  # an old or impossible reply: nothing new in it
            return []
        self._echo = st.echo_sent
        while self._asked and self._asked[0][0] <= st.echo_sent:
            self._asked.popleft()
        self.acked = st.received
        self.dropped = st.echo_sent - st.received
        self.vbat = st.vbat_mv / 1000.0
        self.flags = st.flags
        self._window.append((now, st.echo_sent, st.received, st.setpoints))
        while len(self._window) > 2 and now - self._window[1][0] >= self.window_s:
            self._window.popleft()
        self._since = now
        events = [("firmware_watchdog" if flag != crtp.FLAG_WHEEL_WATCHDOG else "wheel_watchdog", text)
                  for flag, text in _WATCHDOG_FLAGS if st.flags & flag]
        if not self.link_ok:
            self.link_ok = self.heard = True
            events.append(("link_up", f"status after {self.sent} packets sent"))
        return events

    def silent_for(self, now: float) -> float:
        """Seconds since the last reply (or since `started`)."""
        return now - self._since

    def check(self, now: float) -> list[Event]:
        """The link-lost event, once: no reply for `timeout_s` and `lost_after` requests unanswered."""
        if not self.link_ok or now - self._since <= self.timeout_s:
            return []
        unanswered = sum(1 for _, t in self._asked if now - t >= self.reply_wait_s)
        if unanswered < self.lost_after:
            return []
        self.link_ok = False
        self._asked.clear()
        return [("link_lost", f"no status for {now - self._since:.2f} s, {unanswered} requests unanswered")]

    def reporting(self, now: float) -> bool:
        """Telemetry is worth publishing: a reply came, or the first timeout passed without one."""
        return self.heard or now - self._started > self.timeout_s

    def _span(self) -> tuple[float, int, int, int] | None:
        if len(self._window) < 2:
            return None
        (t0, e0, r0, s0), (t1, e1, r1, s1) = self._window[0], self._window[-1]
        return t1 - t0, e1 - e0, r1 - r0, s1 - s0

    @property
    def cmd_rate_hz(self) -> float:
        """Setpoints (flight, stop, wheels) the vehicle received per second, last window."""
        span = self._span()
        return span[3] / span[0] if span and span[0] > 0 else 0.0

    @property
    def link_quality(self) -> float:
        """Fraction of the packets sent in the last window that arrived (0 when the link is lost)."""
        if not self.link_ok:
            return 0.0
        span = self._span()
        return span[2] / span[1] if span and span[1] > 0 else 1.0
