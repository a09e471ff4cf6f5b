"""The service base: token, helpers, clean stop on signals or request, failures, all over real zenoh."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from common.bus.args import run_services
from common.bus.keys import Keys
from common.bus.liveliness import watch_alive
from common.bus.messages import PlanReply, PlanRequest, Pose, VehicleState
from common.bus.pubsub import Publisher, QueryError, drop_name, query, subscribe
from common.bus.service import Service
from common.bus.session import ZenohConfig, free_tcp_endpoint

REPO = Path(__file__).resolve().parents[1]
KEYS = Keys("test")
Sessions = Callable[..., zenoh.Session]


async def eventually(predicate: Callable[[], bool], timeout: float = 3.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.005)


class Echo(Service):
    """Turns poses into states and answers plan requests with the map's name ('slow' never)."""

    async def main(self) -> None:
        states = self.publisher(KEYS.vehicle("v1", "state"), VehicleState)

        def on_pose(pose: Pose, _key: str) -> None:
            states.put(VehicleState(vid=pose.vid, t=pose.t, owner=self.instance, mode="idle",
                                    x=pose.x, y=pose.y, z=pose.z, yaw=pose.yaw))

        async def on_plan(request: PlanRequest) -> PlanReply:
            if request.map == "slow":
                await asyncio.sleep(30)
            return PlanReply(ok=True, error=request.map)

        self.subscribe(KEYS.vehicle("v1", "pose"), Pose, on_pose)
        self.serve(KEYS.planner_plan, PlanRequest, PlanReply, on_plan)
        await self.stopped()


@pytest.mark.timeout(10)
def test_service_works_through_its_helpers_and_stop_releases_everything(
        zenoh_router: str, zsession: Sessions) -> None:
    other = zsession()
    echo = Echo("echo", "e1", ZenohConfig.client(zenoh_router), KEYS)

    async def scenario() -> int:
        running = asyncio.create_task(echo.run())
        alive = await watch_alive(other, KEYS, "echo")
        await alive.wait_until(lambda s: s == {"e1"}, 3)
        states = subscribe(other, KEYS.vehicle("v1", "state"), VehicleState)
        poses = Publisher(other, KEYS.vehicle("v1", "pose"), Pose)
        await eventually(lambda: poses.matched)
        other.put(KEYS.vehicle("v1", "pose"), b"garbage")
        poses.put(Pose(vid="v1", t=5.0, x=1, y=2, z=3, yaw=0))
        state, _key = await asyncio.wait_for(states.recv(), 2)
        assert (state.owner, state.x, state.y, state.z) == ("e1", 1, 2, 3)
        reply = await query(other, KEYS.planner_plan, PlanRequest(map="town", tasks={}), PlanReply, timeout=2)
        assert reply.error == "town"
        await eventually(lambda: echo.counters.total() == 1)

        slow = asyncio.create_task(query(other, KEYS.planner_plan, PlanRequest(map="slow", tasks={}),
                                         PlanReply, timeout=5))
        await asyncio.sleep(0.1)
        echo.stop()
        code = await asyncio.wait_for(running, 3)
        with pytest.raises(QueryError, match="service stopping"):
            await slow
        await alive.wait_until(lambda s: not s, 1)
        await eventually(lambda: not poses.matched)
        return code

    assert asyncio.run(scenario()) == 0
    assert dict(echo.counters) == {drop_name("malformed", Pose, KEYS.vehicle("v1", "pose")): 1}
    with pytest.raises(RuntimeError):
        _ = echo.session


class Crashing(Service):
    async def main(self) -> None:
        async def fail_soon() -> None:
            await asyncio.sleep(0.1)
            raise RuntimeError("controller diverged")

        self.spawn(fail_soon(), name="controller")
        await self.stopped()


@pytest.mark.timeout(10)
def test_a_failing_task_stops_the_service_with_exit_code_1(zenoh_router: str) -> None:
    assert asyncio.run(Crashing("crash", "c1", ZenohConfig.client(zenoh_router), KEYS).run()) == 1


@pytest.mark.timeout(10)
def test_no_router_gives_exit_code_1_without_hanging() -> None:
    config = ZenohConfig.client(free_tcp_endpoint(), connect_timeout_ms=200)
    start = time.monotonic()
    assert asyncio.run(Service("lonely", "l1", config, KEYS).run()) == 1
    assert time.monotonic() - start < 3


CHILD_SERVICE = """
import asyncio, sys
from common.bus.keys import Keys
from common.bus.service import Service
from common.bus.session import ZenohConfig
sys.exit(asyncio.run(Service("trivial", "t1", ZenohConfig.client(sys.argv[1]), Keys("test")).run()))
"""


@pytest.mark.timeout(20)
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_service_process_stops_cleanly_on_a_signal(
        zenoh_router: str, zsession: Sessions, sig: signal.Signals) -> None:
    _stop_child_on_a_signal(zsession(), [sys.executable, "-c", CHILD_SERVICE, zenoh_router], {"t1"}, sig)


def _stop_child_on_a_signal(watcher: zenoh.Session, argv: list[str], instances: set[str], sig: signal.Signals,
                            env: dict[str, str] | None = None, ready: Path | None = None) -> None:
    """Start `argv`, wait until its services `instances` are alive (and its `ready` file is there),
    send it `sig`: every service's token goes, the process exits 0 without a traceback."""
    child = subprocess.Popen(argv, cwd=REPO, stderr=subprocess.PIPE, text=True, env=env)

    async def scenario() -> None:
        alive = await watch_alive(watcher, KEYS, "trivial")
        await alive.wait_until(lambda s: s == instances, 10)
        if ready is not None:
            await eventually(ready.exists, 3.0)
        child.send_signal(sig)
        await alive.wait_until(lambda s: not s, 2)

    try:
        asyncio.run(scenario())
        _, stderr = child.communicate(timeout=5)
    finally:
        child.kill()
    assert child.returncode == 0, stderr
    assert "Traceback" not in stderr


CHILD_SERVICES = """
import sys
from common.bus.args import run_services
from common.bus.keys import Keys
from common.bus.service import Service
from common.bus.session import ZenohConfig
sys.exit(run_services([Service("trivial", name, ZenohConfig.client(sys.argv[1]), Keys("test")) for name in ("t1", "t2")]))
"""


@pytest.mark.timeout(20)
def test_services_side_by_side_are_ready_together_and_stop_together_on_a_signal(
        zenoh_router: str, zsession: Sessions, tmp_path: Path) -> None:
    """`run_services` (several radios' gateways in one process): both serve, the process tells its
    launcher it is ready, and one signal stops both (the last service's signal handler replaces the
    others', and the others stop because one of them ended)."""
    ready = tmp_path / "ready"
    _stop_child_on_a_signal(zsession(), [sys.executable, "-c", CHILD_SERVICES, zenoh_router], {"t1", "t2"},
                            signal.SIGTERM, env={**os.environ, "FLEET_READY_FILE": str(ready)}, ready=ready)


@pytest.mark.timeout(10)
def test_when_one_of_the_services_side_by_side_fails_the_others_stop(zenoh_router: str) -> None:
    """The process ends, with the failure's exit code, so that its supervisor restarts all of them."""
    config = ZenohConfig.client(zenoh_router)
    assert run_services([Service("trivial", "t3", config, KEYS), Crashing("crash", "c2", config, KEYS)]) == 1
