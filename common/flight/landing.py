"""Landing in place on motion capture: the vertical reference of a descent and the watch that says
it has touched down. Shared by the gateway's safety landing (services/radio_gateway/landing.py) and
the executor's emergency descent once poses are back (services/executor/vehicle_controller.py)."""

from __future__ import annotations

REST_SPEED = 0.05
"""m/s: slower than this counts as resting."""


def descent_ref(speed: float, touchdown_height: float, t0: float, z0: float, now: float,
                ground: float = 0.0) -> tuple[float, float]:
    """The vertical reference (z, vz) at `now` of a descent from `z0` starting at `t0`: down at
    `speed` to twice `touchdown_height` below `ground`, where it stays (the vehicle settles on the
    ground at the descent speed instead of being held just above it)."""
    floor = ground - 2.0 * touchdown_height
    z_ref = max(z0 - speed * max(now - t0, 0.0), floor)
    return z_ref, (-speed if floor < z_ref < z0 else 0.0)


class RestWatch:
    """Touchdown: at least `touchdown_height` above the descent's reference (the ground, or a
    helipad, holds it up) and slower than `REST_SPEED`, for `rest_s`."""

    def __init__(self, touchdown_height: float, rest_s: float) -> None:
        self.touchdown_height = touchdown_height
        self.rest_s = rest_s
        self._since: float | None = None

    def __call__(self, now: float, above_ref: float, vz: float) -> bool:
        if above_ref >= self.touchdown_height and abs(vz) < REST_SPEED:
            self._since = self._since if self._since is not None else now
            return now - self._since >= self.rest_s
        self._since = None
        return False
