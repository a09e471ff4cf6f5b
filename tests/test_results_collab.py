"""Paper 002 as reproduced (issue 18): the paper's corner group of metric controllers, WALLFOLLOWING's
OBSTACLE trigger front or back, PAD needing more than one iteration with the paper's primitives and
eps_track 2, and the paper's limits as an option of the experiment (its full run is `-m scale`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from common.domain.team_plan import MetricStep, MetricTurn, decode_json, encode_json
from common.team import controllers as ctl
from common.team.env import grid_env
from common.team.maps import load_env
from common.team.sensing import Sensing
from common.team.team_model import TeamModel
from services.planner.collab.instances import sample_problem
from services.planner.collab.lattice import SlcOptions
from services.planner.collab.pad import PadConfig
from services.planner.collab.planner import TeamPlanner

pytestmark = pytest.mark.compute

E, N, W, S = 0, 2, 4, 6
REPO = Path(__file__).resolve().parents[1]
FIRST_SOLUTION_S = 180.0
"""The paper's limit on the first solution (002 §V-D), as a guard only: with no improvement time a
search returns its first solution, whenever it comes, so a larger limit changes no result; in the
suite's compute lane, at idle priority beside the flights, 20 s of wall clock once held too little
CPU for one of these problems (a CI run on a slow hour: timed out after 27,168 expansions)."""


def experiment(*args: str, timeout: float = 300.0) -> subprocess.CompletedProcess:
    """`python -m bench.collab_experiment ARGS` (tests do not import bench)."""
    return subprocess.run([sys.executable, "-m", "bench.collab_experiment", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout)
ROOM = ["##########", *["#........#"] * 6, "##########"]  # 8 x 6 free cells inside a wall


def test_corner_group_is_step_half_turn_ninety_step_one_metre() -> None:
    s = Sensing(grid_env(ROOM), TeamModel())
    mid, end = ctl.corner_target(s, 0, 2, 2, E, 2, (1, 2))
    assert (mid, end) == ((2, 3), (4, 3))  # 0.5 m east, turn left (north), 1.0 m north
    assert ctl.corner_target(s, 0, 2, 2, E, -2, (1, 2)) is None  # 1 m south of row 2 is the wall
    assert ctl.corner_target(s, 0, 2, 2, 1, 2, (1, 2)) is None  # corners start from a cardinal heading
    # the same motion through Phi, controller by controller (what the simulator executes)
    pose = ctl.phi(s, ctl.DronePose(0, 2, 2), ctl.MetricTurnController(E))
    pose = ctl.phi(s, pose, ctl.MetricStepController(1))
    pose = ctl.phi(s, pose, ctl.MetricTurnController(N))
    pose = ctl.phi(s, pose, ctl.MetricStepController(2))
    assert (pose.row, pose.col) == end
    no_turn = Sensing(grid_env(ROOM, no_metric=[(1.5, 1.0, 2.0, 1.5)]), TeamModel())  # cell (2, 3)
    assert ctl.corner_target(no_turn, 0, 2, 2, E, 2, (1, 2)) is None  # no turning where metric is forbidden


def test_obstacle_trigger_fires_a_metre_before_an_obstacle_ahead_front_or_back() -> None:
    """Following the south wall (1 cell away) east, then west: the sensor facing the travel (the
    front flying forwards, the back flying backwards) sees the end wall 2 cells ahead one cell before
    the intrinsic end next to it."""
    s = Sensing(grid_env(ROOM), TeamModel())
    east = ctl.follow_wall(s, 0, 1, 1, "right", E)
    assert east[None] == (1, 8, 7) and east[ctl.OBSTACLE] == (1, 7, 6)
    west = ctl.follow_wall(s, 0, 1, 8, "left", W)
    assert west[None] == (1, 1, 7) and west[ctl.OBSTACLE] == (1, 2, 6)
    assert ctl.OBSTACLE not in ctl.follow_wall(s, 0, 1, 7, "right", E)  # already that close at the start
    pose = ctl.phi(s, ctl.DronePose(0, 1, 1), ctl.WallFollowController("right", E), ctl.OBSTACLE)
    assert (pose.row, pose.col) == (1, 7)


@pytest.fixture(scope="module")
def cubicles() -> TeamPlanner:
    return TeamPlanner(load_env("office-cubicles"), options=SlcOptions.paper())


def test_paper_primitives_plan_corners_only_and_round_trip(cubicles) -> None:
    lat = cubicles.lattice(sample_problem(cubicles, 0).ugv_start[:2])
    labels = {label[0] for edges in lat.drone_edges for _, label in edges.values()}
    assert "CORNER" in labels and "METRIC" not in labels
    seen_corner = seen_obstacle = False
    for seed in range(8):
        out = cubicles.plan(sample_problem(cubicles, seed), "pad", FIRST_SOLUTION_S, 0.0, PadConfig(eps_track=2.0))
        assert out.plan is not None
        plan = decode_json(encode_json(out.plan))  # OBSTACLE is a trigger the plan format carries
        assert sum(s.cost for s in plan.drone) + sum(s.cost for s in plan.ugv) == pytest.approx(plan.cost)
        actions = [s.action for s in plan.drone]
        seen_obstacle |= any(getattr(a, "trigger", None) == "OBSTACLE" for a in actions)
        for i, a in enumerate(actions):
            if isinstance(a, MetricStep):  # every metric step sits in a corner group
                first = isinstance(actions[i - 1], MetricTurn) and a.distance_m == pytest.approx(0.5)
                second = isinstance(actions[i - 1], MetricTurn) and a.distance_m == pytest.approx(1.0)
                assert first or second
                if second:
                    turn = abs((actions[i - 1].heading_deg - actions[i - 3].heading_deg + 180) % 360 - 180)
                    assert turn == pytest.approx(90.0) and actions[i - 2].distance_m == pytest.approx(0.5)
                    seen_corner = True
    assert seen_obstacle and seen_corner


def test_pad_needs_more_than_one_iteration_with_the_papers_primitives(cubicles) -> None:
    """With eps_track 2 (the experiment's) PAD introduces regions on a share of the cubicle problems,
    as the paper reports (1.26 iterations on average there, 1.59 in the conference rooms)."""
    iterations = []
    for seed in range(6):
        out = cubicles.plan(sample_problem(cubicles, seed), "pad", FIRST_SOLUTION_S, 0.0, PadConfig(eps_track=2.0))
        assert out.plan is not None
        iterations.append(out.iterations)
    assert max(iterations) > 1 and sum(i > 1 for i in iterations) >= 2


def test_paper_limits_option() -> None:
    run = experiment("--paper-limits", "--dry-run")
    assert run.returncode == 0, run.stderr
    settings = json.loads(run.stdout)
    assert (settings["time_limit"], settings["improve"]) == (180.0, 5.0)
    assert settings["slc"] == {"metric": "corner", "obstacle_trigger": True} and settings["eps_track"] == 2.0
    default = json.loads(experiment("--slc", "free", "--dry-run").stdout)
    assert (default["time_limit"], default["improve"], default["slc"]["metric"]) == (10.0, 1.0, "free")


@pytest.mark.scale
def test_experiment_at_the_papers_limits(tmp_path) -> None:
    """Two problems per map at 3 min + 5 s (minutes: kept out of the default suite, `-m scale`)."""
    out = tmp_path / "runs.json"
    run = experiment("--paper-limits", "--instances", "2", "--out", str(tmp_path / "c.png"), "--json", str(out),
                     timeout=2 * 2 * 2 * 190.0)
    assert run.returncode == 0, run.stderr
    runs = json.loads(out.read_text())
    assert len(runs) == 2 * 2 * 2
    assert all(r["solved"] for r in runs if r["method"] == "pad")


def test_the_experiment_refuses_bad_limits() -> None:
    """The same check as tests/test_collab_cli.py's, run as a process (that one imports bench, which
    the import contracts forbid tests to do)."""
    run = subprocess.run([sys.executable, "-m", "bench.collab_experiment", "--instances", "0"], cwd=REPO,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 2 and "--instances" in run.stderr
