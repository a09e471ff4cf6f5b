"""The planner unreachable (issue 8): a mission fails fast with a clear message, within seconds, not
after the planning timeout (here 40 s): no planner alive at all, or one that hangs (SIGSTOP: its
lease expires and the router gives up the query)."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time

import pytest

from common.bus.keys import Keys
from common.bus.liveliness import declare_alive, watch_alive
from common.bus.session import InProcessRouter, open_session
from services.mission.runner import MissionResult, MissionRunner, MissionSpec
from tests.support.fleet_faults import TOWN_TASKS

KEYS = Keys("plannerfault")
FAST_S = 3.0


def _mission(router: InProcessRouter) -> tuple[MissionResult, float]:
    """Run a mission against `router`; its result and how long it took."""
    spec = MissionSpec(map="town", tasks=TOWN_TASKS, time_limit=30.0)
    runner = MissionRunner(spec, router.client_config(), KEYS, progress=False)
    started = time.monotonic()
    assert asyncio.run(runner.run()) == 0
    assert runner.result is not None
    return runner.result, time.monotonic() - started


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
                async def wait_planner() -> None:
                    alive = await watch_alive(session, KEYS, "planner")
                    await alive.wait_until(bool, timeout=30)
                    alive.close()

                asyncio.run(wait_planner())
                time.sleep(1.0)  # its queryable is declared after its token
                planner.send_signal(signal.SIGSTOP)
                result, took = _mission(router)
                print(f"hung planner: {took:.2f} s: {result.reason}")
                assert not result.ok and "planner" in result.reason and took < FAST_S
            finally:
                planner.send_signal(signal.SIGCONT)
                planner.kill()
                planner.wait()
        finally:
            token.undeclare()
            session.close()
