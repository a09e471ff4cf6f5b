"""Team plans (002 §IV-E): per-robot controller sequences with sync points, JSON/msgpack encoding,
and one plan executed end to end in simulation (range sensing, landmark and UGV sightings)."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from common.domain import team_plan as tp
from common.errors import InputError
from common.team.env import Env
from common.team.maps import load_env
from common.team.problem import TeamProblem
from common.team.sensing import Sensing
from common.team.team_model import TeamModel
from services.planner.collab.planner import TeamPlanner
from services.sim.team.world import TeamSim

pytestmark = pytest.mark.compute

# demo-room: the drone starts next to the UGV in the room's corner; the goal is over the middle of
# the room, out of IR range of every wall and far from the landmark: only the UGV can guide it there.
PROBLEM = TeamProblem(drone_start=(0, 2, 2), ugv_start=(2, 1, 0), goal=(1, 7, 11))


@pytest.fixture(scope="module")
def planner() -> TeamPlanner:
    return TeamPlanner(load_env("demo-room"))


@pytest.fixture(scope="module", params=["pad", "arastar"])
def plan(planner, request) -> tp.TeamPlan:
    out = planner.plan(PROBLEM, request.param, time_limit=180)  # (a guard: the first solution is returned)
    assert out.plan is not None and out.plan.planner == request.param
    return out.plan


def without_sync(plan: tp.TeamPlan) -> tp.TeamPlan:
    def strip(steps: tuple[tp.Step, ...]) -> tuple[tp.Step, ...]:
        return tuple(msgspec.structs.replace(s, wait_for=0) for s in steps)

    return msgspec.structs.replace(plan, drone=strip(plan.drone), ugv=strip(plan.ugv))


def test_plan_uses_the_ugv_with_sync_points_both_ways(plan):
    dyn = [i for i, s in enumerate(plan.drone) if isinstance(s.action, tp.GoToLandmarkDyn)]
    assert dyn and plan.ugv
    for i in dyn:  # the drone waits for the UGV motions before it ...
        assert plan.drone[i].wait_for >= 1
        # ... and the UGV's next motion waits for this GOTOLANDMARK_DYN
        assert all(s.wait_for >= i + 1 for s in plan.ugv[plan.drone[i].wait_for :])
    assert plan.goal == pytest.approx((5.75, 3.75, 2.0))
    assert sum(s.cost for s in (*plan.drone, *plan.ugv)) == pytest.approx(plan.cost)
    assert 1.0 <= plan.epsilon < math.inf


def test_plan_encodes_to_json_and_msgpack_and_decodes_strictly(plan, tmp_path):
    assert tp.decode_json(tp.encode_json(plan)) == plan
    assert tp.decode_msgpack(tp.encode_msgpack(plan)) == plan
    raw = msgspec.json.decode(tp.encode_json(plan))
    raw["drone"][0]["action"]["speed"] = 3
    bad = tmp_path / "bad.json"
    bad.write_bytes(msgspec.json.encode(raw))
    with pytest.raises(InputError) as err:
        tp.read_plan(bad)
    assert err.value.field.startswith("drone[0].action") and "speed" in err.value.problem


def test_team_plan_runs_end_to_end_in_simulation(planner, plan):
    report = TeamSim(planner.sensing, plan).run()
    assert report.reached_goal, report.failure
    assert all(e.ok for e in report.events)
    assert len(report.events) == len(plan.drone) + len(plan.ugv)
    dyn = [e for e in report.events if e.action == "GoToLandmarkDyn"]
    ugv_done = [e.end_s for e in report.events if e.robot == "ugv"]
    for e in dyn:  # every GOTOLANDMARK_DYN started after the UGV motions it waits for
        step = plan.drone[e.index]
        assert e.start_s >= (ugv_done[step.wait_for - 1] if step.wait_for else 0.0)


def test_simulation_can_be_stepped_action_by_action(planner, plan):
    sim = TeamSim(planner.sensing, plan)
    first = plan.drone[0]
    assert "drone" in sim.ready() or first.wait_for > 0
    steps = 0
    while sim.ready():
        robot = sim.ready()[0]
        event = sim.step(robot)
        assert event.ok and event.robot == robot
        steps += 1
    assert steps == len(plan.drone) + len(plan.ugv) and sim.report().reached_goal
    with pytest.raises(ValueError):
        sim.step("drone")


def test_ignoring_sync_points_breaks_the_plan(planner, plan):
    report = TeamSim(planner.sensing, without_sync(plan)).run()
    assert not report.reached_goal
    assert "GoToLandmarkDyn" in report.failure


def test_simulation_catches_a_world_that_differs_from_the_map(planner, plan):
    env = planner.env
    ugv_cells = [env.cell_of(*s.end[:2]) for s in plan.ugv]
    heights = env.heights.copy()
    r, c = ugv_cells[len(ugv_cells) // 2]
    heights[r, c] = 0.5  # a box where the UGV has to drive
    world = Env(env.name, env.resolution, heights, env.z_levels, env.landmarks, env.no_ugv, env.no_metric)
    report = TeamSim(Sensing(world, TeamModel()), plan).run()
    assert not report.reached_goal and "UGV" in report.failure


def test_plan_progress_tracks_sync_points(plan):
    progress = tp.PlanProgress(plan)
    blocked = [r for r in tp.ROBOTS if progress.next_step(r) and not progress.can_start(r)]
    for robot in blocked:
        step = progress.next_step(robot)
        assert step.wait_for > progress.done[tp.PlanProgress.other(robot)]
    while not progress.finished:
        robot = next(r for r in tp.ROBOTS if progress.can_start(r))
        progress.complete(robot)
    assert progress.done == {"drone": len(plan.drone), "ugv": len(plan.ugv)}
    with pytest.raises(ValueError):
        progress.complete("ugv")


def test_wait_for_counts_never_exceed_the_other_sequence(plan):
    assert all(s.wait_for <= len(plan.ugv) for s in plan.drone)
    assert all(s.wait_for <= len(plan.drone) for s in plan.ugv)
    assert np.all(np.diff([s.wait_for for s in plan.drone if s.wait_for]) >= 0)
