"""The planner unreachable (issue 8): a mission fails fast with a clear message, within seconds, not
after the planning timeout (here 40 s): no planner alive at all, or one that hangs (SIGSTOP).

The hung planner is first seen to answer a plan query (its queryable is up, not only its token),
then stopped right as the mission sends its request: the request reaches a planner that will never
answer, and the router gives the query up when it expires the planner's session, one link lease
(`LEASE_MS`) after it last heard from it (a keep-alive at most `LEASE_MS / KEEP_ALIVE` before the
stop). So the client's error comes within those bounds of the request: sooner, the query never
reached the planner (no queryable); later, something waited for a timeout instead."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time

import pytest

from common.bus.keys import Keys
from common.bus.liveliness import declare_alive
from common.bus.messages import PlanReply, PlanRequest
from common.bus.pubsub import QueryError, query
from common.bus.session import KEEP_ALIVE, LEASE_MS, InProcessRouter, ZenohConfig, open_session
from services.mission.runner import MissionResult, MissionRunner, MissionSpec
from tests.support.fleet_faults import TOWN_TASKS

KEYS = Keys("plannerfault")
FAST_S = 3.0
LEASE_S = LEASE_MS / 1000
ERROR_AFTER_S = (LEASE_S - LEASE_S / KEEP_ALIVE - 0.1, LEASE_S + 1.0)
"""Bounds of the time from the plan request to the client's error with the planner hung: the lease
less one keep-alive interval (and 0.1 s of clock and delivery), up to the lease plus 1 s of a loaded
machine's delivery."""


class StopsThePlanner(MissionRunner):
    """A mission that stops `planner` (SIGSTOP) right before it sends its plan request, and notes
    when it sent it and when it concluded."""

    def __init__(self, planner: subprocess.Popen, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.planner = planner
        self.requested = self.concluded = 0.0

    def plan_request(self) -> PlanRequest:
        self.planner.send_signal(signal.SIGSTOP)
        self.requested = time.monotonic()
        return super().plan_request()

    def conclude(self, ok: bool, reason: str) -> MissionResult:
        self.concluded = time.monotonic()
        return super().conclude(ok, reason)


def _mission(router: InProcessRouter) -> tuple[MissionResult, float]:
    """Run a mission against `router`; its result and how long it took."""
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, time_limit=30.0)
    runner = MissionRunner(spec, router.client_config(), KEYS, progress=False)
    started = time.monotonic()
    assert asyncio.run(runner.run()) == 0
    assert runner.result is not None
    return runner.result, time.monotonic() - started


async def _answers(config: ZenohConfig, timeout: float) -> PlanReply:
    """The planner's reply to a small plan query, asked again until its queryable answers."""
    request = PlanRequest(map="town", tasks={"cf3": TOWN_TASKS["cf3"]}, planner="sipp", mu=0.5, time_limit=10.0)
    session = open_session(config)
    deadline = time.monotonic() + timeout
    try:
        while True:
            try:
                return await query(session, KEYS.planner_plan, request, PlanReply, timeout=20.0)
            except QueryError:  # no queryable yet: it is declared after the token
                assert time.monotonic() < deadline, "the planner's queryable never answered"
                await asyncio.sleep(0.1)
    finally:
        session.close()


@pytest.mark.timeout(120)
def test_a_mission_without_a_reachable_planner_fails_within_seconds() -> None:
    with InProcessRouter() as router:
        session = open_session(router.client_config())
        token = declare_alive(session, KEYS, "executor", "stand-in")  # the runner checks executors first
        try:
            result, took = _mission(router)
            print(f"no planner: {took:.2f} s: {result.reason}")
            assert not result.ok and "no planner is alive" in result.reason and took < FAST_S

            env = {**os.environ, "FLEET_ZENOH_CONNECT": router.endpoint, "FLEET_NAME": KEYS.fleet}
            planner = subprocess.Popen([sys.executable, "-m", "services.cli", "planner"], env=env,
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            try:
                reply = asyncio.run(_answers(router.client_config(), 60.0))
                assert reply.ok and reply.plan is not None, reply.error  # the queryable is up and plans
                spec = MissionSpec(map="town", tasks=TOWN_TASKS, time_limit=30.0)
                runner = StopsThePlanner(planner, spec, router.client_config(), KEYS, progress=False)
                assert asyncio.run(runner.run()) == 0
                result = runner.result
                assert result is not None and runner.requested > 0.0, "the mission never asked the planner"
                error_after = runner.concluded - runner.requested
                print(f"hung planner: the error {error_after:.2f} s after the request "
                      f"(bounds {ERROR_AFTER_S[0]:.2f}-{ERROR_AFTER_S[1]:.2f} s): {result.reason}")
                assert not result.ok and "the planner is unreachable or failed" in result.reason, result.reason
                assert "no queryable answered" in result.reason, result.reason  # the router gave the query up
                assert ERROR_AFTER_S[0] <= error_after <= ERROR_AFTER_S[1], error_after
                assert error_after < runner.planner_wait_s() / 10  # not the planner's own timeout
            finally:
                planner.send_signal(signal.SIGCONT)
                planner.kill()
                planner.wait()
        finally:
            token.undeclare()
            session.close()
