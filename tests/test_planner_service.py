"""The planner service over real zenoh: a plan request answered with a validated plan and the
vehicles' plans published; bad requests answered with clear errors; an absent planner fails fast;
a request planned only while its requester waits (`PlanRequest.reply_within`)."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest

from common.bus.keys import Keys
from common.bus.messages import PlanReply, PlanRequest, Replan, ServiceStats, Sweep, VehiclePlan
from common.bus.pubsub import QueryError, query, subscribe
from common.bus.session import ZenohConfig, open_session
from common.domain.planfile import Task
from services.cli import main as fleet_main
from services.planner.failed_requests import FailedRequests
from services.planner.registry import solve
from services.planner.service import PlannerService
from services.planner.validate import validate_plan

KEYS = Keys("ptest")
TASKS = {"cf1": Task(start="WP1", goal="EP4"), "cf2": Task(start="EP1", goal="WP6")}
EIGHT = {**TASKS, "cf3": Task(start="WP10", goal="EP8"), "cf4": Task(start="EP7", goal="WP9"),
         "cf5": Task(start="WP7", goal="WP3"), "cf6": Task(start="EP2", goal="WP2"),
         "cf7": Task(start="WP4", goal="EP5"), "cf8": Task(start="EP3", goal="WP5")}
"""Eight vehicles on the town map: the ILP plans them until its time limit (5 s -> 5.05 s)."""


async def _with_planner(endpoint: str, body, keep_failed: Path | None = None):
    svc = PlannerService("planner", "p1", ZenohConfig.client(endpoint), KEYS, keep_failed=keep_failed)
    task = asyncio.create_task(svc.run())
    client = open_session(ZenohConfig.client(endpoint))
    try:
        await asyncio.sleep(0.3)
        return await body(client, svc)
    finally:
        svc.stop()
        assert await task == 0
        client.close()


@pytest.mark.timeout(60)
def test_plan_request_returns_a_valid_plan_and_publishes_vehicle_plans(zenoh_router: str) -> None:
    async def body(client, _svc):
        got: dict[str, VehiclePlan] = {}
        sub = subscribe(client, KEYS.all_vehicles("plan"), VehiclePlan, lambda p, _k: got.__setitem__(p.vid, p))
        await asyncio.sleep(0.2)
        req = PlanRequest(map="town", tasks=TASKS, planner="sipp", mu=0.5, time_limit=20, mission="m1")
        reply = await query(client, KEYS.planner_plan, req, PlanReply, timeout=30)
        for _ in range(50):
            if len(got) == 2:
                break
            await asyncio.sleep(0.05)
        sub.close()
        return reply, got

    reply, got = asyncio.run(_with_planner(zenoh_router, body))
    assert reply.ok and reply.plan is not None
    assert validate_plan(reply.plan).ok
    assert set(got) == {"cf1", "cf2"}
    cf1 = got["cf1"]
    assert cf1.mission == "m1" and cf1.steps[0].node == "WP1" and cf1.steps[-1].node == "EP4"
    assert {s.edge for s in cf1.steps} >= {"drive", "takeoff", "fly", "land"}  # it must fly over the gap


@pytest.mark.timeout(60)
@pytest.mark.parametrize(("request_", "message"), [
    (PlanRequest(map="atlantis", tasks=TASKS), "atlantis"),
    (PlanRequest(map="town", tasks={"cf1": Task(start="Wb0", goal="EP4")}), "tasks.cf1.start"),
    (PlanRequest(map="town", tasks=TASKS, planner="magic"), "unknown planner"),
    (PlanRequest(map="town", tasks=TASKS, mu=2.0), "mu"),
    (PlanRequest(map="town", tasks=TASKS, reply_within=-1.0), "reply_within"),
])
def test_bad_requests_get_clear_errors(zenoh_router: str, request_: PlanRequest, message: str) -> None:
    async def body(client, _svc):
        return await query(client, KEYS.planner_plan, request_, PlanReply, timeout=30)

    reply = asyncio.run(_with_planner(zenoh_router, body))
    assert not reply.ok and message in reply.error


@pytest.mark.timeout(20)
def test_no_planner_fails_fast(zenoh_router: str) -> None:
    async def body() -> None:
        client = open_session(ZenohConfig.client(zenoh_router))
        try:
            await query(client, KEYS.planner_plan, PlanRequest(map="town", tasks=TASKS), PlanReply, timeout=5)
        finally:
            client.close()

    with pytest.raises(QueryError):
        asyncio.run(body())


@pytest.mark.timeout(60)
def test_a_request_whose_requester_stopped_waiting_is_not_planned(zenoh_router: str) -> None:
    """Plans are made one at a time: a request queued behind a long one until its `reply_within`
    ran out is answered "expired" without planning (counted), while the one before it is planned;
    the planner's stats on the bus say so, and how long the expired one waited."""
    async def body(client, _svc):
        stats: list[ServiceStats] = []
        sub = subscribe(client, KEYS.all_stats("planner"), ServiceStats, lambda m, _k: stats.append(m))
        slow = PlanRequest(map="town", tasks=EIGHT, planner="ilp", time_limit=2.0)
        first = asyncio.create_task(query(client, KEYS.planner_plan, slow, PlanReply, timeout=30))
        await asyncio.sleep(0.5)
        quick = PlanRequest(map="town", tasks=TASKS, planner="sipp", time_limit=20, reply_within=0.5)
        second = await query(client, KEYS.planner_plan, quick, PlanReply, timeout=30)
        answered = time.time()
        for _ in range(60):
            if stats and stats[-1].t > answered:
                break
            await asyncio.sleep(0.1)
        sub.close()
        return await first, second, stats[-1]

    first, second, stats = asyncio.run(_with_planner(zenoh_router, body))
    assert first.ok and first.plan is not None
    assert not second.ok and "expired" in second.error and second.plan is None
    assert (stats.counters.get("plans_expired"), stats.counters.get("plans_ok")) == (1, 1)
    assert stats.figures["waited_max_ms"] > 1000.0  # behind the ILP's 2 s, asked 0.5 s into it
    assert stats.figures["planned_max_ms"] > 1900.0


@pytest.mark.timeout(60)
def test_a_request_is_planned_within_what_is_left_of_its_wait(zenoh_router: str) -> None:
    """A time limit longer than the requester waits is cut to the wait: the ILP that plans eight
    vehicles for its whole time limit answers within the 1.5 s its requester waits, not 30 s."""
    async def body(client, _svc):
        req = PlanRequest(map="town", tasks=EIGHT, planner="ilp", time_limit=30.0, reply_within=1.5)
        start = time.monotonic()
        reply = await query(client, KEYS.planner_plan, req, PlanReply, timeout=40)
        return reply, time.monotonic() - start

    reply, took = asyncio.run(_with_planner(zenoh_router, body))
    assert reply.ok and reply.plan is not None and validate_plan(reply.plan).ok
    assert took < 4.0, f"answered after {took:.1f} s"


@pytest.mark.timeout(60)
def test_a_request_it_could_not_plan_is_kept_and_replays_to_the_same_answer(
        zenoh_router: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`fleet planner --keep-failed DIR`: a replan that finds no plan (cf2 came down on cf1's goal,
    without stranding) is written to DIR; `fleet replay-plan` plans it again to the same error (exit
    1). A plan and a refused rejoin are not kept, a planner restarted on the folder numbers on, and a
    file that is no request is a clear error (2)."""
    base = solve(PlanRequest(map="town", tasks=TASKS, time_limit=20)).plan
    assert base is not None
    goal = base.graph.nodes["EP4"].pos
    replan = PlanRequest(map="town", tasks={}, time_limit=10, replan=Replan(
        base=base, at=1.0, left=["cf2"], sweeps=[Sweep("cf2", goal, goal, 1.0, 1.0, rest=True)]))
    kept = tmp_path / "failed"

    async def body(client, _svc):
        ok = await query(client, KEYS.planner_plan, PlanRequest(map="town", tasks=TASKS, time_limit=20), PlanReply,
                         timeout=30)
        failed = await query(client, KEYS.planner_plan, replan, PlanReply, timeout=30)
        return ok, failed

    ok, failed = asyncio.run(_with_planner(zenoh_router, body, keep_failed=kept))
    assert ok.ok and not failed.ok and "could not place cf1" in failed.error, failed.error
    files = sorted(kept.iterdir())
    assert [f.name for f in files] == ["001-replan.msgpack"]
    capsys.readouterr()
    assert fleet_main(["replay-plan", str(files[0])]) == 1
    out = capsys.readouterr().out
    assert "replan of 2 vehicles from 1.0 s around cf2 on town" in out and failed.error in out, out
    bad = tmp_path / "bad.msgpack"
    bad.write_bytes(b"not msgpack")
    assert fleet_main(["replay-plan", str(bad)]) == 2
    assert f"{bad}: not a kept plan request" in capsys.readouterr().err
    refused = PlanReply(ok=False, error="replan: cf1 cannot rejoin yet", refused={"cf1": "its way is closed"})
    assert FailedRequests(kept).keep(replan, refused) is None
    again = FailedRequests(kept)  # a planner restarted on the folder numbers on
    assert again.keep(replan, failed) == kept / "002-replan.msgpack"
