"""The mocap bridge: the `motioncapture` mock backend end to end (rate, rigid-body mapping, capture
stamps), the sim backend (noisy poses of the simulated motion capture, a vanished body reported and not
frozen), and the tracker's rate limit and lost / found logic on synthetic frames."""

from __future__ import annotations

import asyncio
import math
import statistics
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.messages import Pose, SimTruth, VehicleEvent
from common.bus.pubsub import subscribe
from common.bus.session import ZenohConfig
from common.deploy.radios import MocapModel, simulated_radios
from common.errors import InputError
from services.mocap_bridge.bridge import MocapBridge
from services.mocap_bridge.config import MocapConfig, load_mocap
from services.mocap_bridge.tracker import BodyTracker, yaw_of
from services.sim.crazyflie.service import SimService
from tests.support.loadgen import running

KEYS = Keys()


class Poses:
    """Every pose and mocap event, with its arrival time."""

    def __init__(self, session: zenoh.Session) -> None:
        self.poses: dict[str, list[tuple[float, Pose]]] = defaultdict(list)
        self.events: list[VehicleEvent] = []
        subscribe(session, KEYS.all_vehicles("pose"), Pose, lambda p, _k: self.poses[p.vid].append((time.time(), p)))
        subscribe(session, KEYS.all_vehicles("event"), VehicleEvent, lambda e, _k: self.events.append(e))

    def since(self, vid: str, t: float) -> list[Pose]:
        return [p for at, p in self.poses[vid] if at >= t]


def test_mock_backend_feeds_mapped_poses_at_the_configured_rate(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    config = MocapConfig(backend="mock", bodies={"cf_a": "v1", "cf_b": "v2"}, options={
        "rigid_bodies": "cf_a(1.0,2.0,0.5,1,0,0,0);cf_b(-0.5,0.25,0.0,0.7071068,0,0,0.7071068);wand(0,0,1,1,0,0,0)"})
    bridge = MocapBridge(config, ZenohConfig.client(zenoh_router))
    session = zsession()

    async def main() -> None:
        seen = Poses(session)
        async with running(bridge):
            await asyncio.sleep(1.0)
            t0 = time.time()
            await asyncio.sleep(2.0)
            t1 = time.time()
        v1, v2 = seen.since("v1", t0), seen.since("v2", t0)
        rate = len(v1) / (t1 - t0)
        print(f"mock backend: {rate:.1f} poses/s per body")
        assert 85.0 <= rate <= 102.0 and abs(len(v1) - len(v2)) <= 2
        assert set(seen.poses) == {"v1", "v2"}  # the unmapped wand is ignored
        p = v1[-1]
        assert (p.x, p.y, p.z) == pytest.approx((1.0, 2.0, 0.5)) and p.yaw == pytest.approx(0.0, abs=1e-6)
        assert p.source == "mock" and v2[-1].yaw == pytest.approx(math.pi / 2, abs=1e-5)
        assert [q.seq for q in v1] == list(range(v1[0].seq, v1[0].seq + len(v1)))
        assert all(b.t > a.t for a, b in zip(v1, v1[1:], strict=False)) and abs(v1[-1].t - t1) < 0.1
        assert bridge.counters.total() == 0 and not seen.events
        assert bridge.published["v1"] >= len(v1)

    asyncio.run(main())


def test_sim_backend_publishes_noisy_poses_and_reports_a_vanished_body(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    cfg = ZenohConfig.client(zenoh_router)
    spec = simulated_radios({"v1": (0.5, -0.25, 0.0), "v2": (1.0, 1.0, 0.0)}, per_radio=2)
    noise = MocapModel(pos_std=0.002, latency_s=0.01, seed=4)
    bridge = MocapBridge(MocapConfig(), cfg)
    session = zsession()

    async def main() -> None:
        seen = Poses(session)
        truth: dict[str, SimTruth] = {}
        subscribe(session, KEYS.all_sim_truth, SimTruth, lambda m, _k: truth.__setitem__(m.vid, m))
        sim = SimService(spec, cfg, mocap=noise)
        async with running(bridge):
            async with running(sim):
                await asyncio.sleep(1.0)
                t0 = time.time()
                await asyncio.sleep(2.0)
                t1 = time.time()
            v1 = seen.since("v1", t0)
            await asyncio.sleep(0.5)  # the simulator is gone: its vehicles vanish from the capture
            gone = time.time()
            await asyncio.sleep(0.5)
            assert not seen.since("v1", gone) and not seen.since("v2", gone)  # not frozen: no poses at all
            lost = {e.vid for e in seen.events if e.kind == "mocap_lost"}
            assert lost == {"v1", "v2"}
            async with running(SimService(spec, cfg, mocap=noise)):  # back again
                await asyncio.sleep(0.5)
            assert {e.vid for e in seen.events if e.kind == "mocap_found"} == {"v1", "v2"}
        rate = len(v1) / (t1 - t0)
        print(f"sim backend: {rate:.1f} poses/s per body")
        assert 85.0 <= rate <= 102.0
        errors = [p.x - 0.5 for p in v1]
        assert abs(statistics.fmean(errors)) < 0.001 and 0.0015 < statistics.stdev(errors) < 0.0025
        assert all(p.source == "sim" and p.z == pytest.approx(0.0, abs=0.01) for p in v1)
        delays = [at - p.t for at, p in seen.poses["v1"] if t0 <= at <= t1]
        assert min(delays) >= 0.01  # capture stamp is the truth's time; published after the latency

    asyncio.run(main())


def test_tracker_limits_the_rate_and_reports_lost_and_found() -> None:
    tracker = BodyTracker({"a": "v1", "b": "v2"}, rate_hz=100.0, lost_after_s=0.1)
    assert tracker.check(5.0) == []  # nothing is lost before the system's first frame
    published: dict[str, list[float]] = defaultdict(list)
    events = []
    for k in range(200):  # 1 s of 200 Hz frames; "b" is out of view from 0.3 s to 0.6 s; "c" is not ours
        t = k * 0.005
        seen = {"a": (0.0, 0.0, 1.0, 0.0), "c": (0.0, 0.0, 0.0, 0.0)}
        if not 0.3 <= t < 0.6:
            seen["b"] = (1.0, 0.0, 1.0, 0.0)
        poses, caused = tracker.frame(t, seen, t)
        events += [(t, *e[:2]) for e in caused + tracker.check(t)]
        for p in poses:
            published[p.vid].append(p.t)
    assert 99 <= len(published["v1"]) <= 101 and tracker.seq["v1"] == len(published["v1"])
    assert [e[1:] for e in events] == [("v2", "mocap_lost"), ("v2", "mocap_found")]
    assert events[0][0] == pytest.approx(0.4, abs=0.01) and events[1][0] == pytest.approx(0.6)
    assert not [t for t in published["v2"] if 0.3 <= t < 0.6]  # nothing while it is out of view
    assert tracker.ignored == {"c": 200}
    nan, _ = tracker.frame(1.0, {"a": (math.nan, 0.0, 0.0, 0.0)}, 1.0)
    assert nan == []  # an occluded body reported as NaN is not seen
    assert [e[:2] for e in tracker.check(1.2)] == [("v1", "mocap_lost"), ("v2", "mocap_lost")]
    identity = BodyTracker({}, rate_hz=100.0, lost_after_s=0.1)
    poses, _ = identity.frame(0.0, {"cf7": (0.0, 0.0, 0.0, 0.0), "bad/name": (0.0, 0.0, 0.0, 0.0)}, 0.0)
    assert [p.vid for p in poses] == ["cf7"] and identity.ignored == {"bad/name": 1}
    assert yaw_of(math.cos(0.3), 0.0, 0.0, math.sin(0.3)) == pytest.approx(0.6)


def test_mocap_config_errors(tmp_path: Path) -> None:
    path = tmp_path / "mocap.yaml"
    path.write_text("backend: vicon\noptions: {hostname: 10.0.0.5}\nbodies: {cf_01: cf1}\n")
    assert load_mocap(path).options == {"hostname": "10.0.0.5"}
    for text, field in [("backend: kinect\n", "backend"), ("rate_hz: 0\n", "rate_hz"),
                        ("bodies: {a: cf1, b: cf1}\n", "bodies.b"), ("bodies: {a: 'x/y'}\n", "bodies.a"),
                        ("latency_s: -1\n", "latency_s")]:
        path.write_text(text)
        with pytest.raises(InputError) as err:
            load_mocap(path)
        assert err.value.field == field
