"""Pure pursuit for the differential-drive wheel base (paper 000 §VI-B: "For ground waypoints, a
pure pursuit controller is used to follow the desired trajectory. The two ground motors allow for
simple differential steering control").

The reference is timed, so the goal point is the reference `lookahead_time` ahead (the lookahead
distance grows with the reference speed, never below `min_lookahead`) and the forward speed is the
reference speed plus a correction of the along-track error, which keeps the plan's timing. The
curvature is the classic 2 y / d^2 to the goal point (Coulter 1992), with d no shorter than the
minimum lookahead so that a goal close by does not spin the vehicle; wheel speeds are scaled
together when one would exceed the limit, which keeps the curvature. A differential drive goes as
well backwards as forwards: a direction of travel more than `reverse_angle` off the way the vehicle
drives now (its nose, or its tail when reversing) flips that way, so a path that doubles back at a
node (out of a parking spot onto its road, a dodge) is driven back without turning round. A
direction of travel still more than `turn_angle` off is first turned to in place (the plan does not
budget a turn: the vehicle falls behind by its time at the drive speed); a vehicle ahead of its
reference waits rather than backs up; near a resting reference it holds position without steering.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from common.bus.messages import WheelSetpoint
from common.crazyflie.thrust import WheelBase
from common.flight.estimator import Estimate
from common.flight.reference import RefSample, wrap_angle


@dataclass(frozen=True, slots=True)
class PursuitParams:
    """lookahead_time: s of reference ahead; min_lookahead: m; k_along: 1/s gain on the along-track
    error; k_turn: 1/s gain of the in-place turn, limited to max_turn_rate (rad/s: 0.18 m/s at the
    rims of the 6 cm track, under their 0.2 m/s; a plan does not budget the turn at a sharp corner,
    so the vehicle falls behind by the turn's time at the drive speed: at a 135 deg corner out of a
    parking spot of city934 4.7 cm at 3 rad/s, 2.9 cm at 6, on the nominal loop, before it could
    reverse); turn_angle: rad between the way it drives and the direction of travel that triggers
    it; reverse_angle: rad beyond which it drives the other way instead (over 90 deg, so that the
    choice does not chatter); hold_radius: m within which a resting reference is held by driving
    straight forward or back, without steering."""

    lookahead_time: float = 0.3
    min_lookahead: float = 0.03
    k_along: float = 2.0
    k_turn: float = 6.0
    max_turn_rate: float = 6.0
    turn_angle: float = math.radians(60.0)
    reverse_angle: float = math.radians(110.0)
    aligned_angle: float = math.radians(5.0)
    hold_radius: float = 0.03


class PurePursuit:
    """Wheel speeds from the estimate and the reference now and one lookahead ahead."""

    def __init__(self, wheels: WheelBase | None = None, params: PursuitParams = PursuitParams()) -> None:
        self.wheels = wheels or WheelBase()
        self.params = params
        self.reversing = False
        """Driving backwards (its tail first): the way it drove last, kept until the path turns
        more than `reverse_angle` from it."""

    def lookahead(self, ref: RefSample) -> float:
        """Lookahead time (s) for the current reference speed: `lookahead_time`, stretched so that
        the lookahead distance is at least `min_lookahead`."""
        speed = math.hypot(ref.vx, ref.vy)
        p = self.params
        return max(p.lookahead_time, p.min_lookahead / speed) if speed > 1e-6 else 0.0

    def command(self, est: Estimate, ref: RefSample, goal: RefSample) -> WheelSetpoint:
        """`ref` is the reference now, `goal` the reference `lookahead(ref)` s later."""
        p = self.params
        gx, gy = goal.x - est.x, goal.y - est.y
        d2 = gx * gx + gy * gy
        moving = abs(ref.vx) + abs(ref.vy) > 1e-6
        if not moving and d2 < p.hold_radius**2:
            ex = (ref.x - est.x) * math.cos(est.yaw) + (ref.y - est.y) * math.sin(est.yaw)
            return self._wheels(p.k_along * ex, 0.0)
        # face the direction of travel (or, at rest, the point to return to) before driving
        heading = math.atan2(ref.vy, ref.vx) if moving else math.atan2(gy, gx)
        err = self._facing_error(heading, est.yaw, p.reverse_angle)
        if abs(err) > p.turn_angle:
            return self._wheels(0.0, min(max(p.k_turn * err, -p.max_turn_rate), p.max_turn_rate))
        # in the frame of the way it drives (its tail's when reversing)
        facing = est.yaw + math.pi if self.reversing else est.yaw
        c, s = math.cos(facing), math.sin(facing)
        ex = (ref.x - est.x) * c + (ref.y - est.y) * s  # along-track error (positive: reference ahead)
        v = ref.vx * c + ref.vy * s + p.k_along * ex
        if moving:
            v = max(v, 0.0)  # ahead of the reference: wait for it rather than back up
        bx, by = gx * c + gy * s, -gx * s + gy * c
        kappa = 2.0 * by / max(d2, p.min_lookahead**2) if bx > 0.0 and v > 0.0 else 0.0
        return self._wheels(-v if self.reversing else v, kappa * v)

    def _facing_error(self, heading: float, yaw: float, flip_beyond: float) -> float:
        """Angle (rad) from the way it drives to `heading`, after flipping `reversing` if that
        angle was over `flip_beyond`."""
        err = wrap_angle(heading - yaw - (math.pi if self.reversing else 0.0))
        if abs(err) > flip_beyond:
            self.reversing = not self.reversing
            err = wrap_angle(err - math.pi)
        return err

    def turn_towards(self, est: Estimate, heading: float) -> WheelSetpoint | None:
        """Turn in place before driving off towards `heading` (rad), nose or tail first, whichever
        is nearer (None: facing it already)."""
        p = self.params
        err = self._facing_error(heading, est.yaw, math.pi / 2)
        if abs(err) < p.aligned_angle:
            return None
        return self._wheels(0.0, min(max(p.k_turn * err, -p.max_turn_rate), p.max_turn_rate))

    def _wheels(self, v: float, omega: float) -> WheelSetpoint:
        """Unicycle (v, omega) -> wheel rim speeds, both scaled down if one exceeds the limit."""
        half = 0.5 * omega * self.wheels.track
        left, right = v - half, v + half
        peak = max(abs(left), abs(right))
        if peak > self.wheels.max_speed:
            k = self.wheels.max_speed / peak
            left, right = left * k, right * k
        return WheelSetpoint(left=left, right=right)
