"""Where frames come from: a `motioncapture` (libmotioncapture) system, or the simulated one.

Both hand frames to `on_frame(t, seen)` on the event loop: `t` the capture time (epoch s), `seen`
body name -> (x, y, z, yaw) of every body visible in the frame.

- `LibBackend`: vicon, optitrack, qualisys, vrpn, or the library's `mock`, on a thread of its own
  (`waitForNextFrame` blocks, and so may `connect`; both release the GIL). Poses are taken from the
  system's frame to the map's (`frame.FrameTransform`). The Python binding (motioncapture 1.1)
  exposes only `waitForNextFrame` and `rigidBodies`: no frame timestamp and no latency (the C++
  library's `timeStamp()` and `latency()` are not bound), so a frame is stamped on arrival minus
  the configured system latency. A failing connection is retried every `RETRY_S`.
- `sim`: the frames of the simulated motion-capture system of `fleet sim` (`sim/mocap`, noise,
  latency and dropouts are the simulator's), stamped with their capture time.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Mapping

from common.bus.messages import MocapFrame
from common.bus.pubsub import call_in_loop
from services.mocap_bridge.frame import FrameTransform
from services.mocap_bridge.tracker import BodyPose

log = logging.getLogger(__name__)

FrameCallback = Callable[[float, Mapping[str, BodyPose]], None]

RETRY_S = 2.0
"""Seconds between attempts to (re)connect to a motion-capture system."""


class LibBackend:
    """A `motioncapture` system `kind` with `options` (strings, as `motioncapture.connect` takes);
    `transform` takes its poses to the map's frame."""

    def __init__(self, kind: str, options: Mapping[str, str], latency_s: float, on_frame: FrameCallback,
                 on_error: Callable[[str], None], transform: FrameTransform | None = None) -> None:
        self.kind = kind
        self.options = dict(options)
        self.latency_s = latency_s
        self.transform = transform or FrameTransform()
        self._on_frame = on_frame
        self._on_error = on_error
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self._thread = threading.Thread(target=self._run, args=(loop,), name=f"mocap {self.kind}", daemon=True)
        self._thread.start()

    def _run(self, loop: asyncio.AbstractEventLoop) -> None:
        import motioncapture

        while not self._stop.is_set():
            try:
                system = motioncapture.connect(self.kind, self.options)
                while not self._stop.is_set():
                    system.waitForNextFrame()
                    t = time.time() - self.latency_s
                    seen = {name: body_pose(body, self.transform) for name, body in system.rigidBodies.items()}
                    call_in_loop(loop, self._deliver, t, seen)
            except Exception as exc:  # the library raises RuntimeError for everything
                call_in_loop(loop, self._on_error, f"{self.kind}: {exc}")
                self._stop.wait(RETRY_S)

    def _deliver(self, t: float, seen: Mapping[str, BodyPose]) -> None:
        if not self._stop.is_set():  # frames still queued when the bridge stops are dropped
            self._on_frame(t, seen)

    def close(self) -> None:
        """Ask the thread to stop (a daemon: a `connect` blocked on an absent system cannot hold the exit)."""
        self._stop.set()


def body_pose(body, transform: FrameTransform) -> BodyPose:
    """A `motioncapture.RigidBody` in the map's frame."""
    x, y, z = (float(v) for v in body.position)
    q = body.rotation
    return transform.pose((x, y, z), q.w, q.x, q.y, q.z)


def frame_bodies(frame: MocapFrame) -> dict[str, BodyPose]:
    """A simulated system's frame (`sim/mocap`) as the bridge takes frames: body name -> pose."""
    return {b.name: (b.x, b.y, b.z, b.yaw) for b in frame.bodies}
