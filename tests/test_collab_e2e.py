"""A ground-air team plan (paper 002 §IV-E) run end to end over real zenoh: the planner service
answers `planner: collab`, two executors own one robot each and wait on each other's progress at
the sync points, the collab simulator runs the actions with the drone's sensing; a bad team
request gets a clear error; an executor that dies mid-mission hands its robot over."""

from __future__ import annotations

import asyncio
import itertools
import time
from collections.abc import Awaitable, Callable

import pytest

from common.bus.keys import Keys
from common.bus.messages import ActionStatus, PlanReply, PlanRequest, TeamAction, TeamTask, VehicleTeamPlan
from common.bus.pubsub import query, subscribe
from common.bus.session import ZenohConfig, open_session
from common.domain import team_plan as tp
from common.domain.ownership import owner_of
from common.team.maps import load_env
from common.team.sensing import Sensing
from common.team.team_model import TeamModel
from services.executor.service import ExecutorService
from services.executor.team_robots import RESEND_S, TeamRobot
from services.mission.team_mission import TeamMission, TeamMissionSpec
from services.planner.service import PlannerService
from services.sim.team.service import TeamSimService
from services.sim.team.world import TeamWorld

KEYS = Keys("collab-test")
DRONE, UGV = "drone1", "ugv1"
# demo-room: the goal is over the middle of the room, out of IR range of every wall and far from the
# landmark: only the UGV can guide the drone there (GOTOLANDMARK_DYN behind it, four sync points).
TEAM = TeamTask(drone=DRONE, ugv=UGV, drone_start=(1.25, 1.25, 1.0), ugv_start=(0.75, 1.25, 0.0),
                goal=(5.75, 3.75, 2.0), improve_s=0.0)


def split_executors() -> tuple[str, str]:
    """Two executor names under which the drone and the UGV have different owners."""
    for a, b in itertools.combinations([f"exec-{i}" for i in range(10)], 2):
        if owner_of(DRONE, {a, b}) != owner_of(UGV, {a, b}):
            return owner_of(DRONE, {a, b}), owner_of(UGV, {a, b})  # type: ignore[return-value]
    raise AssertionError("no split found")


class Observer:
    """Every action sent and every status reported, as a bystander receives them."""

    def __init__(self, session) -> None:
        self.log: list[TeamAction | ActionStatus] = []
        self.subs = [subscribe(session, KEYS.all_vehicles("action"), TeamAction, self._add),
                     subscribe(session, KEYS.all_vehicles("action_status"), ActionStatus, self._add)]

    def _add(self, msg, _key: str) -> None:
        self.log.append(msg)

    def first_t(self, pred: Callable[[TeamAction | ActionStatus], bool]) -> float:
        """The earliest `t` (the sender's clock) of the messages that match."""
        return min(m.t for m in self.log if pred(m))

    def close(self) -> None:
        for sub in self.subs:
            sub.close()


async def run_team(endpoint: str, executors: tuple[str, ...], time_scale: float,
                   during: Callable[[Observer, dict[str, ExecutorService]], Awaitable[None]] | None = None):
    """Planner, executors and the collab sim in this event loop; one team mission; its result."""
    zc = ZenohConfig.client(endpoint)
    world = TeamWorld(Sensing(load_env("demo-room"), TeamModel()), TEAM.drone_start, TEAM.ugv_start)
    execs = {name: ExecutorService(name, zc, KEYS, rate_hz=20.0) for name in executors}
    services = [PlannerService("planner", "p1", zc, KEYS), *execs.values(),
                TeamSimService("sim", zc, KEYS, world, {"drone": DRONE, "ugv": UGV}, time_scale=time_scale)]
    tasks = [asyncio.create_task(s.run()) for s in services]
    client = open_session(zc)
    observer = Observer(client)
    try:
        await asyncio.sleep(0.5)
        mission = TeamMission(TeamMissionSpec(map="demo-room", team=TEAM, stall_s=15.0), zc, KEYS, progress=False)
        run = asyncio.create_task(mission.run())
        if during is not None:
            await during(observer, execs)
        assert await asyncio.wait_for(run, 60) == 0
        return mission.result, observer
    finally:
        observer.close()
        client.close()
        for s in services:
            s.stop()
        await asyncio.gather(*tasks)


@pytest.mark.timeout(60)
def test_team_plan_runs_end_to_end_through_two_executors(zenoh_router: str) -> None:
    drone_exec, ugv_exec = split_executors()
    result, obs = asyncio.run(run_team(zenoh_router, (drone_exec, ugv_exec), time_scale=20.0))
    assert result.ok, result.summary()
    plan = result.plan
    assert any(isinstance(s.action, tp.GoToLandmarkDyn) for s in plan.drone)
    drone, ugv = result.robots[DRONE], result.robots[UGV]
    assert (drone.done, ugv.done) == (len(plan.drone), len(plan.ugv))
    assert (drone.owner, ugv.owner) == (drone_exec, ugv_exec)  # progress crossed zenoh between executors
    assert result.goal_error_m is not None and result.goal_error_m < 0.01
    # every step was sent by its robot's owner, and run once by the simulated robot
    actions = [m for m in obs.log if isinstance(m, TeamAction)]
    assert {(a.vid, a.owner) for a in actions} == {(DRONE, drone_exec), (UGV, ugv_exec)}
    for vid, steps in ((DRONE, plan.drone), (UGV, plan.ugv)):
        for i in range(len(steps)):
            dones = {m.t for m in obs.log if isinstance(m, ActionStatus) and (m.vid, m.index, m.status) == (vid, i, "done")}
            assert len(dones) == 1, (vid, i)
    # sync points: a waiting step is sent only after the partner reported the steps it waits for
    # done, by the messages' own clocks (one host here); the order two subscriptions deliver in is
    # not causal order (zenoh orders per publisher, not across them)
    synced = 0
    for vid, partner, steps in ((DRONE, UGV, plan.drone), (UGV, DRONE, plan.ugv)):
        for i, step in enumerate(steps):
            sent = obs.first_t(lambda m, vid=vid, i=i: isinstance(m, TeamAction) and (m.vid, m.index) == (vid, i))
            if step.wait_for:
                synced += 1
                awaited = obs.first_t(lambda m, p=partner, n=step.wait_for - 1: isinstance(m, ActionStatus)
                                      and (m.vid, m.index, m.status) == (p, n, "done"))
                assert awaited < sent, f"{vid} step {i} sent {awaited - sent:.3f} s before {partner} step {step.wait_for - 1} was done"
    assert synced == result.sync_points >= 4 and not result.sync_violations
    assert "sync points honoured: " in result.summary() and "FAILED" not in result.summary()


@pytest.mark.timeout(60)
def test_a_robot_whose_executor_dies_is_taken_over_mid_action(zenoh_router: str) -> None:
    drone_exec, ugv_exec = split_executors()
    killed_at: dict[str, float] = {}

    async def kill_ugv_executor_mid_action(obs: Observer, execs: dict[str, ExecutorService]) -> None:
        deadline = time.monotonic() + 30
        while not any(isinstance(m, ActionStatus) and (m.vid, m.index, m.status) == (UGV, 1, "started") for m in obs.log):
            assert time.monotonic() < deadline, "the UGV never started its second step"
            await asyncio.sleep(0.01)
        killed_at["log"] = len(obs.log)
        execs[ugv_exec].stop()

    result, obs = asyncio.run(run_team(zenoh_router, (drone_exec, ugv_exec), time_scale=6.0,
                                       during=kill_ugv_executor_mid_action))
    assert result.ok, result.summary()
    assert result.robots[UGV].owner == drone_exec and result.robots[UGV].done == len(result.plan.ugv)
    after = obs.log[killed_at["log"]:]
    assert any(isinstance(m, TeamAction) and m.vid == UGV and m.owner == drone_exec for m in after)
    # the step in flight was re-sent by the new owner but run only once
    done = [m for m in obs.log if isinstance(m, ActionStatus) and (m.vid, m.index, m.status) == (UGV, 1, "done")]
    assert done and len({m.t for m in done}) == 1
    assert not result.sync_violations


@pytest.mark.timeout(60)
def test_bad_team_requests_get_clear_errors(zenoh_router: str) -> None:
    bad = {
        "needs `team`": PlanRequest(map="demo-room", tasks={}, planner="collab"),
        "goal": PlanRequest(map="demo-room", tasks={}, planner="collab",
                            team=TeamTask(DRONE, UGV, (1.25, 1.25, 1.0), (0.75, 1.25, 0.0), (0.0, 0.0, 1.0))),
        "atlantis": PlanRequest(map="atlantis", tasks={}, planner="collab", team=TEAM),
        "different vehicles": PlanRequest(map="demo-room", tasks={}, planner="collab",
                                          team=TeamTask(DRONE, DRONE, TEAM.drone_start, TEAM.ugv_start, TEAM.goal)),
        "team.ugv": PlanRequest(map="demo-room", tasks={}, planner="collab",
                                team=TeamTask(DRONE, "ugv/1", TEAM.drone_start, TEAM.ugv_start, TEAM.goal)),
    }

    async def body() -> dict[str, PlanReply]:
        zc = ZenohConfig.client(zenoh_router)
        svc = PlannerService("planner", "p1", zc, KEYS)
        task = asyncio.create_task(svc.run())
        client = open_session(zc)
        try:
            await asyncio.sleep(0.3)
            return {m: await query(client, KEYS.planner_plan, r, PlanReply, timeout=30) for m, r in bad.items()}
        finally:
            client.close()
            svc.stop()
            await task

    for message, reply in asyncio.run(body()).items():
        assert not reply.ok and message in reply.error, (message, reply.error)


def _tiny_plan() -> tp.TeamPlan:
    """Drone: climb, then fly to the UGV once it has moved; UGV: move, then again after the drone's flight."""
    drone = (tp.Step(tp.Altitude(2.0), (1.25, 1.25, 2.0), 1.0),
             tp.Step(tp.GoToLandmarkDyn((1.0, 1.0, 1.2), (3.25, 2.25, 2.0)), (3.25, 2.25, 2.0), 2.0, wait_for=1))
    ugv = (tp.Step(tp.MetricMotion(distance_m=1.5), (2.25, 1.25, 0.0), 1.5),
           tp.Step(tp.MetricMotion(distance_m=1.0), (3.25, 1.25, 0.0), 1.0, wait_for=2))
    return tp.TeamPlan(tp.PLAN_FORMAT, "demo-room", "pad", (1.25, 1.25, 1.0), (0.75, 1.25, 0.0), (3.25, 2.25, 2.0),
                       drone, ugv, 5.5, 1.0, 0.0, 0)


def _status(index: int, status: str, pose=(1.25, 1.25, 2.0), mission: str = "m1") -> ActionStatus:
    return ActionStatus(vid=DRONE, mission=mission, index=index, status=status, pose=pose, t=0.0)  # type: ignore[arg-type]


def test_team_robot_sends_a_step_only_when_its_sync_point_is_met() -> None:
    robot = TeamRobot(VehicleTeamPlan(DRONE, "m1", "drone", UGV, _tiny_plan()), "exec-1")
    assert robot.mode == "loaded" and robot.action(100.0) is None  # not started
    robot.start(100.0)
    first = robot.action(100.0)
    assert first is not None and first.index == 0 and robot.mode == "acting"
    assert robot.action(100.0 + RESEND_S / 2) is None  # not yet due again
    assert robot.action(100.0 + RESEND_S).index == 0  # re-sent until answered
    assert not robot.on_status(_status(0, "started"))
    assert robot.on_status(_status(0, "done")) and robot.done == 1
    assert not robot.on_status(_status(0, "done"))  # a repeat changes nothing
    assert robot.action(102.0) is None and robot.mode == "waiting"  # GOTOLANDMARK_DYN waits for the UGV
    assert not robot.partner_progress(0)
    assert robot.partner_progress(1)
    dyn = robot.action(102.0)
    assert dyn is not None and dyn.index == 1 and isinstance(dyn.step.action, tp.GoToLandmarkDyn)
    state = robot.state(102.0)
    assert (state.step, state.steps, state.mode, state.arrived) == (1, 2, "acting", False)
    assert robot.on_status(_status(1, "done", (3.25, 2.25, 2.0)))
    state = robot.state(103.0)
    assert (state.step, state.mode, state.arrived, state.z) == (2, "done", True, 2.0)


def test_team_robot_stops_at_a_failed_action_and_resumes_from_a_state() -> None:
    plan = VehicleTeamPlan(DRONE, "m1", "drone", UGV, _tiny_plan(), t0=1.0)
    robot = TeamRobot(plan, "exec-1")
    robot.start(plan.t0)
    robot.action(2.0)
    assert not robot.on_status(_status(0, "done", mission="m0"))  # another mission's report
    assert robot.on_status(ActionStatus(DRONE, "m1", 0, "failed", (1.25, 1.25, 1.0), 2.5, "ALTITUDE not available"))
    assert robot.mode == "failed" and "ALTITUDE" in robot.failure and robot.action(9.0) is None
    taken = TeamRobot(plan, "exec-2", resume=robot.state(3.0))
    assert taken.mode == "failed" and taken.action(9.0) is None
    ok = TeamRobot(plan, "exec-1")
    ok.start(1.0)
    ok.action(2.0)
    ok.on_status(_status(0, "done"))
    resumed = TeamRobot(plan, "exec-2", resume=ok.state(3.0))
    resumed.start(1.0)
    resumed.partner_progress(1)
    again = resumed.action(4.0)
    assert resumed.done == 1 and again is not None and again.index == 1 and again.owner == "exec-2"
