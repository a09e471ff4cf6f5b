"""The mission's judge of separation in ground truth (`services.mission.separation`): every truth is
judged against the others' latest, so a brush shorter than the mission's look (0.1 s) is seen."""

from __future__ import annotations

import math

import pytest

from common.bus.messages import SimTruth, SimTruthFrame
from common.domain.vehicle_model import VehicleModel
from services.mission.separation import SeparationMonitor

pytestmark = pytest.mark.compute
R, H = VehicleModel().body()
RATE_HZ = 100.0


def crossing(dz: float) -> list[SimTruth]:
    """cf1 parked at the origin; cf2 passing it at 1 m/s along y = 2r - 2 mm, `dz` above it, for a
    second of 100 Hz truths: the bodies overlap (horizontally) for 0.044 s. The two bodies' clocks
    differ by rounding, as the simulator's do."""
    out = []
    for k in range(int(RATE_HZ)):
        t = k / RATE_HZ
        out.append(SimTruth(vid="cf1", t=t, x=0.0, y=0.0, z=0.0, yaw=0.0))
        out.append(SimTruth(vid="cf2", t=t + 1e-12, x=-0.5 + t, y=2 * R - 0.002, z=dz, yaw=0.0, vx=1.0))
    return out


def test_a_brush_shorter_than_a_tenth_of_a_second_is_a_contact() -> None:
    sep = SeparationMonitor(R, H)
    for truth in crossing(0.0):
        sep.update(truth)
    assert sep.contacts and {sep.contacts[0][1], sep.contacts[0][2]} == {"cf1", "cf2"}
    assert len(sep.contacts) == 5  # one per instant in contact (0.48 ... 0.52 s), not one per truth
    assert 0.03 <= max(c[0] for c in sep.contacts) - min(c[0] for c in sep.contacts) <= 0.06  # (0.044 s of overlap)
    assert sep.min_gap == pytest.approx(-0.002, abs=1e-9) and set(sep.min_pair) == {"cf1", "cf2"}


def test_frames_of_every_body_are_judged_as_their_truths() -> None:
    """A simulator's `sim/truths` frames (every body of one instant) give the judgement its
    truths one by one give."""
    by_truth, by_frame = SeparationMonitor(R, H), SeparationMonitor(R, H)
    truths = crossing(0.0)
    for truth in truths:
        by_truth.update(truth)
    for k in range(0, len(truths), 2):
        by_frame.update_frame(SimTruthFrame(t=truths[k].t, truths=truths[k:k + 2]))
    assert by_frame.contacts == by_truth.contacts and len(by_frame.contacts) == 5
    assert (by_frame.min_gap, by_frame.min_pair) == (by_truth.min_gap, by_truth.min_pair)


def test_bodies_apart_in_height_or_far_apart_do_not_touch() -> None:
    sep = SeparationMonitor(R, H)
    for truth in crossing(H + 0.001):  # one passing just over the other
        sep.update(truth)
    assert not sep.contacts and math.isinf(sep.min_gap)
    far = SeparationMonitor(R, H)
    far.update(SimTruth(vid="cf1", t=0.0, x=0.0, y=0.0, z=0.0, yaw=0.0))
    far.update(SimTruth(vid="cf2", t=0.0, x=2.0, y=0.0, z=0.0, yaw=0.0))
    far.update(SimTruth(vid="cf1", t=0.01, x=0.0, y=0.0, z=0.0, yaw=0.0))  # judged at the next instant
    assert not far.contacts and math.isinf(far.min_gap)  # beyond NEAR_M: "none closer than 1 m"
    far.update(SimTruth(vid="cf3", t=0.01, x=2.0, y=0.5, z=0.0, yaw=0.0))
    far.update(SimTruth(vid="cf1", t=0.02, x=0.0, y=0.0, z=0.0, yaw=0.0))  # the next instant: the last judged
    assert far.min_gap == pytest.approx(0.5 - 2 * R) and set(far.min_pair) == {"cf2", "cf3"}
