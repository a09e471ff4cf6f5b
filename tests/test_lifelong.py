"""New tasks while flying (issue 16): `fleet mission add` gives a vehicle of a running mission a new
goal, planned against the others' paths, and `fleet mission run --lifelong` keeps giving every
vehicle that arrives a random free parking spot. Judged in ground truth: every vehicle ends at its
last goal, no contact."""

from __future__ import annotations

import asyncio
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from services.mission.demo import local_fleet
from services.mission.runner import MissionRunner, MissionSpec
from tests.support.fleet_faults import NO_RECORDER, TOWN_TASKS, Watch, fly, until

pytestmark = pytest.mark.flight

REPO = Path(__file__).resolve().parents[1]


def fleet_mission_add(fleet, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **fleet.credentials.env("mission")}
    return subprocess.run([sys.executable, "-m", "services.cli", "mission", "add", *args, "--connect", fleet.endpoint,
                           "--fleet", fleet.keys.fleet], cwd=REPO, capture_output=True, text=True, timeout=60, env=env)


@pytest.mark.timeout(240)
def test_lifelong_tasks_and_an_operators_new_goal_are_flown_without_contact(tmp_path) -> None:
    # new tasks for 22 s: cf1 and cf2 arrive at about 17 s and get random goals, cf3 (sent elsewhere
    # by the operator) arrives at about 23 s and its mission ends there
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, planner="sipp", time_limit=20, lifelong_s=22.0, seed=4)
    answers: list[subprocess.CompletedProcess[str]] = []

    async def scenario(watch: Watch, runner: MissionRunner) -> None:
        await until(lambda: runner.t0 is not None, 30, "the mission's start")
        refused = await asyncio.to_thread(fleet_mission_add, fleet, runner.mission, "cf9", "WP7")
        assert refused.returncode == 1 and "cf9 is not in the mission" in refused.stderr, refused
        taken = await asyncio.to_thread(fleet_mission_add, fleet, runner.mission, "cf3", TOWN_TASKS["cf1"].goal)
        assert taken.returncode == 1 and "is the goal of cf1" in taken.stderr, taken
        # cf3 drives for 15 s: while it is on its way, send it elsewhere
        answers.append(await asyncio.to_thread(fleet_mission_add, fleet, runner.mission, "cf3", "WP5"))

    with local_fleet("town", TOWN_TASKS, tmp_path / "run", executors=2, fleet="lifelong", without=NO_RECORDER) as fleet:
        result, watch = fly(fleet, spec, scenario)

    assert answers[0].returncode == 0, answers[0]
    assert "cf3 -> WP5: planned" in answers[0].stdout
    print(result.summary())
    assert result.ok, result.reason
    assert result.tasks_added >= 3, result.events
    # every task was finished, but cf3's first, which the operator replaced on its way
    assert result.tasks_done == len(TOWN_TASKS) + result.tasks_added - 1, (result.tasks_done, result.tasks_added)
    assert result.final_plan is not None
    for vid, path in result.final_plan.paths.items():
        goal = result.final_plan.graph.nodes[path[-1].node].pos
        last = watch.truth[vid][-1]
        assert math.dist((last.x, last.y, last.z), goal) < 0.05, (vid, path[-1].node, last)
    assert result.contacts == 0 and not watch.contacts, (watch.separation_line(), watch.contacts[:5])
