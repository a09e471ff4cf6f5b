"""The wheel app (firmware/wheels, the flying car's extension of the stock firmware), simulated: the
same protocol (version 2, firmware/wheels/PROTOCOL.md) and the same behaviour as
`firmware/wheels/src/wheels_logic.c`: WHEELS set the wheel speeds until the next one, the wheel
watchdog stops them more than 500 ms after the last non-zero WHEELS, and each STATUS_REQUEST is
answered with what an app can know (app-channel counts, uptime, battery, the commanded wheel speeds,
the age of the commander's setpoint, the supervisor's flags)."""

from __future__ import annotations

from dataclasses import dataclass

from common.crazyflie import crtp

WATCHDOG_S = 0.5


@dataclass(frozen=True)
class AppView:
    """What the app reads from the firmware when it builds a STATUS."""

    uptime_ms: int
    vbat: float
    setpoint_age_s: float
    motors: bool
    flying: bool
    armed: bool
    locked: bool
    low_battery: bool


class WheelsApp:
    def __init__(self) -> None:
        self.reboot()

    def reboot(self) -> None:
        self.left_mm_s = self.right_mm_s = 0
        self.received = 0
        self.rejected = 0
        self.watchdog_trips = 0
        self._last_wheels = -1e9
        self._latched = 0

    @property
    def speeds_m_s(self) -> tuple[float, float]:
        return self.left_mm_s / 1000.0, self.right_mm_s / 1000.0

    def tick(self, now: float) -> None:
        """The watchdog check (the app runs it at least every 10 ms)."""
        if (self.left_mm_s or self.right_mm_s) and now - self._last_wheels > WATCHDOG_S:
            self.left_mm_s = self.right_mm_s = 0
            self.watchdog_trips += 1
            self._latched |= crtp.FLAG_WHEEL_WATCHDOG

    def receive(self, payload: bytes, now: float, view: AppView) -> bytes | None:
        """One app-channel packet; the STATUS to send back, if it asked for one."""
        self.tick(now)
        self.received += 1
        try:
            msg = crtp.decode_app_uplink(payload)
        except crtp.CrtpError:
            self.rejected += 1
            return None
        if isinstance(msg, crtp.Wheels):
            self.left_mm_s, self.right_mm_s = msg.left_mm_s, msg.right_mm_s
            self._last_wheels = now
            return None
        return crtp.encode_status(self._status(msg.seq, view))

    def _status(self, seq: int, v: AppView) -> crtp.Status:
        flags = self._latched
        self._latched = 0
        for flag, on in ((crtp.FLAG_MOTORS, v.motors), (crtp.FLAG_FLYING, v.flying), (crtp.FLAG_ARMED, v.armed),
                         (crtp.FLAG_LOCKED, v.locked), (crtp.FLAG_LOW_BATTERY, v.low_battery)):
            if on:
                flags |= flag
        return crtp.Status(echo_seq=seq, received=self.received, uptime_ms=v.uptime_ms, rejected=self.rejected,
                           vbat_mv=round(v.vbat * 1000.0), wheel_left_mm_s=self.left_mm_s,
                           wheel_right_mm_s=self.right_mm_s, setpoint_age_ms=min(round(v.setpoint_age_s * 1000), 0xFFFF),
                           flags=flags)
