"""Where frames come from: a `motioncapture` (libmotioncapture) system, or the simulator's truth.

Both hand frames to `on_frame(t, seen)` on the event loop: `t` the capture time (epoch s), `seen`
body name -> (x, y, z, yaw) of every body visible in the frame.

- `LibBackend`: vicon, optitrack, qualisys, vrpn, or the library's `mock`, on a thread of its own
  (`waitForNextFrame` blocks, and so may `connect`; both release the GIL). The Python binding gives
  no frame timestamp: a frame is stamped on arrival minus the configured system latency. A failing
  connection is retried every `RETRY_S`.
- `SimBackend`: `sim/truth/<vid>` from `fleet sim`, with Gaussian noise, a capture-to-publication
  delay and random dropouts (`SimNoise`); the capture time is the truth's own time. `blind` hides
  one body for a while (fault injection, docs/reliability.md).
"""

from __future__ import annotations

import asyncio
import logging
import math
import random
import threading
import time
from collections.abc import Callable, Mapping

from common.bus.messages import SimTruth
from common.bus.pubsub import call_in_loop
from services.mocap_bridge.config import SimNoise
from services.mocap_bridge.tracker import BodyPose, yaw_of

log = logging.getLogger(__name__)

FrameCallback = Callable[[float, Mapping[str, BodyPose]], None]

RETRY_S = 2.0
"""Seconds between attempts to (re)connect to a motion-capture system."""


class LibBackend:
    """A `motioncapture` system `kind` with `options` (strings, as `motioncapture.connect` takes)."""

    def __init__(self, kind: str, options: Mapping[str, str], latency_s: float, on_frame: FrameCallback,
                 on_error: Callable[[str], None]) -> None:
        self.kind = kind
        self.options = dict(options)
        self.latency_s = latency_s
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
                    seen = {name: _body_pose(body) for name, body in system.rigidBodies.items()}
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


def _body_pose(body) -> BodyPose:
    x, y, z = (float(v) for v in body.position)
    q = body.rotation
    return x, y, z, yaw_of(q.w, q.x, q.y, q.z)


class SimBackend:
    """Simulated motion capture from ground truth (feed it with `on_truth`)."""

    def __init__(self, noise: SimNoise, on_frame: FrameCallback) -> None:
        self.noise = noise
        self._on_frame = on_frame
        self._rng = random.Random(noise.seed)
        self._dropout_until: dict[str, float] = {}
        self._last_t: dict[str, float] = {}
        self._closed = False

    def on_truth(self, truth: SimTruth, _key: str = "") -> None:
        n = self.noise
        last = self._last_t.get(truth.vid)
        self._last_t[truth.vid] = truth.t
        starts = last is not None and n.dropout_rate_hz > 0.0 and truth.t > last
        if starts and self._rng.random() < -math.expm1(-n.dropout_rate_hz * (truth.t - last)):
            self.blind(truth.vid, truth.t + n.dropout_s)
        if truth.t < self._dropout_until.get(truth.vid, -math.inf):
            return
        g = self._rng.gauss
        seen = {truth.vid: (truth.x + g(0.0, n.pos_std), truth.y + g(0.0, n.pos_std), truth.z + g(0.0, n.pos_std),
                            math.remainder(truth.yaw + g(0.0, n.yaw_std), 2.0 * math.pi))}
        asyncio.get_running_loop().call_later(n.latency_s, self._deliver, truth.t, seen)

    def blind(self, vid: str, until: float) -> None:
        """`vid` is not seen in frames captured before `until` (epoch s; an earlier end is kept)."""
        self._dropout_until[vid] = max(until, self._dropout_until.get(vid, -math.inf))

    def _deliver(self, t: float, seen: Mapping[str, BodyPose]) -> None:
        if not self._closed:
            self._on_frame(t, seen)

    def close(self) -> None:
        """Frames still on their way are dropped (the bridge is stopping)."""
        self._closed = True
