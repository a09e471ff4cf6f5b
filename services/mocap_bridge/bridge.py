"""`fleet mocap`: motion capture -> poses (paper 000 §VI-B: "position and yaw estimates from a Vicon
motion capture system"), stamped with the capture time: every frame as one `PoseFrame` on
`mocap/frame` (100 Hz by default; the executors and gateways fuse these: the hot path) and each
vehicle's pose on `vehicle/<vid>/pose` at `vehicle_pose_hz` (20 Hz by default; for tools, the
recorder and anyone who reads one vehicle).

A `motioncapture` system (vicon, optitrack, qualisys, vrpn, or the library's mock) or the simulated
one of `fleet sim` (`sim`: its frames on `sim/mocap`) feeds the `BodyTracker`, which maps rigid
bodies to vehicles, limits the rate and reports a vanished body as `VehicleEvent` "mocap_lost" on
`vehicle/<vid>/event` (no poses for it until it is back: "mocap_found"). Counters and the poses
published per vehicle go out on `stats/mocap/<instance>`.

At start the bridge waits up to `startup_wait_s` for every mapped rigid body and then logs one line:
every body seen, or which are missing (with their vehicles, a seen but unmapped body of nearly the
same name as a likely typo, and the bodies seen that are not ours), or that no frame came at all.
The result is `startup` (a `StartupReport`) and `missing_bodies` in the stats.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Mapping

from common.bus.keys import Keys
from common.bus.messages import FramePose, MocapFrame, Pose, PoseFrame, VehicleEvent
from common.bus.service import Service
from common.bus.session import ZenohConfig
from common.bus.stats import publish_stats
from services.mocap_bridge.backends import LibBackend, frame_bodies
from services.mocap_bridge.config import MocapConfig, check_mocap
from services.mocap_bridge.frame import FrameTransform
from services.mocap_bridge.tracker import BodyPose, BodyTracker, Event, StartupReport

log = logging.getLogger(__name__)


class MocapBridge(Service):
    """Publishes the poses of `config`'s backend. `published` counts poses per vehicle."""

    def __init__(self, config: MocapConfig, zconfig: ZenohConfig, instance: str = "mocap",
                 keys: Keys | None = None) -> None:
        check_mocap(config, "mocap config")
        super().__init__("mocap", instance, zconfig, keys)
        self.config = config
        self.tracker: BodyTracker | None = None
        self.published: dict[str, int] = {}
        self.startup: StartupReport | None = None

    async def main(self) -> None:
        cfg = self.config
        self._poses = self.publishers(lambda vid: self.keys.vehicle(vid, "pose"), Pose)
        self._frames = self.publisher(self.keys.mocap_frame, PoseFrame)
        self._frame_seq = 0
        self._pose_due: dict[str, float] = {}
        self._events = self.publishers(lambda vid: self.keys.vehicle(vid, "event"), VehicleEvent)
        tracker = self.tracker = BodyTracker(cfg.bodies, cfg.rate_hz, cfg.lost_after_s, source=cfg.backend)
        backend: LibBackend | None = None
        if cfg.backend == "sim":
            self.subscribe(self.keys.sim_mocap, MocapFrame, lambda f, _k: self._on_frame(f.t, frame_bodies(f)))
        else:
            options = dict(cfg.options)
            if cfg.backend == "mock":
                options.setdefault("frequency", str(round(cfg.rate_hz)))
            frame = FrameTransform(cfg.frame.up, cfg.frame.origin, cfg.frame.yaw_deg)
            backend = LibBackend(cfg.backend, options, cfg.latency_s, self._on_frame, self._on_backend_error, frame)
            backend.start(asyncio.get_running_loop())
        self.spawn(publish_stats(self, self._figures), name="stats")
        if cfg.startup_wait_s > 0:
            self.spawn(self._startup_check(tracker), name="startup check")
        try:
            while True:  # lost bodies are noticed even when no frame comes at all
                self._publish_events(tracker.check(time.time()))
                await asyncio.sleep(min(cfg.lost_after_s / 2.0, 1.0 / cfg.rate_hz))
        finally:
            if backend is not None:
                backend.close()

    def _on_frame(self, t: float, seen: Mapping[str, BodyPose]) -> None:
        """A frame captured at `t`: poses and events. One older than `max_age_s` by now (the loop
        fell behind) is dropped and counted: a backlog of late poses would grow without bound
        (measured: 80 s behind in an overloaded soak); a younger one is fused at its capture time."""
        assert self.tracker is not None
        now = time.time()
        if now - t > self.config.max_age_s:
            if self.counters.inc("late_frames") == 1:
                log.warning("mocap: dropped a frame captured %.2f s ago (max_age_s %.2f; further ones only "
                            "counted as 'late_frames')", now - t, self.config.max_age_s)
            return
        poses, events = self.tracker.frame(t, seen, now)
        self._publish_events(events)
        if not poses:
            return
        self._frame_seq += 1
        self._frames.put(PoseFrame(t=t, seq=self._frame_seq, source=self.config.backend, arrived=now,
                                   poses=[FramePose(p.vid, p.x, p.y, p.z, p.yaw) for p in poses]))
        every = 1.0 / self.config.vehicle_pose_hz
        for pose in poses:
            self.published[pose.vid] = self.published.get(pose.vid, 0) + 1
            if t >= self._pose_due.get(pose.vid, 0.0):
                self._poses.put(pose.vid, pose)
                self._pose_due[pose.vid] = max(self._pose_due.get(pose.vid, 0.0), t - every / 2) + every

    async def _startup_check(self, tracker: BodyTracker) -> None:
        """Wait up to `startup_wait_s` for every mapped body; log which are missing (module docstring)."""
        wait_s = self.config.startup_wait_s
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and not tracker.all_found():
            await asyncio.sleep(0.05)
        report = self.startup = tracker.startup_report()
        text = f"mocap: {report.message(self.config.backend, wait_s)}"
        if report.ok:
            log.info(text)
        else:
            log.warning(text)

    def _figures(self) -> dict[str, float]:
        figures = {"bodies": len(self.published), "poses": sum(self.published.values()),
                   "late_frames": self.counters.get("late_frames", 0)}
        if self.startup is not None:
            figures["missing_bodies"] = len(self.startup.missing)
        return figures

    def _on_backend_error(self, message: str) -> None:
        if self.counters.inc("backend_error") == 1:
            log.error("mocap: %s (retrying; further errors only counted)", message)

    def _publish_events(self, events: list[Event]) -> None:
        for vid, kind, detail in events:
            log.warning("mocap: %s %s: %s", vid, kind, detail)
            self._events.put(vid, VehicleEvent(vid=vid, t=time.time(), kind=kind, detail=detail))
