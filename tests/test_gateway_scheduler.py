"""The gateway's packet schedule and per-vehicle rules, on a simulated clock (no I/O): the budget is
shared equally between flying vehicles, wheel commands are serialised at the switch's rate, stale
commands become landings or stops, stops, the thrust unlock, the settling after a flight (stops
while the supervisor says flying, then notify-setpoint-stop), arming and crash-recovery requests
and the emergency stop go out as the firmware needs; link health from the firmware's log blocks."""

from __future__ import annotations

from collections import Counter

import pytest

from common.bus.messages import FlightSetpoint, StopSetpoint, WheelSetpoint
from common.crazyflie import crtp
from common.deploy.radios import GatewayParams
from services.radio_gateway.health import LinkHealth
from services.radio_gateway.scheduler import Scheduler
from services.radio_gateway.vehicle import Drive, VehicleChannel
from tests.support.gateway_packets import Notify, Null, Supervisor, decode

HOVER = FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=48000)
TICK = 0.01
FLYING_INFO, LANDED_INFO = 0x021E, 0x020E  # supervisor.info: can fly, armed, auto-arm (+ flying)


def _radio(flyers: int, drivers: int, budget: float = 500.0, params: GatewayParams | None = None):
    params = params or GatewayParams()
    chans = [VehicleChannel(f"f{i}", params, 0.0) for i in range(flyers)]
    chans += [VehicleChannel(f"d{i}", params, 0.0) for i in range(drivers)]
    return chans, Scheduler(chans, budget, params, 0.0)


def _run(chans, sched, seconds: float, command=None, t0: float = 0.0, answered=None, info=None):
    """Tick for `seconds`; `command(ch, now)` gives each channel's setpoint (None: silent) every tick;
    a status request sent at `now` is answered (everything received) if `answered(now)`; a log block
    with `supervisor.info = info(now)` arrives every 0.1 s unless that is None."""
    sent: dict[str, list[tuple[float, object]]] = {ch.vid: [] for ch in chans}
    events = []
    now = t0
    while now < t0 + seconds - 1e-9:
        now += TICK
        for ch in chans:
            sp = command(ch, now) if command else None
            if sp is not None:
                ch.command(sp, now)
            bits = info(now) if info else None
            if bits is not None and round(now / TICK) % 10 == 0:
                events += [(ch.vid, e) for e in ch.health.on_log({"pm.vbatMV": 3900, "supervisor.info": bits}, now)]
            events += [(ch.vid, e) for e in ch.supervise(now)]
        batch, caused = sched.tick(now)
        events += caused
        for vid, raw in batch:
            packet = decode(raw)
            sent[vid].append((now, packet))
            if isinstance(packet, crtp.StatusRequest) and answered and answered(now):
                ch = sched._by_vid[vid]
                events += [(vid, e) for e in ch.on_status(_status(ch, 0, echo=packet.seq), now + TICK / 2)]
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
        assert [f.thrust for f in flights[:3]] == [0, 0, 0] and flights[3] == HOVER  # the thrust lock opened first
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


def test_a_wheel_app_that_gets_no_requests_on_a_full_radio_is_not_called_silent() -> None:
    chans, sched = _radio(12, 0)  # flight takes every slot: no STATUS request goes out
    _, events = _run(chans, sched, 3.0, lambda ch, now: HOVER, info=lambda now: FLYING_INFO)
    assert "wheel_app_silent" not in [e[1][0] for e in events]


def test_the_driving_switch_serialises_wheel_commands_at_its_rate() -> None:
    chans, sched = _radio(0, 10)
    sent, _ = _run(chans, sched, 2.0, lambda ch, now: WheelSetpoint(left=now, right=-now))  # always changing
    wheels = [_kinds(sent[ch.vid])["Wheels"] for ch in chans]
    rate = GatewayParams().drive_hz
    assert sum(wheels) <= rate * 2.0 + 1
    assert min(wheels) >= rate * 2.0 / 10 - 1 and max(wheels) - min(wheels) <= 1
    by_tick = Counter(t for ch in chans for t, p in sent[ch.vid] if isinstance(p, crtp.Wheels))
    assert max(by_tick.values()) == 1  # one wheel packet at a time


def test_a_stop_goes_ahead_of_the_driving_switch_queue() -> None:
    """Ten drivers whose commands change every tick fill the switch (each gets a wheel packet every
    tenth tick); the one told to stop gets its zero out in the tick it was told, ahead of the queue
    and beyond the switch's rate, and its repeats go on through the queue."""
    chans, sched = _radio(0, 10)
    before, _ = _run(chans, sched, 1.0, lambda ch, now: WheelSetpoint(left=now, right=-now))
    stop_at = max(t for t, p in before["d3"] if isinstance(p, crtp.Wheels)) + 2 * TICK  # its turn 8 ticks away
    def command(ch, now):
        if ch.vid == "d3" and now >= stop_at - 1e-9:
            return StopSetpoint()
        return WheelSetpoint(left=now, right=-now)
    sent, _ = _run(chans, sched, 0.5, command, t0=1.0)
    zeros = [t for t, p in sent["d3"] if isinstance(p, crtp.Wheels) and p.left_mm_s == 0 and p.right_mm_s == 0]
    assert zeros and zeros[0] == pytest.approx(stop_at), zeros
    assert len(zeros) == GatewayParams().stop_repeats
    by_tick = Counter(t for ch in chans for t, p in sent[ch.vid] if isinstance(p, crtp.Wheels))
    assert by_tick[zeros[0]] == 2  # the stop beside the switch's own packet


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
    resume = GatewayParams().resume_s
    for k in range(round(resume / TICK)):  # fresh commands, short of `resume_s`: the landing goes on
        assert flyer.command(HOVER, 1.0 + k * TICK) == []
    assert flyer.mode == Drive.LANDING and flyer.took_over
    for k in range(round(resume / TICK)):  # after a silence they begin again; once they have come
        flyer.command(HOVER, 1.5 + k * TICK)  # for `resume_s`, the owner has the vehicle back
    assert flyer.command(HOVER, 1.5 + resume) == [("cmd_resumed", "fresh flight command during the safety landing")]
    assert flyer.mode == Drive.FLIGHT and not flyer.took_over


def test_after_a_flight_stops_go_out_while_the_supervisor_says_flying_then_notify_setpoint_stop() -> None:
    """Firmware 2023.06+: a stop followed by silence while the supervisor still believes the vehicle
    flies (2 s after its motors stopped) locks it; the gateway keeps it fed, then hands over."""
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _run(chans, sched, 0.3, lambda c, now: HOVER, info=lambda now: FLYING_INFO)
    sent, _ = _run(chans, sched, 3.0, lambda c, now: StopSetpoint(), t0=0.3,
                   info=lambda now: FLYING_INFO if now < 2.4 else LANDED_INFO)
    packets = sent[ch.vid]
    stops = [t for t, p in packets if isinstance(p, crtp.Stop)]
    notifies = [t for t, p in packets if isinstance(p, Notify)]
    assert len(notifies) == 3 and min(notifies) > 2.4  # once the supervisor reports it landed
    assert max(b - a for a, b in zip(stops, stops[1:], strict=False)) <= 0.1 + TICK  # never 0.5 s silent
    assert max(stops) < min(notifies) and len([p for _t, p in packets if isinstance(p, crtp.Wheels)]) == 3
    assert ch.mode == Drive.IDLE and not ch.wants_flight_slot
    assert not any(isinstance(p, FlightSetpoint) for _t, p in packets)


def test_settling_continues_while_the_car_drives_off_and_ends_after_a_bound_without_supervisor_news() -> None:
    params = GatewayParams()
    chans, sched = _radio(1, 0, params=params)
    (ch,) = chans
    _run(chans, sched, 0.3, lambda c, now: HOVER)
    sent, _ = _run(chans, sched, 4.0, lambda c, now: StopSetpoint() if now < 0.315 else WheelSetpoint(left=0.1, right=0.1),
                   t0=0.3)  # no log block: the supervisor's state is unknown
    packets = sent[ch.vid]
    notifies = [t for t, p in packets if isinstance(p, Notify)]
    assert len(notifies) == 3 and params.settle_max_s < min(notifies) - 0.3 < params.settle_max_s + 0.2
    assert _kinds(packets)["Wheels"] > 30 and ch.mode == Drive.DRIVE and not ch.wants_flight_slot


def test_link_health_from_log_blocks_and_wheel_app_replies() -> None:
    health = LinkHealth(started=0.0, timeout_s=1.0, period_s=0.1)
    assert not health.reporting(0.5) and health.reporting(1.1)  # silent past the timeout: report it lost
    assert [e[0] for e in health.on_log({"pm.vbatMV": 3900, "supervisor.info": 0x020E}, 1.0)] == ["link_up"]
    for i in range(1, 10):
        health.on_log({"pm.vbatMV": 3890, "supervisor.info": 0x020E}, 1.0 + 0.1 * i)
    assert health.vbat == 3.89 and health.link_quality == 1.0 and health.supervisor == 0x020E
    assert [e[0] for e in health.on_log({"supervisor.info": 0x0044}, 2.0)] == ["vehicle_locked"]
    health.on_log({"supervisor.info": 0x0044}, 2.3)  # 2.1 and 2.2 lost
    assert 0.8 < health.link_quality < 0.9
    status = crtp.Status(echo_seq=100, received=95, uptime_ms=5000, rejected=0, vbat_mv=3900, wheel_left_mm_s=0,
                         wheel_right_mm_s=0, setpoint_age_ms=12, flags=crtp.FLAG_WHEEL_WATCHDOG)
    assert [e[0] for e in health.on_status(status, 2.4)] == ["wheel_watchdog"]
    assert health.app_lost == 5 and health.setpoint_age_ms == 12
    assert health.on_status(crtp.Status(90, 80, 5000, 0, 3900, 0, 0, 0, 0), 2.5) == []  # older than the last
    assert health.on_status(crtp.Status(200, 201, 5000, 0, 3900, 0, 0, 0, 0), 2.5) == []  # impossible
    assert health.stale_replies == 2
    assert health.check(3.2) == []  # 0.9 s since the last block
    assert [e[0] for e in health.check(3.4)] == ["link_lost"] and health.check(3.5) == []
    assert health.link_quality == 0.0


def test_a_silent_vehicle_is_judged_lost_a_second_after_its_last_log_block() -> None:
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _, events = _run(chans, sched, 1.5, info=lambda now: 0x020E if now < 1.0 else None)
    assert [e[1][0] for e in events] == ["link_up"] and ch.health.link_ok  # < 1 s since the last block
    _, lost = _run(chans, sched, 1.0, t0=1.5)
    assert [e[1][0] for e in lost] == ["link_lost"] and not ch.health.link_ok


def test_a_stalled_gateway_does_not_take_its_stall_for_a_lost_link() -> None:
    """The process slept 1.5 s (a loaded machine): the gateway excuses the silence it could not see."""
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _, events = _run(chans, sched, 1.0, info=lambda now: 0x020E)
    ch.health.excuse(2.5)
    _, after = _run(chans, sched, 0.5, info=lambda now: 0x020E, t0=2.5)
    assert [e[1][0] for e in events + after] == ["link_up"] and ch.health.link_ok


def test_a_flying_car_whose_wheel_app_never_answers_is_reported_once_and_again_when_it_answers() -> None:
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _, events = _run(chans, sched, 3.0, info=lambda now: 0x020E)  # log blocks, no STATUS replies
    assert [e[1][0] for e in events] == ["link_up", "wheel_app_silent"] and ch.health.app_ok is False
    _, events = _run(chans, sched, 1.0, info=lambda now: 0x020E, answered=lambda now: True, t0=3.0)
    assert [e[1][0] for e in events] == ["wheel_app_up"] and ch.health.app_ok
    drone = VehicleChannel("drone", GatewayParams(), 0.0, wheels=False)
    _, events = _run([drone], Scheduler([drone], 500.0, GatewayParams(), 0.0), 3.0, info=lambda now: 0x020E)
    assert [e[1][0] for e in events] == ["link_up"]  # no wheels, no app to miss


def test_flight_setpoints_go_before_status_requests_and_only_flying_cars_are_asked_for_status() -> None:
    params = GatewayParams()
    chans = [VehicleChannel("car", params, 0.0), VehicleChannel("drone", params, 0.0, wheels=False)]
    sched = Scheduler(chans, 100.0, params, 0.0)  # one packet per tick: every flight slot is contested
    sent, _ = _run(chans, sched, 2.0, lambda c, now: HOVER)
    for vid in ("car", "drone"):
        assert _kinds(sent[vid])["FlightSetpoint"] >= 95  # ~50 Hz each: the budget's share, no less
    assert _kinds(sent["drone"])["StatusRequest"] == 0


def test_a_stock_vehicle_with_nothing_to_send_gets_null_packets_to_keep_its_link_active() -> None:
    """The firmware resets its log blocks after a second without any radio packet
    (`CONFIG_RADIO_ACTIVITY_TIMEOUT_MS`); a parked stock Crazyflie gets no setpoints and has no wheel
    app to ask for a status, so the schedule sends it a null packet at the status rate."""
    params = GatewayParams()
    drone = VehicleChannel("drone", params, 0.0, wheels=False)
    sent, _ = _run([drone], Scheduler([drone], 500.0, params, 0.0), 2.0)
    nulls = [t for t, p in sent["drone"] if isinstance(p, Null)]
    assert len(nulls) == pytest.approx(2.0 * params.status_hz, abs=1)
    assert max(b - a for a, b in zip([0.0, *nulls], nulls, strict=False)) <= 1.0 / params.status_hz + 0.02


def test_arming_and_crash_recovery_requests_follow_the_supervisor() -> None:
    chans, sched = _radio(1, 0)
    (ch,) = chans
    brushless_disarmed = 0x0201  # can arm, not armed, no auto-arm
    sent, events = _run(chans, sched, 1.0, lambda c, now: HOVER, info=lambda now: brushless_disarmed)
    arms = [t for t, p in sent[ch.vid] if p == Supervisor(1)]
    assert 2 <= len(arms) <= 3 and "arming" in [e[1][0] for e in events]  # repeated every 0.5 s
    chans, sched = _radio(1, 0)
    (ch,) = chans
    sent, _ = _run(chans, sched, 0.6, info=lambda now: 0x0280)  # crashed, not tumbled
    assert Supervisor(2) in [p for _t, p in sent[ch.vid]]
    sent, _ = _run(chans, sched, 0.6, info=lambda now: 0x02A0, t0=0.6)  # crashed and still tumbled
    assert Supervisor(2) not in [p for _t, p in sent[ch.vid]]


def test_an_emergency_stop_goes_first_repeatedly_and_refuses_commands() -> None:
    chans, sched = _radio(3, 0, budget=200.0)
    _run(chans, sched, 0.3, lambda c, now: HOVER)
    for ch in chans:
        ch.emergency_stop()
    locked = 0x0240  # supervisor.info: Locked
    sent, _ = _run(chans, sched, 1.0, info=lambda now: locked if now > 0.35 else FLYING_INFO, t0=0.3)
    for ch in chans:
        packets = [p for _t, p in sent[ch.vid]]
        assert packets[0] == Supervisor(3) and packets.count(Supervisor(3)) == GatewayParams().estop_repeats
        assert not any(isinstance(p, FlightSetpoint) for p in packets)
        with pytest.raises(ValueError, match="emergency stop"):
            ch.command(HOVER, 1.3)


def test_an_emergency_stop_is_sent_again_until_the_supervisor_locks_and_after_a_reconnect() -> None:
    chans, sched = _radio(1, 0)
    (ch,) = chans
    ch.emergency_stop()
    sent, _ = _run(chans, sched, 1.0, info=lambda now: FLYING_INFO)  # the stops were lost: still flying
    stops = [t for t, p in sent[ch.vid] if p == Supervisor(3)]
    assert len(stops) == GatewayParams().estop_repeats + 4  # then one every 0.2 s
    ch.connected(was_flying=True)  # the link came back
    sent, _ = _run(chans, sched, 0.5, info=lambda now: 0x0240, t0=1.0)
    assert [p for _t, p in sent[ch.vid]].count(Supervisor(3)) == GatewayParams().estop_repeats


def test_a_drive_only_car_refuses_flight_setpoints() -> None:
    ch = VehicleChannel("car", GatewayParams(), 0.0, flies=False)
    with pytest.raises(ValueError, match="does not fly"):
        ch.command(HOVER, 0.0)
    ch.command(WheelSetpoint(left=0.1, right=0.1), 0.0)


def test_a_stop_followed_at_once_by_driving_still_stops_the_motors() -> None:
    """The executor's touchdown: StopSetpoint, then wheel commands from the next tick on."""
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _run(chans, sched, 0.3, lambda c, now: HOVER)
    sent, _ = _run(chans, sched, 0.5, lambda c, now: StopSetpoint() if now < 0.315 else WheelSetpoint(left=0.1, right=0.1),
                   t0=0.3, info=lambda now: LANDED_INFO)
    packets = sent[ch.vid]
    assert [p for _t, p in packets if isinstance(p, crtp.Stop | FlightSetpoint)][:3] == [crtp.Stop()] * 3
    assert _kinds(packets)["FlightSetpoint"] == 0 and _kinds(packets)["Wheels"] >= 5
    assert ch.mode == Drive.DRIVE and not ch.wants_flight_slot  # landed: settled, handed over


def _status(ch: VehicleChannel, flags: int, echo: int | None = None) -> crtp.Status:
    """A reply to request `echo` (default: one sent now), everything received."""
    seq = ch.health.app_seq + 1 if echo is None else echo
    return crtp.Status(echo_seq=seq, received=seq, uptime_ms=1000, rejected=0, vbat_mv=3900, wheel_left_mm_s=0,
                       wheel_right_mm_s=0, setpoint_age_ms=5, flags=flags)


def test_motors_reported_running_after_the_stops_were_lost_are_stopped_again() -> None:
    chans, sched = _radio(1, 0)
    (ch,) = chans
    _run(chans, sched, 0.3, lambda c, now: HOVER)
    _run(chans, sched, 0.2, lambda c, now: StopSetpoint() if now < 0.32 else WheelSetpoint(left=0.05, right=0.05),
         t0=0.3, info=lambda now: LANDED_INFO)  # the stops went out (and were lost): driving now
    assert ch.mode == Drive.DRIVE and not ch.wants_flight_slot
    assert [e[0] for e in ch.on_status(_status(ch, crtp.FLAG_MOTORS), 0.5)] == ["motors_restopped"]
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
