"""Typed pub/sub, drop accounting, request/reply and liveliness over a real in-process zenoh router."""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.liveliness import declare_alive, watch_alive
from common.bus.messages import MAX_MESSAGE_BYTES, Codec, PlanReply, PlanRequest, Pose, Telemetry
from common.bus.pubsub import (
    Counters,
    Publisher,
    QueryError,
    QueryTimeout,
    drop_name,
    find_queryable,
    query,
    serve,
    subscribe,
)
from common.bus.session import LEASE_MS
from common.domain.planfile import Task

REPO = Path(__file__).resolve().parents[1]
KEYS = Keys("test")
POSE_KEY = KEYS.vehicle("v1", "pose")
Sessions = Callable[..., zenoh.Session]


def pose(seq: int) -> Pose:
    return Pose(vid="v1", t=1000.0 + seq, x=1.0, y=2.0, z=0.5, yaw=0.1, seq=seq)


async def eventually(predicate: Callable[[], bool], timeout: float = 3.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.005)


@pytest.mark.timeout(10)
def test_typed_roundtrip_delivers_messages_in_order_with_their_keys(zsession: Sessions) -> None:
    tx, rx = zsession(), zsession()

    async def scenario() -> list[tuple[Pose, str]]:
        got: asyncio.Queue[tuple[Pose, str]] = asyncio.Queue()

        async def on_pose(msg: Pose, key: str) -> None:
            await got.put((msg, key))

        sub = subscribe(rx, KEYS.all_vehicles("pose"), Pose, on_pose)
        pub = Publisher(tx, POSE_KEY, Pose)
        await eventually(lambda: pub.matched)
        for seq in range(3):
            pub.put(pose(seq))
        received = [await asyncio.wait_for(got.get(), 2) for _ in range(3)]
        with pytest.raises(TypeError):
            pub.put(Telemetry(vid="v1", t=0, gateway="g", vbat=4, link_quality=1, sent=0,
                              dropped=0, cmd_rate_hz=0))  # type: ignore[arg-type]
        sub.close()
        await eventually(lambda: not pub.matched)
        pub.close()
        return received

    assert asyncio.run(scenario()) == [(pose(seq), POSE_KEY) for seq in range(3)]


@pytest.mark.timeout(10)
def test_malformed_messages_are_dropped_counted_logged_once_and_the_next_good_one_arrives(
        zsession: Sessions, caplog: pytest.LogCaptureFixture) -> None:
    tx, rx = zsession(), zsession()
    counters = Counters()
    bad_payloads = [
        b"\xc1 not msgpack",
        Codec(Task).encode(Task(start="a", goal="b")),  # another message type
        msgspec.msgpack.encode({**msgspec.structs.asdict(pose(0)), "extra": 1}),  # unknown field
        msgspec.msgpack.encode({**msgspec.structs.asdict(pose(0)), "x": "far"}),  # wrong field type
    ]

    async def scenario() -> Pose:
        sub = subscribe(rx, KEYS.all_vehicles("pose"), Pose, counters=counters)
        pub = Publisher(tx, POSE_KEY, Pose)
        await eventually(lambda: pub.matched)
        for payload in bad_payloads:
            tx.put(POSE_KEY, payload)
        pub.put(pose(7))
        msg, _key = await asyncio.wait_for(sub.recv(), 2)
        await eventually(lambda: counters.total() == len(bad_payloads))
        sub.close()
        return msg

    with caplog.at_level(logging.WARNING, logger="common.bus.pubsub"):
        assert asyncio.run(scenario()) == pose(7)
    assert dict(counters) == {drop_name("malformed", Pose, POSE_KEY): len(bad_payloads)}
    assert len([r for r in caplog.records if "malformed" in r.getMessage()]) == 1


@pytest.mark.timeout(15)
def test_oversized_payload_is_rejected_by_publisher_and_subscriber(zsession: Sessions) -> None:
    tx, rx = zsession(), zsession()
    counters = Counters()

    async def scenario() -> Pose:
        sub = subscribe(rx, POSE_KEY, Pose, counters=counters)
        # BLOCK: with the default DROP, a put queued behind the 4 MiB one may be dropped by zenoh
        pub = Publisher(tx, POSE_KEY, Pose, congestion_control=zenoh.CongestionControl.BLOCK)
        await eventually(lambda: pub.matched)
        with pytest.raises(ValueError, match="exceeds"):
            pub.put(Pose(vid="v1", t=0, x=0, y=0, z=0, yaw=0, source="x" * MAX_MESSAGE_BYTES))
        tx.put(POSE_KEY, bytes(MAX_MESSAGE_BYTES + 1), congestion_control=zenoh.CongestionControl.BLOCK)
        pub.put(pose(1))
        msg, _key = await asyncio.wait_for(sub.recv(), 5)
        sub.close()
        return msg

    assert asyncio.run(scenario()) == pose(1)
    assert dict(counters) == {drop_name("oversized", Pose, POSE_KEY): 1}


@pytest.mark.timeout(10)
def test_slow_consumer_loses_the_oldest_messages_and_counts_them(zsession: Sessions) -> None:
    tx, rx = zsession(), zsession()
    counters = Counters()
    sent, room = 20, 4

    async def scenario() -> list[int]:
        sub = subscribe(rx, POSE_KEY, Pose, counters=counters, maxlen=room)
        pub = Publisher(tx, POSE_KEY, Pose)
        await eventually(lambda: pub.matched)
        for seq in range(sent):
            pub.put(pose(seq))
        await eventually(lambda: counters.total() == sent - room)
        kept = [(await sub.recv())[0].seq for _ in range(room)]
        sub.close()
        return kept

    assert asyncio.run(scenario()) == list(range(sent - room, sent))
    assert dict(counters) == {drop_name("overflow", Pose, POSE_KEY): sent - room}


@pytest.mark.timeout(10)
def test_wait_returns_when_a_message_arrives_or_its_time_runs_out_and_leaves_nothing_behind(
        zsession: Sessions) -> None:
    """A control loop's wait for its next input or its tick (`Subscription.wait`, then `drain`)."""
    tx, rx = zsession(), zsession()

    async def scenario() -> None:
        loop = asyncio.get_running_loop()
        sub = subscribe(rx, POSE_KEY, Pose)
        pub = Publisher(tx, POSE_KEY, Pose)
        await eventually(lambda: pub.matched)
        start = time.monotonic()
        assert not await sub.wait(0.05)  # nothing sent: its time runs out
        assert 0.04 <= time.monotonic() - start < 0.5
        loop.call_later(0.05, pub.put, pose(1))
        start = time.monotonic()
        assert await sub.wait(5.0)  # woken by the arrival, long before its time
        assert time.monotonic() - start < 1.0
        assert [m.seq for m, _ in sub.drain()] == [1]
        pub.put(pose(2))
        await eventually(lambda: bool(sub._mailbox._items))
        others: list[int] = []
        loop.call_soon(others.append, 1)
        assert await sub.wait(0.0)  # already waiting: at once, but the loop's other work ran meanwhile
        assert others == [1]
        assert [m.seq for m, _ in sub.drain()] == [2]
        for _ in range(200):  # no timer and no task is left behind
            assert not await sub.wait(0.0)
        assert len(loop._scheduled) == 0 or all(h.cancelled() for h in loop._scheduled)  # type: ignore[attr-defined]
        assert len(asyncio.all_tasks()) == 1
        sub.close()

    asyncio.run(scenario())


@pytest.mark.timeout(10)
def test_a_failing_handler_is_counted_and_the_subscription_goes_on(zsession: Sessions) -> None:
    tx, rx = zsession(), zsession()
    counters = Counters()

    async def scenario() -> list[int]:
        seen: list[int] = []

        def on_pose(msg: Pose, _key: str) -> None:
            if msg.seq == 1:
                raise RuntimeError("bug in handler")
            seen.append(msg.seq)

        sub = subscribe(rx, POSE_KEY, Pose, on_pose, counters=counters)
        pub = Publisher(tx, POSE_KEY, Pose)
        await eventually(lambda: pub.matched)
        for seq in range(3):
            pub.put(pose(seq))
        await eventually(lambda: len(seen) == 2)
        sub.close()
        return seen

    assert asyncio.run(scenario()) == [0, 2]
    assert dict(counters) == {drop_name("handler", Pose, POSE_KEY): 1}


async def plan_handler(request: PlanRequest) -> PlanReply:
    if request.map == "missing":
        raise FileNotFoundError("no map called 'missing'")
    if request.map == "slow":
        await asyncio.sleep(30)
    return PlanReply(ok=True, error=f"planned {sorted(request.tasks)} on {request.map}")


def plan_request(map_name: str) -> PlanRequest:
    return PlanRequest(map=map_name, tasks={"v1": Task(start="p1", goal="p2")})


@pytest.mark.timeout(15)
def test_query_reply_error_reply_malformed_request_timeout_and_no_queryable(zsession: Sessions) -> None:
    server, client = zsession(), zsession()
    counters = Counters()
    key = KEYS.planner_plan

    async def scenario() -> None:
        queryable = serve(server, key, PlanRequest, PlanReply, plan_handler, counters=counters)
        querier = client.declare_querier(key)
        await eventually(lambda: querier.matching_status.matching)
        reply = await query(client, key, plan_request("town"), PlanReply, timeout=2)
        assert reply == PlanReply(ok=True, error="planned ['v1'] on town")

        with pytest.raises(QueryError, match="FileNotFoundError: no map called 'missing'"):
            await query(client, key, plan_request("missing"), PlanReply, timeout=2)
        with pytest.raises(QueryError, match="malformed PlanRequest request"):
            await query(client, key, pose(0), PlanReply, timeout=2)

        ticks = 0

        async def ticker() -> None:
            nonlocal ticks
            while True:
                await asyncio.sleep(0.01)
                ticks += 1

        ticking = asyncio.create_task(ticker())
        start = time.monotonic()
        with pytest.raises(QueryTimeout):
            await query(client, key, plan_request("slow"), PlanReply, timeout=0.3)
        assert 0.3 <= time.monotonic() - start < 1.0
        assert ticks >= 10, "the event loop was blocked while waiting for the reply"
        ticking.cancel()

        with pytest.raises(QueryError, match="no queryable"):
            await query(client, KEYS.root + "/nobody/home", plan_request("town"), PlanReply, timeout=2)

        pending = asyncio.create_task(query(client, key, plan_request("slow"), PlanReply, timeout=5))
        await asyncio.sleep(0.2)
        queryable.close()
        with pytest.raises(QueryError, match="service stopping"):
            await pending

    asyncio.run(scenario())
    assert counters[f"query_error:{KEYS.planner_plan}"] == 1
    assert counters[drop_name("malformed", PlanRequest, KEYS.planner_plan)] == 1


@pytest.mark.timeout(15)
def test_a_query_waits_for_a_queryable_declared_after_it_was_sent(zsession: Sessions) -> None:
    """A client that saw a service come alive (its token comes first) and asks it at once."""
    server, client = zsession(), zsession()
    key = KEYS.planner_plan

    async def scenario() -> None:
        with pytest.raises(QueryError, match="no queryable"):
            await query(client, key, plan_request("town"), PlanReply, timeout=2)
        assert not await find_queryable(client, key, 0.2)

        async def serve_late() -> None:
            await asyncio.sleep(0.5)
            serve(server, key, PlanRequest, PlanReply, plan_handler)

        late = asyncio.create_task(serve_late())
        start = time.monotonic()
        reply = await query(client, key, plan_request("town"), PlanReply, timeout=2, find_s=3)
        assert reply.ok and 0.5 <= time.monotonic() - start < 2.0
        await late

    asyncio.run(scenario())


@pytest.mark.timeout(10)
def test_liveliness_set_follows_tokens_appearing_and_disappearing(zsession: Sessions) -> None:
    watcher, first, second = zsession(), zsession(), zsession()

    async def scenario() -> None:
        changes: list[tuple[str, bool]] = []
        early = declare_alive(first, KEYS, "executor", "e0")
        await (await watch_alive(watcher, KEYS, "executor")).wait_until(lambda s: "e0" in s, 2)
        executors = await watch_alive(watcher, KEYS, "executor", lambda i, alive, _s: changes.append((i, alive)))
        assert executors.instances == {"e0"}, "a token that existed before watching is known at once"

        tokens = [declare_alive(second, KEYS, "executor", "e1"),
                  declare_alive(second, KEYS, "gateway", "g1")]  # another service: not in the set
        assert await executors.wait_until(lambda s: s == {"e0", "e1"}, 2) == {"e0", "e1"}
        early.undeclare()
        await executors.wait_until(lambda s: s == {"e1"}, 2)
        second.close()
        await executors.wait_until(lambda s: not s, 2)
        del tokens
        assert changes == [("e0", True), ("e1", True), ("e0", False), ("e1", False)]
        executors.close()

    asyncio.run(scenario())


@pytest.mark.timeout(10)
def test_a_wrong_gone_is_corrected_from_the_routers_snapshot(zsession: Sessions) -> None:
    """Under load zenoh once told a surviving executor that its own token had gone instead of its
    killed peer's: every "gone" is followed by a liveliness query whose answer wins."""
    watcher, first, second = zsession(), zsession(), zsession()

    async def scenario() -> None:
        changes: list[tuple[str, bool]] = []
        mine, peer = declare_alive(first, KEYS, "executor", "e1"), declare_alive(second, KEYS, "executor", "e2")
        executors = await watch_alive(watcher, KEYS, "executor", lambda i, alive, _s: changes.append((i, alive)))
        await executors.wait_until(lambda s: s == {"e1", "e2"}, 2)
        second.close()  # e2 really goes...
        executors._apply(KEYS.alive("executor", "e1"), False)  # ...and zenoh says e1 (as it did once)
        assert await executors.wait_until(lambda s: s == {"e1"}, 2) == {"e1"}
        assert changes[-1] in (("e1", True), ("e2", False)), changes
        assert ("e1", False) in changes and changes.count(("e2", False)) == 1
        executors.close()
        del mine, peer

    asyncio.run(scenario())


CHILD_WITH_TOKEN = """
import sys, time
from common.bus.keys import Keys
from common.bus.liveliness import declare_alive
from common.bus.session import ZenohConfig, open_session
session = open_session(ZenohConfig.client(sys.argv[1]))
token = declare_alive(session, Keys("test"), "executor", "child")
time.sleep(60)
"""


@pytest.mark.timeout(20)
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGSTOP], ids=["killed", "hung"])
def test_token_of_a_killed_or_hung_process_disappears_within_a_second(
        zenoh_router: str, zsession: Sessions, sig: signal.Signals) -> None:
    watcher = zsession()
    child = subprocess.Popen([sys.executable, "-c", CHILD_WITH_TOKEN, zenoh_router], cwd=REPO)

    async def scenario() -> float:
        executors = await watch_alive(watcher, KEYS, "executor")
        await executors.wait_until(lambda s: "child" in s, 10)
        start = time.monotonic()
        os.kill(child.pid, sig)
        await executors.wait_until(lambda s: "child" not in s, 2)
        return time.monotonic() - start

    try:
        gone_after = asyncio.run(scenario())
    finally:
        child.kill()
        child.wait()
    print(f"token of a {'killed' if sig == signal.SIGKILL else 'hung'} process gone after {gone_after:.3f} s")
    assert gone_after < 1.0
    if sig == signal.SIGSTOP:  # only the lease can tell a hung process from a quiet one
        assert gone_after >= LEASE_MS / 1000 * 0.9


def test_the_router_hop_benchmark_measures_every_transport(tmp_path: Path) -> None:
    """`bench.router_hop` (docs/bus.md, "The hot path and the router"): frames reach every subscriber
    through the router, over peer links, in shared memory and through a router in a busy process (whose
    own subscriber hears them too), and the table and the PNG come out.
    Not in the compute lane: its processes must get the CPU within its 1.5 s of settling (at idle
    priority beside the flights a peer subscriber connected after the publisher had finished and
    got no frame)."""
    run = subprocess.run([sys.executable, "-m", "bench.router_hop", "--bodies", "8", "--seconds", "1", "--warmup", "50",
                          "--out", str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=1100)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = [line.split() for line in run.stdout.splitlines() if line.split()[1:2] == ["subscriber"]]
    assert sorted(row[0] for row in rows) == ["busy-router", "busy-router", "peer", "peer", "router", "router", "shm",
                                              "shm"], run.stdout
    assert all(int(row[2]) > 0 for row in rows), run.stdout
    busy = [line.split() for line in run.stdout.splitlines() if line.split()[1:3] == ["busy", "listener"]]
    assert len(busy) == 1 and int(busy[0][3]) > 0, run.stdout
    assert (tmp_path / "router_hop.png").stat().st_size > 10_000
