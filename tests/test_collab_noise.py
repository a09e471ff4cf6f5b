"""Paper 002 under sensing noise (002 §III-B): range and bearing errors in the simulated team world
(`SensingNoise`, services/sim/team/world.py) and the executor's re-try of a drone step that ended
off its planned end (services/executor/team_robots.py); the measurement runs as a process
(bench.collab_noise)."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from common.bus.messages import ActionStatus, VehicleTeamPlan
from common.domain import team_plan as tp
from common.team.maps import load_env
from services.executor.team_robots import RETRIES, TeamRobot
from services.planner.collab.planner import TeamPlanner
from services.sim.team.world import SensingNoise, TeamSim, TeamWorld

pytestmark = pytest.mark.compute

REPO = Path(__file__).resolve().parents[1]
DRONE, UGV = "drone1", "ugv1"
LOUD = SensingNoise(0.3, 15.0)


@pytest.fixture(scope="module")
def room() -> tuple[TeamPlanner, tp.TeamPlan]:
    planner = TeamPlanner(load_env("demo-room"))
    problem = planner.problem_at((1.25, 1.25, 1.0), (0.75, 1.25, 0.0), (5.75, 3.75, 2.0))
    plan = planner.plan(problem, "pad", 180.0).plan  # (a guard: the first solution is returned)
    assert plan is not None
    return planner, plan


def test_noise_free_world_runs_the_plan_and_noise_is_seeded(room) -> None:
    planner, plan = room
    for seed in range(5):
        assert TeamSim(planner.sensing, plan, SensingNoise(), seed).run().reached_goal
    with pytest.raises(ValueError):
        SensingNoise(-0.1, 0.0)
    runs = [TeamSim(planner.sensing, plan, LOUD, seed).run() for seed in range(20)]
    again = TeamSim(planner.sensing, plan, LOUD, 7).run()
    assert [e.pose for e in again.events] == [e.pose for e in runs[7].events]
    failed = [r for r in runs if not r.reached_goal]
    assert failed and all("ended at" in (r.failure or "") or "not available" in (r.failure or "") for r in failed)


def test_noise_moves_only_the_ends_of_actions_that_sense(room) -> None:
    """WALLFOLLOWING and GOTOLANDMARK end where their sensing puts them; METRIC*, ALTITUDE and the
    UGV's motions sense nothing and end as planned under any noise."""
    planner, plan = room
    moved: Counter[str] = Counter()
    for seed in range(30):
        for e in TeamSim(planner.sensing, plan, LOUD, seed).run().events:
            if not e.ok:
                moved[e.action] += 1
    assert moved and set(moved) <= {"WallFollowing", "GoToLandmarkStat", "GoToLandmarkDyn"}
    world = TeamWorld(planner.sensing, (1.25, 1.25, 1.0), (0.75, 1.25, 0.0), LOUD, 3)
    for _ in range(20):
        climb = world.outcome("drone", tp.Step(tp.Altitude(2.0), (1.25, 1.25, 2.0), 1.0))
        drive = world.outcome("ugv", tp.Step(tp.MetricMotion(distance_m=1.0), (1.75, 1.25, 0.0), 1.0))
        assert climb.ok and drive.ok


def _plan() -> tp.TeamPlan:
    drone = (tp.Step(tp.Altitude(2.0), (1.25, 1.25, 2.0), 1.0),
             tp.Step(tp.GoToLandmarkDyn((1.0, 1.0, 1.2), (3.25, 2.25, 2.0)), (3.25, 2.25, 2.0), 2.0, wait_for=1))
    ugv = (tp.Step(tp.MetricMotion(distance_m=1.5), (2.25, 1.25, 0.0), 1.5),
           tp.Step(tp.MetricMotion(distance_m=1.0), (3.25, 1.25, 0.0), 1.0, wait_for=2))
    return tp.TeamPlan(tp.PLAN_FORMAT, "demo-room", "pad", (1.25, 1.25, 1.0), (0.75, 1.25, 0.0), (3.25, 2.25, 2.0),
                       drone, ugv, 5.5, 1.0, 0.0, 0)


def _at_dyn(robot_kind: tp.Robot = "drone") -> TeamRobot:
    """A robot of `_plan()` with its GOTOLANDMARK_DYN (step 1) in flight."""
    robot = TeamRobot(VehicleTeamPlan(DRONE, "m1", robot_kind, UGV, _plan()), "exec-1")
    robot.start(0.0)
    robot.partner_progress(1)
    robot.action(1.0)
    assert robot.on_status(ActionStatus(DRONE, "m1", 0, "done", (1.25, 1.25, 2.0), 1.0))
    return robot


def _failed(index: int, pose: tp.Vec3, attempt: int) -> ActionStatus:
    return ActionStatus(DRONE, "m1", index, "failed", pose, 2.0 + attempt, "ended at ...", attempt)


def test_executor_retries_a_drone_step_that_ended_in_a_neighbouring_cell() -> None:
    robot = _at_dyn()
    first = robot.action(2.0)
    assert first is not None and (first.index, first.attempt) == (1, 0)
    assert robot.on_status(_failed(1, (3.75, 2.25, 2.0), 0))  # a cell past the planned end
    retry = robot.action(2.1)
    assert retry is not None and (retry.index, retry.attempt, retry.step) == (1, 1, first.step)
    assert robot.mode == "acting" and robot.done == 1 and robot.state(2.1).step == 1  # the UGV still waits
    assert not robot.on_status(_failed(1, (3.75, 2.25, 2.0), 0))  # the first attempt's status again: stale
    assert robot.on_status(ActionStatus(DRONE, "m1", 1, "done", (3.25, 2.25, 2.0), 4.0, "", 1))
    assert robot.done == 2 and robot.mode == "done" and robot.retries == 1 and robot.attempt == 0


def test_executor_gives_up_after_its_retries_or_when_a_retry_cannot_help() -> None:
    robot = _at_dyn()
    robot.action(2.0)
    offs = [(3.25, 2.75, 2.0), (2.75, 2.25, 2.0), (3.75, 2.75, 2.0)]  # a neighbouring cell after every attempt
    for attempt in range(RETRIES):
        assert robot.on_status(_failed(1, offs[attempt % 3], attempt)) and robot.mode == "acting"
        assert robot.action(3.0 + attempt).attempt == attempt + 1
    assert robot.on_status(_failed(1, offs[(RETRIES + 1) % 3], RETRIES))
    assert robot.mode == "failed" and f"after {RETRIES} re-tries" in robot.failure
    far = _at_dyn()
    far.action(2.0)
    assert far.on_status(_failed(1, (4.75, 2.25, 2.0), 0)) and far.mode == "failed"  # 1.5 m off: the plan is broken
    stuck = _at_dyn()
    stuck.action(2.0)
    assert stuck.on_status(_failed(1, (1.25, 1.25, 2.0), 0)) and stuck.mode == "failed"  # never moved: not available


def test_noise_levels_measured_with_and_without_retries(tmp_path) -> None:
    out = tmp_path / "noise.json"
    run = subprocess.run([sys.executable, "-m", "bench.collab_noise", "--maps", "office-conference", "--problems", "2",
                          "--draws", "2", "--out", str(out)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = json.loads(out.read_text())["maps"]["office-conference"]["rows"]
    assert rows[0]["range_std"] == 0 and rows[0]["plain"] == rows[0]["handled"] == 1.0 and rows[0]["retries_per_run"] == 0
    assert all(r["handled"] >= r["plain"] for r in rows)
    assert rows[-1]["plain"] < 1.0 and any(r["retries_per_run"] > 0 for r in rows)
    assert "success, executor re-tries" in run.stdout
