"""The mocap bridge: the `motioncapture` mock backend end to end (rate, rigid-body mapping, capture
stamps; a y-up system's frame taken to the map's, the start-up check naming a missing body), the sim
backend (noisy poses of the simulated motion capture, a vanished body reported and not frozen), the
tracker's rate limit and lost / found logic on synthetic frames, the frame transform, the mapping
errors, and the shipped example files."""

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
from hypothesis import given, settings
from hypothesis import strategies as st

from common.bus.keys import Keys
from common.bus.messages import Pose, PoseFrame, SimTruth, VehicleEvent
from common.bus.pubsub import subscribe
from common.bus.session import ZenohConfig
from common.deploy.radios import MocapModel, simulated_radios
from common.errors import InputError
from services.mocap_bridge.bridge import MocapBridge
from services.mocap_bridge.config import FrameSpec, MocapConfig, load_mocap
from services.mocap_bridge.frame import FrameTransform, wrap_angle
from services.mocap_bridge.tracker import BodyTracker, StartupReport, yaw_of
from services.sim.crazyflie.service import SimService
from tests.support.loadgen import running

KEYS = Keys()
REPO = Path(__file__).resolve().parents[1]


class Poses:
    """Every pose of the bridge's frames (`poses`) and of its per-vehicle keys (`vehicle_poses`), and
    every mocap event, with its arrival time."""

    def __init__(self, session: zenoh.Session) -> None:
        self.poses: dict[str, list[tuple[float, Pose]]] = defaultdict(list)
        self.vehicle_poses: dict[str, list[tuple[float, Pose]]] = defaultdict(list)
        self.events: list[VehicleEvent] = []
        subscribe(session, KEYS.mocap_frame, PoseFrame, self._on_frame)
        subscribe(session, KEYS.all_vehicles("pose"), Pose,
                  lambda p, _k: self.vehicle_poses[p.vid].append((time.time(), p)))
        subscribe(session, KEYS.all_vehicles("event"), VehicleEvent, lambda e, _k: self.events.append(e))

    def _on_frame(self, frame: PoseFrame, _key: str) -> None:
        now = time.time()
        for p in frame.poses:
            self.poses[p.vid].append((now, frame.pose(p)))

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
        one = [p for at, p in seen.vehicle_poses["v1"] if t0 <= at <= t1]  # per vehicle: 20 Hz
        assert 17.0 <= len(one) / (t1 - t0) <= 21.0, len(one)
        assert set(seen.vehicle_poses) == {"v1", "v2"}
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
        frames: list[tuple[float, PoseFrame]] = []
        subscribe(session, KEYS.mocap_frame, PoseFrame, lambda f, _k: frames.append((time.time(), f)))
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
        # a frame says when the bridge had it: the capture system's latency before, ours after
        stamped = [(at, f) for at, f in frames if t0 <= at <= t1]
        assert len(stamped) > 150
        assert all(f.t + 0.01 <= f.arrived <= at for at, f in stamped)

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
                        ("latency_s: -1\n", "latency_s"), ("backend: vicon\nframe: {up: x}\n", "frame.up"),
                        ("backend: vicon\nframe: {origin: [0, 0]}\n", "frame.origin"),
                        ("backend: vicon\nframe: {origin: [0, .nan, 0]}\n", "frame.origin"),
                        ("backend: vicon\nframe: {yaw: 90}\n", "frame"), ("frame: {up: y}\n", "frame"),
                        ("startup_wait_s: -1\n", "startup_wait_s")]:
        path.write_text(text)
        with pytest.raises(InputError) as err:
            load_mocap(path)
        assert err.value.field == field and err.value.source == str(path), text


def test_a_rigid_body_named_twice_is_an_error_naming_both_lines(tmp_path: Path) -> None:
    path = tmp_path / "mocap.yaml"
    path.write_text("backend: vicon\nbodies:\n  cf_01: cf1\n  cf_02: cf2\n  cf_01: cf3\n")
    with pytest.raises(InputError) as err:
        load_mocap(path)
    assert err.value.field == "bodies.cf_01"
    assert "rigid body cf_01 named twice (lines 3 and 5)" in err.value.problem
    path.write_text("backend: vicon\nbackend: mock\n")
    with pytest.raises(InputError) as err:
        load_mocap(path)
    assert err.value.field == "backend" and "key backend named twice" in err.value.problem


@pytest.mark.parametrize("system", ["vicon", "optitrack", "qualisys", "vrpn"])
def test_shipped_examples_load(system: str) -> None:
    config = load_mocap(REPO / "deploy" / f"mocap-{system}.yaml")
    assert config.backend == system and config.options["hostname"]
    assert sorted(config.bodies.values()) == [f"cf{k}" for k in range(1, 9)]
    assert config.frame.up == ("y" if system == "optitrack" else "z")


def _pose(transform: FrameTransform, p, axis, angle: float):
    """A body at `p` turned by `angle` about the unit `axis` (both in the system's frame), transformed."""
    h = angle / 2.0
    return transform.pose(p, math.cos(h), *(math.sin(h) * a for a in axis))


def test_frame_transform() -> None:
    identity = FrameTransform()
    assert identity.identity
    assert _pose(identity, (1.0, 2.0, 0.5), (0, 0, 1), 0.3) == pytest.approx((1.0, 2.0, 0.5, 0.3))
    y_up = FrameTransform(up="y")
    # a body 0.5 m above the floor of a y-up system, 2 m along its -z axis: map y is the system's -z
    assert _pose(y_up, (1.0, 0.5, -2.0), (0, 1, 0), 0.0) == pytest.approx((1.0, 2.0, 0.5, 0.0))
    # turned 30 deg about the system's up axis (its y): a yaw of 30 deg, CCW seen from above
    assert _pose(y_up, (0.0, 0.0, 0.0), (0, 1, 0), math.radians(30))[3] == pytest.approx(math.radians(30))
    # a roll about the system's x axis is no yaw
    assert _pose(y_up, (0.0, 0.0, 0.0), (1, 0, 0), 0.4)[3] == pytest.approx(0.0, abs=1e-12)
    # the map's origin at the system's (2, 0.1, -1) (y up), its +x axis along the system's -z (map y):
    # 90 deg CCW from the system's +x
    placed = FrameTransform(up="y", origin=(2.0, 0.1, -1.0), yaw_deg=90.0)
    assert placed.position((2.0, 0.1, -1.0)) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert placed.position((2.0, 1.1, -2.0)) == pytest.approx((1.0, 0.0, 1.0), abs=1e-12)  # 1 m along its +x, 1 m up
    assert placed.position((3.0, 0.1, -1.0)) == pytest.approx((0.0, -1.0, 0.0), abs=1e-12)  # the system's +x: map -y
    assert _pose(placed, (2.0, 0.1, -1.0), (0, 1, 0), math.radians(90))[3] == pytest.approx(0.0, abs=1e-12)
    assert _pose(placed, (2.0, 0.1, -1.0), (0, 1, 0), 0.0)[3] == pytest.approx(-math.pi / 2)
    assert wrap_angle(3 * math.pi) == pytest.approx(math.pi) and wrap_angle(-math.pi / 2) == pytest.approx(-math.pi / 2)
    nan = y_up.pose((math.nan, 0.0, 0.0), 1.0, 0.0, 0.0, 0.0)
    assert math.isnan(nan[0])  # an occluded body stays not seen
    with pytest.raises(ValueError):
        FrameTransform(up="x")


_unit = st.floats(-1.0, 1.0)


@settings(max_examples=300, deadline=None)
@given(q=st.tuples(_unit, _unit, _unit, _unit).filter(lambda q: sum(v * v for v in q) > 0.01),
       p=st.tuples(*[st.floats(-5.0, 5.0)] * 3), origin=st.tuples(*[st.floats(-5.0, 5.0)] * 3),
       up=st.sampled_from(["y", "z"]), yaw_deg=st.floats(-360.0, 360.0))
def test_transformed_yaw_is_the_heading_of_the_transformed_body_axis(q, p, origin, up, yaw_deg) -> None:
    """The yaw of a transformed pose is the map heading of the body's +x axis, found by transforming two
    points of that axis as positions: orientation and position go through the same frame change."""
    n = math.sqrt(sum(v * v for v in q))
    w, x, y, z = (v / n for v in q)
    # the body's +x axis in the system's frame: the first column of the rotation matrix of q
    ax = (1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y))
    transform = FrameTransform(up, origin, yaw_deg)
    a = transform.position(p)
    b = transform.position(tuple(pi + ai for pi, ai in zip(p, ax, strict=True)))
    dx, dy = b[0] - a[0], b[1] - a[1]
    if math.hypot(dx, dy) < 0.05:
        return  # the body's x axis (nearly) vertical: no heading
    yaw = transform.pose(p, w, x, y, z)[3]
    assert wrap_angle(yaw - math.atan2(dy, dx)) == pytest.approx(0.0, abs=1e-6)


def test_startup_report_names_missing_and_unmapped_bodies() -> None:
    tracker = BodyTracker({"cf_01": "cf1", "cf_07": "cf7", "cf_08": "cf8"}, rate_hz=100.0, lost_after_s=0.1)
    none = tracker.startup_report()
    assert not none.ok and "no frame from the vicon system within 10 s" in none.message("vicon", 10)
    tracker.frame(0.0, {"cf_01": (0.0, 0.0, 0.0, 0.0), "CF07": (0.0, 0.0, 0.0, 0.0), "wand": (0.0, 0.0, 0.0, 0.0)}, 0.0)
    assert not tracker.all_found()
    report = tracker.startup_report()
    assert report.missing == {"cf_07": "cf7", "cf_08": "cf8"} and report.unmapped == ["CF07", "wand"]
    assert report.look_alikes() == {"cf_07": "CF07"}
    assert StartupReport(1, {"cf10": "v1", "cf_7": "v7"}, ["cf100", "CF-007"], []).look_alikes() == {"cf_7": "CF-007"}
    assert report.message("vicon", 10) == (
        "2 of 3 mapped rigid bodies not seen within 10 s: cf_07 (vehicle cf7; did you mean 'CF07'?), "
        "cf_08 (vehicle cf8); seen but not mapped: CF07, wand")
    tracker.frame(0.01, {"cf_07": (0.0, 0.0, 0.0, 0.0), "cf_08": (0.0, 0.0, 0.0, 0.0)}, 0.01)
    assert tracker.all_found() and tracker.startup_report().ok
    assert tracker.startup_report().message("vicon", 10).startswith("every mapped rigid body seen (3)")
    identity = BodyTracker({}, rate_hz=100.0, lost_after_s=0.1)
    identity.frame(0.0, {"cf2": (0.0, 0.0, 0.0, 0.0), "x/y": (0.0, 0.0, 0.0, 0.0)}, 0.0)
    assert not identity.all_found()  # nothing to expect: the bridge waits the whole time, then lists them
    assert identity.startup_report().message("mock", 1) == "no body mapping: bodies seen as vehicles: cf2; not vehicle ids, ignored: x/y"
    assert isinstance(identity.startup_report(), StartupReport)


def test_mock_y_up_system_is_taken_to_the_map_frame_and_a_missing_body_is_named(
        zenoh_router: str, zsession: Callable[..., zenoh.Session], caplog: pytest.LogCaptureFixture) -> None:
    """An OptiTrack-like y-up system (the library's mock): poses in the map's frame; the start-up check
    names the mapped body that never shows up, with the near-namesake it sees instead."""
    s = math.sin(math.radians(30) / 2)
    c = math.cos(math.radians(30) / 2)
    config = MocapConfig(
        backend="mock", bodies={"cf_01": "v1", "cf_02": "v2"}, startup_wait_s=0.5,
        frame=FrameSpec(up="y", origin=(1.0, 0.0, 0.0), yaw_deg=0.0),
        options={"rigid_bodies": f"cf_01(2.0,0.5,-3.0,{c},0,{s},0);CF02(0,0,0,1,0,0,0)"})
    bridge = MocapBridge(config, ZenohConfig.client(zenoh_router))
    session = zsession()

    async def main() -> None:
        seen = Poses(session)
        with caplog.at_level("WARNING", logger="services.mocap_bridge.bridge"):
            async with running(bridge):
                await asyncio.sleep(1.0)
        assert set(seen.poses) == {"v1"}
        p = seen.poses["v1"][-1][1]
        assert (p.x, p.y, p.z) == pytest.approx((1.0, 3.0, 0.5), abs=1e-6)  # y up -> z up, origin removed
        assert p.yaw == pytest.approx(math.radians(30), abs=1e-6)
        assert bridge.startup is not None and bridge.startup.missing == {"cf_02": "v2"}
        assert "1 of 2 mapped rigid bodies not seen within 0.5 s: cf_02 (vehicle v2; did you mean 'CF02'?)" in caplog.text
        assert bridge._figures()["missing_bodies"] == 1

    asyncio.run(main())
