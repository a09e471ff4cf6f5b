"""The paper-002 commands: `fleet collab plan` (planner), `fleet sim replay` and `fleet sim team`
(simulator), `fleet mission team` (mission client); bad input as InputError naming the field."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from common.domain.team_plan import read_plan
from common.errors import InputError
from services.cli import build_parser

pytestmark = pytest.mark.compute


def run(*argv: str) -> int:
    args: argparse.Namespace = build_parser().parse_args(argv)
    return args.handler(args)


REPO = Path(__file__).resolve().parents[1]
ROOM = ("--map", "demo-room", "--start", "1.25,1.25,1.0", "--ugv", "0.75,1.25,0", "--goal", "5.75,3.75,2.0")


def test_plan_prints_and_writes_a_team_plan_the_simulated_world_replays(tmp_path, capsys):
    out = tmp_path / "plan.json"
    assert run("collab", "plan", *ROOM, "--out", str(out), "--time-limit", "20") == 0
    text = capsys.readouterr().out
    assert "GOTOLANDMARK_DYN" in text and "[after ugv" in text
    plan = read_plan(out)
    assert plan.map == "demo-room" and plan.planner == "pad"
    assert run("sim", "replay", str(out)) == 0
    assert "drone reached the goal" in capsys.readouterr().out


def test_plan_with_a_seeded_problem_as_json(capsys):
    assert run("collab", "plan", "--map", "demo-room", "--seed", "1", "--planner", "arastar", "--json") == 0
    assert '"format":"fleet-collab-plan/1"' in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv,field",
    [
        (("collab", "plan", "--map", "nowhere"), "map"),
        (("collab", "plan", "--map", "demo-room", "--start", "1,1,1"), "--start/--ugv/--goal"),
        (("collab", "plan", *ROOM[:-1], "0,0,1"), "goal"),  # inside the outer wall
        (("collab", "plan", *ROOM[:4], "--ugv", "1.25,1.25,zero", *ROOM[6:]), "--ugv"),
        (("sim", "replay", "/nonexistent/plan.json"), ""),
        (("sim", "team", "--ugv", "0.25,0.25,0"), "ugv_start"),  # the UGV inside the outer wall
        (("sim", "team", "--time-scale", "0"), "--time-scale"),
        (("sim",), "--config"),
        (("mission", "team", "--goal", "5.75,3.75"), "--goal"),
        (("mission", "team", "--local", "--executors", "0"), "--executors"),
    ],
)
def test_bad_input_raises_input_error(argv, field):
    with pytest.raises(InputError) as err:
        run(*argv)
    assert err.value.field.startswith(field)


def test_the_experiment_refuses_bad_limits():
    """bench/ sits above tests/ (the import contracts): run it as a user does."""
    done = subprocess.run([sys.executable, "-m", "bench.collab_experiment", "--instances", "0"], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and "--instances" in done.stderr
