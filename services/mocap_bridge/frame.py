"""The motion-capture system's frame -> the map's frame (the `frame:` section of the mocap file).

A system streams positions and orientations in its own world frame: its up axis (Vicon and Qualisys
stream z up; OptiTrack's Motive streams y up by default), its origin (where the calibration square
lay) and its heading. The map's frame is z up, x and y on the floor, yaw CCW from +x seen from above.

`frame: {up: y, origin: [ox, oy, oz], yaw_deg: a}` says: the system's up axis is y; the map's
origin is at (ox, oy, oz) in the system's own coordinates (as its software shows them); the map's
+x axis points `a` degrees CCW (seen from above) from the system's +x axis. Then, for a body at
position p with orientation q in the system's frame:

    U      the z-up change: identity for `up: z`; for `up: y` (x, y, z) -> (x, -z, y), the rotation
           of +90 deg about x, which takes the y axis to z (a proper rotation, so handedness holds)
    p_map  = Rz(-a) (U p - U origin)
    q_map  = Rz(-a) U q U^T: the body's own axes change with the world's (a rigid body's axes are
           set in the system's convention), so U acts on q by conjugation, which for a quaternion
           rotates its vector part: (w, x, y, z) -> (w, U (x, y, z))
    yaw    = yaw(U q U^T) - a, wrapped to (-pi, pi]

The body's heading is its +x axis, as in `tracker.yaw_of` (ZYX yaw).
"""

from __future__ import annotations

import math

from services.mocap_bridge.tracker import BodyPose, yaw_of

Vec3 = tuple[float, float, float]


def _up(v: Vec3, up: str) -> Vec3:
    x, y, z = v
    return (x, -z, y) if up == "y" else (x, y, z)


def wrap_angle(a: float) -> float:
    """`a` in (-pi, pi]."""
    a = math.fmod(a + math.pi, 2.0 * math.pi)
    if a <= 0.0:
        a += 2.0 * math.pi
    return a - math.pi


class FrameTransform:
    """System frame -> map frame (module docstring). The default is the identity."""

    def __init__(self, up: str = "z", origin: Vec3 = (0.0, 0.0, 0.0), yaw_deg: float = 0.0) -> None:
        if up not in ("y", "z"):
            raise ValueError(f"up axis {up!r} is not y or z")
        self.up = up
        self.origin = _up(origin, up)
        self.yaw = math.radians(yaw_deg)
        self._cos, self._sin = math.cos(self.yaw), math.sin(self.yaw)

    @property
    def identity(self) -> bool:
        return self.up == "z" and self.origin == (0.0, 0.0, 0.0) and self.yaw == 0.0

    def position(self, p: Vec3) -> Vec3:
        x, y, z = _up(p, self.up)
        dx, dy, dz = x - self.origin[0], y - self.origin[1], z - self.origin[2]
        return (self._cos * dx + self._sin * dy, -self._sin * dx + self._cos * dy, dz)

    def pose(self, p: Vec3, qw: float, qx: float, qy: float, qz: float) -> BodyPose:
        """A body at `p` with orientation (qw, qx, qy, qz), both in the system's frame -> x, y, z, yaw
        in the map's frame."""
        x, y, z = self.position(p)
        vx, vy, vz = _up((qx, qy, qz), self.up)
        return x, y, z, wrap_angle(yaw_of(qw, vx, vy, vz) - self.yaw)
