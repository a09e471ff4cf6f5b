"""Where a local bring-up's router runs: compose's `fleet router`, a process of its own, not the
process that brought the fleet up and runs Python besides (docs/bus.md, "A router in a busy
process"); `router_process` for benchmarks that play parts of the fleet themselves."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest

from common.bus.liveliness import watch_alive
from common.bus.messages import Telemetry
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import ZenohConfig, open_session
from common.deploy.launcher import status
from common.deploy.local import bring_up, router_process


def running(pid: int) -> bool:
    """The process is there and not a zombie (one killed after its grace period is not reaped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.timeout(60)
def test_a_bring_up_runs_its_router_as_a_process_of_its_own(tmp_path: Path) -> None:
    """`only` names services: the router comes with them (`fleet mission team --local` brings up
    three)."""
    with bring_up(tmp_path / "run", {"FLEET_NAME": "localrouter"}, only=["planner"]) as fleet:
        procs = status(fleet.run_dir)
        assert fleet.router is None
        assert sorted(p["service"] for p in procs) == ["planner", "router"] and all(p["alive"] for p in procs)

        async def planners() -> frozenset[str]:
            session = open_session(fleet.client_config())
            try:
                alive = await watch_alive(session, fleet.keys, "planner")
                found = await alive.wait_until(lambda s: len(s) == 1, timeout=20)
                alive.close()
                return found
            finally:
                session.close()

        assert len(asyncio.run(planners())) == 1  # reached through the router process
    assert [p["instance"] for p in procs if running(p["pid"])] == []  # all stopped


@pytest.mark.timeout(60)
def test_router_process_carries_messages_and_is_gone_after(tmp_path: Path) -> None:
    with router_process(tmp_path) as endpoint:
        (router,) = status(tmp_path)
        assert router["service"] == "router" and router["alive"]
        assert endpoint.startswith("tcp/127.0.0.1:") and endpoint in router["argv"]
        sender, receiver = (open_session(ZenohConfig.client(endpoint)) for _ in range(2))

        async def round_trip() -> list[str]:
            heard: list[str] = []
            sub = subscribe(receiver, "lr/vehicle/cf1/telemetry", Telemetry, lambda m, _k: heard.append(m.vid))
            await asyncio.sleep(0.3)
            Publisher(sender, "lr/vehicle/cf1/telemetry", Telemetry).put(
                Telemetry(vid="cf1", t=time.time(), gateway="g", vbat=4.0, link_quality=1.0, sent=0, dropped=0,
                          cmd_rate_hz=0.0, owner=""))
            for _ in range(100):
                if heard:
                    break
                await asyncio.sleep(0.02)
            sub.close()
            return heard

        try:
            assert asyncio.run(round_trip()) == ["cf1"]
        finally:
            sender.close()
            receiver.close()
    assert not running(router["pid"])
