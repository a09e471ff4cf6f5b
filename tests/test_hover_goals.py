"""Air-node goals (issue 19's single-vehicle take-off, go to, land): a plan request may end a flying
vehicle's task at an air node, where it hovers; a running mission replans it from there to another
air node and down to a spot. Scenario files keep the stricter rule (spots only); the mission runner
flies an air goal only in a hover mission, which stays open while a vehicle hovers."""

from __future__ import annotations

import pytest

from common.bus.messages import PlanRequest, Replan
from common.bus.session import ZenohConfig
from common.domain.planfile import Task
from common.errors import InputError
from services.mission.runner import MissionRunner, MissionSpec
from services.planner.maps.loading import load_graph
from services.planner.maps.tasks import check_tasks
from services.planner.registry import solve


def test_a_plan_request_may_end_a_flying_vehicles_task_in_the_air_and_a_replan_lands_it() -> None:
    up = solve(PlanRequest(map="town", tasks={"cf8": Task(start="EP8", goal="i_El4")}))
    assert up.ok and up.plan is not None, up.error
    path = up.plan.paths["cf8"]
    assert path[-1].node == "i_El4" and up.plan.graph.nodes["i_El4"].kind == "air"
    at = path[-1].t + 1.0  # hovering
    over = solve(PlanRequest(map="town", tasks={}, time_limit=1.0,
                             replan=Replan(base=up.plan, at=at, goals={"cf8": "a0_11_1"})))
    assert over.ok and over.plan is not None, over.error
    assert over.plan.paths["cf8"][-1].node == "a0_11_1" and over.plan.paths["cf8"][:len(path)] == path
    down = solve(PlanRequest(map="town", tasks={}, time_limit=1.0,
                             replan=Replan(base=over.plan, at=over.plan.paths["cf8"][-1].t + 1.0, goals={"cf8": "EP8"})))
    assert down.ok and down.plan is not None, down.error
    assert down.plan.paths["cf8"][-1].node == "EP8" and down.plan.tasks["cf8"].goal == "EP8"


def test_a_vehicle_that_only_drives_or_a_scenario_file_may_not_end_in_the_air() -> None:
    drives = solve(PlanRequest(map="town", tasks={"cf8": Task(start="EP8", goal="i_El4", capabilities="drive")}))
    assert not drives.ok and "tasks.cf8.goal" in drives.error and "air node" in drives.error
    with pytest.raises(InputError, match="tasks.cf8.goal"):
        check_tasks({"cf8": Task(start="EP8", goal="i_El4")}, load_graph("town"), "scenario.yaml")


def test_the_runner_flies_an_air_goal_only_in_a_hover_mission_and_keeps_it_open_while_one_hovers() -> None:
    up = solve(PlanRequest(map="town", tasks={"cf8": Task(start="EP8", goal="i_El4")}))
    assert up.plan is not None
    plain = MissionRunner(MissionSpec(map="town", tasks=dict(up.plan.tasks)), ZenohConfig.client("tcp/127.0.0.1:9"))
    assert plain.accept(up) == "cf8: a goal in the air needs a hover mission (--hover)"

    hover = MissionRunner(MissionSpec(map="town", tasks=dict(up.plan.tasks), hover=True, slack_s=1.0),
                          ZenohConfig.client("tcp/127.0.0.1:9"))
    hover.plan, hover.t0 = up.plan, 1000.0  # as after `accept` and the start
    hover.reports["cf8"].planned_s = up.plan.paths["cf8"][-1].t
    assert hover.end_reason(1000.0 + 3600.0) is None  # an hour later it still hovers: open until told
    hover.plan = down = solve(PlanRequest(map="town", tasks={}, time_limit=1.0, replan=Replan(
        base=up.plan, at=up.plan.paths["cf8"][-1].t + 1.0, goals={"cf8": "EP8"}))).plan
    assert down is not None
    assert hover.end_reason(1000.0 + 3600.0) == "time limit: not every vehicle arrived"  # going down: limits apply
    hover.reports["cf8"].arrived = True
    assert hover.end_reason(1000.0 + 3600.0) == "every vehicle arrived"
