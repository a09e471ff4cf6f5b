"""Trajectory generation: the smoothed reference keeps the plan's times and stays within
`max_deviation` of the plan's linear interpolation at every instant (000 §VI-C)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.bus.messages import PlanStep
from common.domain.vehicle_model import VehicleModel
from common.flight.modes import Mode
from common.flight.reference import wrap_angle
from services.executor.trajectory import Trajectory, TrajectoryParams
from tests.support.closed_loop import reference_steps

pytestmark = pytest.mark.compute

MODEL = VehicleModel()
STEPS = reference_steps(MODEL)


def _pos(s) -> tuple[float, float, float]:
    return (s.x, s.y, s.z)


def test_reference_stays_within_the_deviation_bound_of_the_plan() -> None:
    traj = Trajectory(STEPS)
    worst = max(math.dist(_pos(s), traj.plan_position(s.t)) for s in traj.samples(0.002, lead=1, tail=1))
    assert worst <= traj.params.max_deviation + 1e-9
    assert traj.deviation_bound() <= traj.params.max_deviation + 1e-9
    assert worst > 0.5 * traj.params.max_deviation  # the corners really are smoothed


def test_plan_positions_are_plan_position_at_each_time_at_once() -> None:
    """(The proximity stop's bend reads a mover's plan so, `VehicleController.bend`.)"""
    traj = Trajectory(STEPS)
    ts = [traj.start_time - 1.0, *(s.t for s in STEPS), *(0.37 * k for k in range(120)), traj.end_time + 1.0]
    at_once = traj.plan_positions(np.array(ts))
    assert at_once.shape == (len(ts), 3)
    for t, p in zip(ts, at_once, strict=True):
        assert p == pytest.approx(traj.plan_position(t), abs=1e-12), t


def test_every_node_is_within_the_bound_at_its_time_and_on_schedule_after_the_blend() -> None:
    traj = Trajectory(STEPS)
    for i, step in enumerate(STEPS):
        assert math.dist(_pos(traj.sample(step.t)), step.pos) <= traj.params.max_deviation + 1e-9
        after = step.t + traj.half[i]
        assert math.dist(_pos(traj.sample(after)), traj.plan_position(after)) < 1e-9
        assert traj.half[i] <= traj.params.max_blend


def test_velocity_is_continuous_and_is_the_derivative_of_position() -> None:
    traj = Trajectory(STEPS)
    samples = traj.samples(0.001, lead=0.5, tail=0.5)
    for a, b in zip(samples, samples[1:], strict=False):
        dv = math.dist((a.vx, a.vy, a.vz), (b.vx, b.vy, b.vz))
        assert dv < 0.02, f"velocity jumps by {dv} at t={a.t}"
        mid = ((b.x - a.x) / 0.001, (b.y - a.y) / 0.001, (b.z - a.z) / 0.001)
        assert math.dist(mid, (0.5 * (a.vx + b.vx), 0.5 * (a.vy + b.vy), 0.5 * (a.vz + b.vz))) < 1e-3


def test_rests_before_the_first_and_after_the_last_entry_and_waits_hold_still() -> None:
    traj = Trajectory(STEPS)
    for t, node in ((-5.0, STEPS[0]), (STEPS[-1].t + 10.0, STEPS[-1])):
        s = traj.sample(t)
        assert _pos(s) == pytest.approx(node.pos)
        assert (s.vx, s.vy, s.vz) == (0.0, 0.0, 0.0)
    hover = next(i for i, s in enumerate(STEPS) if s.kind == "air" and STEPS[i - 1].node == s.node)
    mid = traj.sample(0.5 * (STEPS[hover - 1].t + STEPS[hover].t))
    assert _pos(mid) == pytest.approx(STEPS[hover].pos)
    assert math.hypot(mid.vx, mid.vy, mid.vz) == 0.0


def test_planned_modes_follow_edge_kinds_and_wait_places() -> None:
    traj = Trajectory(STEPS)
    modes = [traj.sample(0.5 * (a.t + b.t)).mode for a, b in zip(STEPS, STEPS[1:], strict=False)]
    assert modes == [Mode.PARKED, Mode.DRIVING, Mode.DRIVING, Mode.DRIVING, Mode.DRIVING, Mode.TAKING_OFF,
                     Mode.FLYING, Mode.FLYING, Mode.LANDING, Mode.DRIVING, Mode.DRIVING, Mode.DRIVING]
    assert traj.sample(-1.0).mode == Mode.PARKED
    assert traj.sample(STEPS[-1].t + 1.0).mode == Mode.DONE
    assert traj.segment(STEPS[3].t) == 4  # progress: four entries at or before r2's arrival


def test_yaw_follows_the_road_and_touches_down_facing_the_next_road() -> None:
    traj = Trajectory(STEPS, yaw0=0.0)
    on_road = traj.sample(0.5 * (STEPS[2].t + STEPS[3].t))  # r1 -> r2 along +x
    assert on_road.yaw == pytest.approx(0.0, abs=1e-9)
    landing_end = next(s for s in STEPS if s.edge == "land").t
    after_landing = next(b for a, b in zip(STEPS, STEPS[1:], strict=False) if a.t == landing_end)
    heading = math.atan2(after_landing.pos[1] - STEPS[9].pos[1], after_landing.pos[0] - STEPS[9].pos[0])
    assert wrap_angle(traj.sample(landing_end - 0.05).yaw - heading) == pytest.approx(0.0, abs=1e-9)
    takeoff_start = STEPS[5].t
    ramp = traj.sample(takeoff_start + 0.5)
    assert abs(ramp.yaw_rate) == pytest.approx(traj.params.yaw_rate)


def test_zero_duration_traversal_and_time_going_back_are_refused() -> None:
    a = PlanStep(node="a", t=0.0, pos=(0.0, 0.0, 0.0), kind="parking")
    with pytest.raises(ValueError, match="same time"):
        Trajectory([a, PlanStep(node="b", t=0.0, pos=(1.0, 0.0, 0.0), kind="waypoint", edge="drive")])
    with pytest.raises(ValueError, match="back in time"):
        Trajectory([PlanStep(node="a", t=1.0, pos=(0.0, 0.0, 0.0), kind="parking"),
                    PlanStep(node="b", t=0.5, pos=(1.0, 0.0, 0.0), kind="waypoint", edge="drive")])
    # a repeated entry (same node, same time) is a zero-length wait, dropped
    assert len(Trajectory([a, a]).steps) == 1


def test_samples_are_closely_spaced() -> None:
    traj = Trajectory(STEPS)
    samples = traj.samples(0.01)
    assert samples[0].t == pytest.approx(STEPS[0].t)
    assert samples[-1].t == pytest.approx(STEPS[-1].t, abs=0.01)
    assert all(b.t - a.t == pytest.approx(0.01) for a, b in zip(samples, samples[1:], strict=False))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(0.05, 3.0), st.booleans()),
                min_size=2, max_size=8),
       st.floats(0.002, 0.01))
def test_any_path_stays_within_its_bound(legs: list[tuple[float, float, float, bool]], bound: float) -> None:
    steps = [PlanStep(node="n0", t=0.0, pos=(0.0, 0.0, 0.0), kind="waypoint")]
    for i, (x, y, dt, wait) in enumerate(legs, start=1):
        prev = steps[-1]
        if wait:
            steps.append(PlanStep(node=prev.node, t=prev.t + dt, pos=prev.pos, kind=prev.kind))
        else:
            steps.append(PlanStep(node=f"n{i}", t=prev.t + dt, pos=(x, y, 0.0), kind="waypoint", edge="drive"))
    traj = Trajectory(steps, TrajectoryParams(max_deviation=bound))
    worst = max(math.dist(_pos(s), traj.plan_position(s.t)) for s in traj.samples(0.005, lead=0.3, tail=0.3))
    assert worst <= bound + 1e-9
