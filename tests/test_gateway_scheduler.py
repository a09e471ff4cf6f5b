"""The gateway's packet schedule and per-vehicle rules, on a simulated clock (no I/O): the budget is
shared equally between flying vehicles, wheel commands are serialised at the switch's rate, stale
commands become landings or stops, stops and the thrust unlock go out as the firmware needs."""

from __future__ import annotations

from collections import Counter

import pytest

from common.bus.messages import FlightSetpoint, StopSetpoint, WheelSetpoint
from common.crazyflie import crtp
from common.deploy.radios import GatewayParams
from services.radio_gateway.linkstats import LinkStats
from services.radio_gateway.scheduler import Scheduler
from services.radio_gateway.vehicle import Drive, VehicleChannel

HOVER = FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=48000)
TICK = 0.01


def _radio(flyers: int, drivers: int, budget: float = 500.0, params: GatewayParams | None = None):
    params = params or GatewayParams()
    chans = [VehicleChannel(f"f{i}", params, 0.0) for i in range(flyers)]
    chans += [VehicleChannel(f"d{i}", params, 0.0) for i in range(drivers)]
    return chans, Scheduler(chans, budget, params, 0.0)


def _run(chans, sched, seconds: float, command=None, t0: float = 0.0, answered=None):
    """Tick for `seconds`; `command(ch, now)` gives each channel's setpoint (None: silent) every tick;
    a status request sent at `now` is answered (everything received) if `answered(now)`."""
    sent: dict[str, list[tuple[float, object]]] = {ch.vid: [] for ch in chans}
    events = []
    now = t0
    while now < t0 + seconds - 1e-9:
        now += TICK
        for ch in chans:
            sp = command(ch, now) if command else None
            if sp is not None:
                ch.command(sp, now)
            events += [(ch.vid, e) for e in ch.supervise(now)]
        batch, caused = sched.tick(now)
        events += caused
        for vid, raw in batch:
            packet = crtp.decode_uplink(raw)
            sent[vid].append((now, packet))
            if isinstance(packet, crtp.StatusRequest) and answered and answered(now):
                ch = sched._by_vid[vid]
                events += [(vid, e) for e in ch.on_status(_status(ch, 0, echo=packet.sent), now + TICK / 2)]
    return sent, events


def _kinds(packets) -> Counter:
    return Counter(type(p).__name__ for _t, p in packets)


def test_four_flyers_and_two_drivers_fit_the_default_budget() -> None:
    chans, sched = _radio(4, 2)

    def command(ch, now):
        return HOVER if ch.vid.startswith("f") else WheelSetpoint(left=0.05, right=0.05)

    sent, events = _run(chans, sched, 2.0, command)
    for i in range(4):
        packets = sent[f"f{i}"]
        flights = [p for _t, p in packets if isinstance(p, FlightSetpoint)]
        assert flights[0].thrust == 0 and flights[1] == HOVER  # the firmware's thrust lock is opened first
        assert _kinds(packets)["FlightSetpoint"] >= 195  # 100 Hz
        assert 9 <= _kinds(packets)["StatusRequest"] <= 11  # 5 Hz
        assert max(b[0] - a[0] for a, b in zip(packets, packets[1:], strict=False)) <= TICK + 1e-9
    for i in range(2):
        assert 19 <= _kinds(sent[f"d{i}"])["Wheels"] <= 21  # unchanged: refreshed every 0.1 s
    assert sched.flight_skipped == 0
    assert events == []


def test_an_overloaded_radio_shares_its_budget_equally() -> None:
    chans, sched = _radio(12, 0)
    sent, _ = _run(chans, sched, 2.0, lambda ch, now: HOVER)
    flights = [_kinds(sent[ch.vid])["FlightSetpoint"] for ch in chans]
    total = sum(len(p) for p in sent.values())
    assert total <= 500 * 2.0 + 10  # never above the budget (plus the bucket's two ticks)
    assert min(flights) >= (500 - 12 * 5) * 2.0 / 12 - 2  # ~36 Hz each
    assert max(flights) - min(flights) <= 2
    assert sched.flight_skipped > 0


def test_the_driving_switch_serialises_wheel_commands_at_its_rate() -> None:
    chans, sched = _radio(0, 10)
    sent, _ = _run(chans, sched, 2.0, lambda ch, now: WheelSetpoint(left=now, right=-now))  # always changing
    wheels = [_kinds(sent[ch.vid])["Wheels"] for ch in chans]
    assert sum(wheels) <= 50 * 2.0 + 1
    assert min(wheels) >= 9 and max(wheels) - min(wheels) <= 1
    by_tick = Counter(t for ch in chans for t, p in sent[ch.vid] if isinstance(p, crtp.Wheels))
    assert max(by_tick.values()) == 1  # one wheel packet at a time


def test_stale_commands_land_a_flyer_and_stop_a_driver() -> None:
    chans, sched = _radio(1, 1)
    flyer, driver = chans

    def command(ch, now):
        if now > 0.5:
            return None  # the executor goes silent
        return HOVER if ch is flyer else WheelSetpoint(left=0.1, right=0.1)

    sent, events = _run(chans, sched, 1.0, command)
    kinds = [e[1][0] for e in events]
    assert kinds == ["stale_cmd_landing", "stale_cmd_stop"] or kinds == ["stale_cmd_stop", "stale_cmd_landing"]
    assert flyer.mode == Drive.LANDING and flyer.took_over
    times = [t for t, p in sent[flyer.vid] if isinstance(p, FlightSetpoint)]
    assert times[-1] > 0.99 and max(b - a for a, b in zip(times, times[1:], strict=False)) <= TICK + 1e-9
    after = [p for t, p in sent[driver.vid] if t > 0.6]
    assert crtp.Wheels(0, 0) in after and sum(isinstance(p, crtp.Stop) for p in after) == 3
    assert driver.mode == Drive.IDLE and driver.took_over
    flyer.command(HOVER, 1.0)  # a fresh command takes back over
    assert flyer.mode == Drive.FLIGHT and not flyer.took_over


def test_a_stop_goes_out_three_times_with_zero_wheels_then_only_status() -> None:
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _run(chans, sched, 0.3, lambda c, now: HOVER)
    sent, _ = _run(chans, sched, 1.0, lambda c, now: StopSetpoint(), t0=0.3)
    kinds = _kinds(sent[ch.vid])
    assert kinds["Stop"] == 3 and kinds["Wheels"] == 3 and kinds["FlightSetpoint"] == 0
    assert ch.mode == Drive.IDLE and not ch.wants_flight_slot


def test_link_stats_from_status_replies() -> None:
    stats = LinkStats(started=0.0, timeout_s=1.0, lost_after=2)
    assert not stats.reporting(0.5) and stats.reporting(1.1)  # silent past the timeout: report it lost
    assert stats.on_status(crtp.Status(100, 90, 80, 3900, 0, 0, 0), 1.0) == [("link_up", "status after 0 packets sent")]
    events = stats.on_status(crtp.Status(200, 185, 170, 3890, 0, 0, crtp.FLAG_WATCHDOG_LEVEL), 1.5)
    assert [e[0] for e in events] == ["firmware_watchdog"]
    assert (stats.acked, stats.dropped, stats.vbat) == (185, 15, 3.89)
    assert stats.cmd_rate_hz == pytest.approx(180.0) and stats.link_quality == pytest.approx(0.95)
    assert stats.on_status(crtp.Status(150, 140, 130, 3900, 0, 0, 0), 1.6) == []  # older than the last
    assert stats.on_status(crtp.Status(300, 301, 0, 3900, 0, 0, 0), 1.6) == []  # impossible
    assert stats.stale_replies == 2 and stats.dropped == 15
    stats.sent = 200
    stats.request(1.6)
    assert stats.check(2.6) == []  # silent for 1.1 s, but only one request unanswered
    stats.request(2.55)
    assert stats.check(2.6) == []  # the second one could still be answered
    assert [e[0] for e in stats.check(2.7)] == ["link_lost"] and stats.check(3.0) == []
    assert stats.link_quality == 0.0


def test_a_silent_vehicle_is_probed_and_its_link_judged_lost_after_a_second() -> None:
    chans, sched = _radio(1, 0)
    (ch,) = chans
    sent, events = _run(chans, sched, 1.75, answered=lambda now: now < 1.0)
    assert [e[1][0] for e in events] == ["link_up"] and ch.stats.link_ok  # < 1 s since the last reply
    later, lost = _run(chans, sched, 1.5, answered=lambda now: False, t0=1.75)
    assert [e[1][0] for e in lost] == ["link_lost"] and not ch.stats.link_ok
    requests = [t for t, p in sent[ch.vid] + later[ch.vid] if isinstance(p, crtp.StatusRequest)]
    last_reply = max(t for t in requests if t < 1.0)
    assert last_reply > 0.75
    silent = [t for t in requests if last_reply < t <= last_reply + 1.0]
    assert len(silent) >= GatewayParams().lost_after_requests + 1  # probed at 20 Hz, not 5 Hz
    judged = [t for t in requests if t > last_reply + 1.2]
    assert len(judged) <= 5 * (3.25 - last_reply - 1.2) + 1  # lost: back to 5 Hz


def test_a_stalled_gateway_does_not_take_its_stall_for_a_lost_link() -> None:
    """The process slept 1.5 s (a loaded machine): no requests went out, so no replies are missing."""
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _, events = _run(chans, sched, 1.0, answered=lambda now: True)
    _, after = _run(chans, sched, 0.5, answered=lambda now: True, t0=2.5)
    assert [e[1][0] for e in events + after] == ["link_up"] and ch.stats.link_ok


def test_a_stop_followed_at_once_by_driving_still_stops_the_motors() -> None:
    """The executor's touchdown: StopSetpoint, then wheel commands from the next tick on."""
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _run(chans, sched, 0.3, lambda c, now: HOVER)
    sent, _ = _run(chans, sched, 0.5, lambda c, now: StopSetpoint() if now < 0.315 else WheelSetpoint(left=0.1, right=0.1),
                   t0=0.3)
    kinds = _kinds(sent[ch.vid])
    assert kinds["Stop"] == 3 and kinds["FlightSetpoint"] == 0 and kinds["Wheels"] >= 5
    assert ch.mode == Drive.DRIVE and not ch.wants_flight_slot


def _status(ch: VehicleChannel, flags: int, echo: int | None = None) -> crtp.Status:
    """A reply to request `echo` (default: one sent now), everything received."""
    sent = ch.stats.sent + 1 if echo is None else echo
    return crtp.Status(echo_sent=sent, received=sent, setpoints=0, vbat_mv=3900, wheel_left_mm_s=0,
                       wheel_right_mm_s=0, flags=flags)


def test_motors_reported_running_after_the_stops_were_lost_are_stopped_again() -> None:
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _run(chans, sched, 0.3, lambda c, now: HOVER)
    _run(chans, sched, 0.2, lambda c, now: StopSetpoint() if now < 0.32 else WheelSetpoint(left=0.05, right=0.05),
         t0=0.3)  # the stops went out (and were lost): driving now
    assert ch.mode == Drive.DRIVE and not ch.wants_flight_slot
    assert [e[0] for e in ch.on_status(_status(ch, crtp.FLAG_MOTORS), 0.5)] == ["link_up", "motors_restopped"]
    sent, _ = _run(chans, sched, 0.1, lambda c, now: WheelSetpoint(left=0.05, right=0.05), t0=0.5)
    assert _kinds(sent[ch.vid])["Stop"] == 3 and ch.mode == Drive.DRIVE
    assert ch.on_status(_status(ch, 0), 0.6) == [] and not ch.wants_flight_slot  # stopped: nothing more
    _run(chans, sched, 0.1, lambda c, now: HOVER, t0=0.6)
    assert ch.on_status(_status(ch, crtp.FLAG_MOTORS), 0.7) == [] and ch.mode == Drive.FLIGHT  # flying: its own


def test_a_driver_taking_off_gets_its_wheels_zeroed_repeatedly() -> None:
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _run(chans, sched, 0.3, lambda c, now: WheelSetpoint(left=0.1, right=0.1))
    sent, _ = _run(chans, sched, 0.3, lambda c, now: HOVER, t0=0.3)
    wheels = [p for _t, p in sent[ch.vid] if isinstance(p, crtp.Wheels)]
    assert len(wheels) == 3 and all(w.left_mm_s == 0 and w.right_mm_s == 0 for w in wheels)
    assert ch.mode == Drive.FLIGHT
