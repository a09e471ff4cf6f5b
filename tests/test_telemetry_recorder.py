"""The telemetry recorder keeps a mission's end on a busy machine: it runs at a lower priority and
lags the 100 Hz streams, so what arrived but was not drawn when the fleet stops is drawn before the
recording closes, and a backlog is thinned by the samples' own times (a live-view run lost the last
0.7 m of a vehicle's path and its `done`: drawn by arrival time, a backlog kept its oldest sample
of every 50 ms of drawing and the stop threw the rest away)."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.messages import PlanModel, PlanStep, Telemetry, VehiclePlan, VehicleState
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import ZenohConfig
from services.telemetry.service import TelemetryService

KEYS = Keys("rec")
REPO = Path(__file__).resolve().parents[1]
DELIVERY_S = 0.5
"""s for zenoh's threads to hand the burst to the mailboxes while the event loop is held."""


def battery(t: float) -> Telemetry:
    return Telemetry(vid="cf1", t=t, gateway="r0", vbat=4.0, link_quality=1.0, sent=0, dropped=0, cmd_rate_hz=0.0)


def hold_the_loop_while(publish: Callable[[], None]) -> None:
    """Publish from the event loop without yielding to it, as a starved process would see a burst."""
    publish()
    time.sleep(DELIVERY_S)


def test_a_subscription_closed_and_drained_hands_back_what_its_handler_had_not_taken(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    handled: list[float] = []
    pub_session = zsession()

    async def main() -> list[float]:
        sub = subscribe(zsession(), KEYS.vehicle("cf1", "telemetry"), Telemetry, lambda m, _k: handled.append(m.t))
        pub = Publisher(pub_session, KEYS.vehicle("cf1", "telemetry"), Telemetry)
        await asyncio.sleep(0.3)  # the subscriber reaches the router
        hold_the_loop_while(lambda: [pub.put(battery(float(i))) for i in range(50)])
        left = [m.t for m, _key in sub.close_and_drain()]
        pub.put(battery(99.0))  # after the close: not received
        await asyncio.sleep(0.3)
        sub.close()  # a second close (a service's own closers) is harmless
        return left

    left = asyncio.run(main())
    assert handled == [] and left == [float(i) for i in range(50)]


def test_the_recorder_draws_its_backlog_at_the_stop_thinned_by_the_samples_times(
        zenoh_router: str, zsession: Callable[..., zenoh.Session], tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    session = zsession()
    steps = [PlanStep(node="A", t=0.0, pos=(0.0, 0.0, 0.0), kind="parking"),
             PlanStep(node="B", t=2.0, pos=(1.0, 0.0, 0.0), kind="waypoint", edge="drive")]
    t0 = time.time()
    states = [VehicleState(vid="cf1", t=t0 + 0.01 * i, owner="e1", mode="driving" if i < 199 else "done",
                           x=i / 199, y=0.0, z=0.0, yaw=0.0, mission="m1") for i in range(200)]  # 2 s at 100 Hz

    async def main() -> None:
        svc = TelemetryService("t1", ZenohConfig.client(zenoh_router), KEYS, out=tmp_path, max_hz=20.0)
        run = asyncio.create_task(svc.run())
        plan = Publisher(session, KEYS.vehicle("cf1", "plan"), VehiclePlan)
        state = Publisher(session, KEYS.vehicle("cf1", "state"), VehicleState)
        deadline = time.monotonic() + 10.0
        while svc.recording is None:  # the plan opens the mission's recording
            assert time.monotonic() < deadline, "no recording opened"
            plan.put(VehiclePlan(vid="cf1", mission="m1", map="town", steps=steps, model=PlanModel()))
            await asyncio.sleep(0.2)
        hold_the_loop_while(lambda: [state.put(s) for s in states])
        svc.stop()  # the fleet stops right after the mission: the whole burst is still waiting
        assert await run == 0

    asyncio.run(main())
    bodies: list[tuple[int, float]] = []
    modes: list[tuple[int, str]] = []
    for chunk in RrdReader(str(tmp_path / "m1.rrd")).store().stream():
        batch = chunk.to_record_batch()
        if "time" not in batch.schema.names:
            continue
        times = batch.column("time").cast("int64").to_pylist()
        if chunk.entity_path == "/vehicles/cf1/body":
            bodies += [(t, c[0][0]) for t, c in zip(times, batch.column("Cylinders3D:centers").to_pylist(), strict=True)]
        elif chunk.entity_path == "/vehicles/cf1/mode":
            modes += [(t, m[0]) for t, m in zip(times, batch.column("StateChange:state").to_pylist(), strict=True)]
    assert [m for _, m in sorted(modes)] == ["driving", "done"]
    xs = [x for _, x in sorted(bodies)]
    assert 38 <= len(xs) <= 41, xs  # 2 s drawn at 20 Hz by the states' own times
    assert xs[-1] > 0.97, xs  # the end of the path is there


@pytest.mark.compute
def test_the_recorder_cost_benchmark_runs_and_plots(tmp_path: Path) -> None:
    """`bench.recorder_cost` (bench/ sits above tests/ in the import contracts: run as a user does)."""
    run = subprocess.run([sys.executable, "-m", "bench.recorder_cost", "--vehicles", "1", "2", "--seconds", "2",
                          "--out", str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = [line.split() for line in run.stdout.splitlines() if line.split()[:1] in (["1"], ["2"])]
    assert [row[0] for row in rows] == ["1", "2"] and all(float(row[1]) > 0.0 for row in rows), run.stdout
    assert (tmp_path / "recorder_cost.png").stat().st_size > 10_000
