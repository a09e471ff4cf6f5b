"""The simulated motion-capture system: every capture sees the simulated vehicles' true poses with
Gaussian noise, loses bodies now and then (random dropouts, or a `mocap_dropout` fault), and
delivers the frame `latency_s` after capture (docs/mocap.md). Frames go out on `sim/mocap`, where the
mocap bridge's `sim` backend reads them as it would read a Vicon or an OptiTrack.
"""

from __future__ import annotations

import asyncio
import math
import random
import time
from collections.abc import Callable, Iterable

from common.bus.messages import MocapBody, MocapFrame, SimTruth
from common.deploy.radios import MocapModel


class SimMocap:
    """Frames of the truths it is given, with `model`'s imperfections, handed to `deliver`."""

    def __init__(self, model: MocapModel, deliver: Callable[[MocapFrame], None]) -> None:
        self.model = model
        self._deliver = deliver
        self._rng = random.Random(model.seed)
        self._dropout_until: dict[str, float] = {}
        self._last_t: float | None = None
        self.closed = False

    def capture(self, t: float, truths: Iterable[SimTruth]) -> None:
        """One capture at `t` (epoch s) of the bodies in `truths`, delivered `latency_s` later."""
        m, g = self.model, self._rng.gauss
        last, self._last_t = self._last_t, t
        bodies = []
        for truth in truths:
            starts = last is not None and m.dropout_rate_hz > 0.0 and t > last
            if starts and self._rng.random() < -math.expm1(-m.dropout_rate_hz * (t - last)):
                self.blind(truth.vid, t + m.dropout_s)
            if t < self._dropout_until.get(truth.vid, -math.inf):
                continue
            bodies.append(MocapBody(truth.vid, truth.x + g(0.0, m.pos_std), truth.y + g(0.0, m.pos_std),
                                    truth.z + g(0.0, m.pos_std), math.remainder(truth.yaw + g(0.0, m.yaw_std), 2.0 * math.pi)))
        # `latency_s` after the capture, not after the simulator's work on it (stepping every vehicle
        # to `t` took a few ms of a 32-vehicle fleet's cycle: a real system's latency does not grow so)
        delay = max(t + m.latency_s - time.time(), 0.0)
        asyncio.get_running_loop().call_later(delay, self._send, MocapFrame(t=t, bodies=bodies))

    def blind(self, vid: str, until: float) -> None:
        """`vid` is not seen in frames captured before `until` (epoch s; an earlier end is kept)."""
        self._dropout_until[vid] = max(until, self._dropout_until.get(vid, -math.inf))

    def _send(self, frame: MocapFrame) -> None:
        if not self.closed:
            self._deliver(frame)
