"""Mode state machine: the transition table is the only way between modes, and a transition outside
it is refused and logged, never raised (000 §VI-C)."""

from __future__ import annotations

import itertools
import logging

import pytest

from common.flight.modes import AIRBORNE, GROUNDED, TRANSITIONS, Mode, ModeMachine, segment_mode


def test_every_mode_has_a_row_and_no_self_loops() -> None:
    assert set(TRANSITIONS) == set(Mode)
    assert all(mode not in targets for mode, targets in TRANSITIONS.items())


def test_ground_and_air_meet_only_through_takeoff_and_landings() -> None:
    for src, targets in TRANSITIONS.items():
        for dst in targets:
            if src in GROUNDED and dst in AIRBORNE:
                assert dst == Mode.TAKING_OFF, f"{src} -> {dst}"
            if src in AIRBORNE and dst in GROUNDED:
                assert src in (Mode.LANDING, Mode.EMERGENCY_LANDING), f"{src} -> {dst}"


def test_done_is_left_only_for_a_new_plan_and_emergencies_end_on_the_ground() -> None:
    """An emergency descent ends done, or held where it came down (in its take-off or landing's
    column: the mission may bring it back)."""
    assert TRANSITIONS[Mode.DONE] == {Mode.PARKED}
    assert TRANSITIONS[Mode.EMERGENCY_LANDING] == {Mode.DONE, Mode.HOLDING}
    for mode in AIRBORNE - {Mode.EMERGENCY_LANDING}:
        assert Mode.EMERGENCY_LANDING in TRANSITIONS[mode]


@pytest.mark.parametrize(("src", "dst"), list(itertools.product(Mode, Mode)))
def test_request_obeys_the_table(src: Mode, dst: Mode) -> None:
    machine = ModeMachine("cf1", initial=src)
    allowed = dst == src or dst in TRANSITIONS[src]
    assert machine.request(dst, 1.0, "test") is allowed
    assert machine.mode == (dst if allowed else src)
    assert machine.refused == (0 if allowed else 1)
    assert len(machine.history) == (1 if allowed and dst != src else 0)


def test_refused_transition_is_logged_once_per_target_until_the_mode_changes(caplog) -> None:
    machine = ModeMachine("cf7")
    with caplog.at_level(logging.WARNING, logger="common.flight.modes"):
        for _ in range(5):
            assert not machine.request(Mode.FLYING, 0.0, "plan")
        assert machine.refused == 5
        assert len(caplog.records) == 1
        assert "cf7" in caplog.text and "parked -> flying" in caplog.text
        assert machine.request(Mode.DRIVING, 1.0, "plan")
        assert not machine.request(Mode.FLYING, 2.0, "plan")
        assert len(caplog.records) == 2


def test_history_and_sequence() -> None:
    machine = ModeMachine("cf1")
    for mode in (Mode.DRIVING, Mode.TAKING_OFF, Mode.FLYING, Mode.LANDING, Mode.DRIVING, Mode.DONE):
        assert machine.request(mode, 0.0, "plan")
    assert machine.sequence() == [Mode.PARKED, Mode.DRIVING, Mode.TAKING_OFF, Mode.FLYING, Mode.LANDING,
                                  Mode.DRIVING, Mode.DONE]
    assert [tr.dst for tr in machine.history][-1] == Mode.DONE
    assert not machine.airborne


@pytest.mark.parametrize(("edge", "kind", "prev", "expected"), [
    ("drive", "waypoint", Mode.PARKED, Mode.DRIVING),
    ("takeoff", "air", Mode.DRIVING, Mode.TAKING_OFF),
    ("fly", "air", Mode.TAKING_OFF, Mode.FLYING),
    ("land", "land", Mode.FLYING, Mode.LANDING),
    ("", "air", Mode.FLYING, Mode.FLYING),  # hover
    ("", "parking", Mode.DRIVING, Mode.PARKED),  # pulled into a parking spot
    ("", "waypoint", Mode.DRIVING, Mode.DRIVING),  # waiting on the road
    ("", "land", Mode.LANDING, Mode.DRIVING),  # landed, waiting to drive on
    ("", "waypoint", Mode.PARKED, Mode.PARKED),  # not yet started
])
def test_segment_mode(edge: str, kind, prev: Mode, expected: Mode) -> None:
    assert segment_mode(edge, kind, prev) == expected
