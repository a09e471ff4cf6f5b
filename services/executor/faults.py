"""Fault detection and the fault manoeuvres of one vehicle: low battery (paper 000 §V-C: charge may
not fall below C_low), lost radio link, and where to go when the plan must be left.

- low battery: the charge used (eq. 4-5, estimated by the executor) reaches the usable charge
  (capacity - reserve), or the telemetry voltage stays below `vbat_low` for `vbat_low_s`;
- lost link: the gateway reports `link_ok = False`, or telemetry that was flowing stops;
- safe landing: fly level to above the nearest node of the vehicle's own plan where it takes off or
  lands (a node it was going to use anyway, under airspace it flies in), then descend at the
  landing speed; with every such node taken, straight down, or down beside it under one of its
  plan's flights (`safe_landing_steps`);
- emergency descent: without a trustworthy pose, a descent at `descent_speed` on the
  dead-reckoned state, its horizontal speed braked to a stop, then level (the estimator predicts
  with the commanded accelerations); the real vehicle
  may descend slower (drag, thrust error), so the motors stop only after the predicted descent
  time again (`descent_slack`) plus `descent_margin_s`; with poses back, the flight controller lands
  it where it is and the motors stop once it rests (`EmergencyDescent`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from common.bus.messages import PlanStep, Telemetry
from common.domain.geometry import touches_keep_out
from common.domain.mapfile import MapSpec
from common.domain.vehicle_model import VehicleModel
from common.flight.landing import LandInPlace

_MIN_DESCENT = 0.01
"""m: the descent of a safe landing is timed as at least this long, so that its last two entries are
never at the same time (a vehicle that sank to the ground while its link was lost)."""


@dataclass(frozen=True, slots=True)
class FaultParams:
    """vbat_low: V under load (the Crazyflie firmware warns at 3.2 V; a margin above it);
    vbat_critical: V under load for `vbat_low_s` at which the reserve counts as spent (a fault
    landing waiting for a clear node lands on the nearest: the firmware shuts the vehicle down after
    5 s under 3.0 V, `PM_BAT_CRITICAL_LOW_VOLTAGE` and `_TIMEOUT` in its `pm.h`); link_timeout_s:
    telemetry silence meaning a lost link; max_hold_s: longest ground hold before giving up the plan;
    emergency descent: speed (m/s), gain on its error (1/s), acceleration limit (m/s^2), and the wait past the predicted touchdown before the motors stop, as a
    fraction of the predicted descent time plus a margin (s); descent_bias_max: the largest
    thrust-model error (m/s^2) the blind descent allows for (`PoseEstimator.lift_error`; the flight
    integrators' bias, which a stalled loop winds up to 5.5, the descent used to keep: climbs to
    30 m in a 32-vehicle soak); rest_s: with poses,
    the landing in place rests that long on the ground (`common.flight.landing.LandInPlace`) before
    the motors stop; descent_brake_max: the largest horizontal deceleration (m/s^2) braking the
    descent's horizontal speed (at `descent_gain`). Tracking guard
    (issue 15): a plan is collision-free only while every vehicle stays within the margin it was
    planned with (`VehicleModel.margin`), so a vehicle whose estimated distance from its reference
    exceeds `guard_factor` x margin for `guard_s`, or `guard_burst` x margin at once, is held. Two
    margins, not one: the shipped maps' 3 cm is below what a loaded 2-core machine's loop tracks
    (driving 4.6-5.3 cm for 0.2 s in a 32-vehicle soak, flying 6 cm bursts), and the plans' closest
    approaches are rarely at the margin; a vehicle that leaves it that far is held
    (hovering or stopped where it is) and reported (`tracking_hold`), unless it is a flyer whose
    executor pauses its mission first (`VehicleController._pause_for_tracking`,
    `ProximityParams.pause_tracking`); `guard` False disables it.
    After a take-over the guard waits `guard_rejoin_s` for the vehicle to get back onto its
    reference (it drifted, or its gateway landed it, while it had no owner); it also waits
    `guard_drive_start_s` after a drive starts from rest: a vehicle parked facing away from its
    first edge turns in place on its spot first (pure pursuit, > 60 deg off) and falls behind its
    plan there, by up to 9 cm in a 32-vehicle soak on city934. In a take-off it judges the
    horizontal error only: the plan gives the climbing vehicle its spot's column, and a climb that
    starts late (a loaded machine's pose stalls: 9 cm behind at once in a CI run) is late inside
    it, unless its plan has it `guard_burst` x the margin above the ground layer (a body's height)
    while it is still in it: others may cross its spot by then, so it is held; the first edge after
    the climb is judged in full. The fleet's reflex to a held
    vehicle (`VehicleController.yield_to`): a vehicle whose plan brings it within reach of where
    another is held, or under one coming down in an emergency landing, in the next `yield_s` s
    holds too, before a replan could steer it around (the
    mission's replan switches a second after it hears of the hold, or 3 s when its planner had to
    be asked again: `services.mission.runner.REPLAN_TIME_LIMITS_S`); 0 disables the reflex."""

    vbat_low: float = 3.3
    vbat_critical: float = 3.1
    vbat_low_s: float = 1.0
    link_timeout_s: float = 1.0
    max_hold_s: float = 3.0
    descent_speed: float = 0.25
    descent_gain: float = 3.0
    descent_accel: float = 1.0
    descent_slack: float = 1.0
    descent_margin_s: float = 0.3
    rest_s: float = 0.3
    descent_bias_max: float = 1.5
    descent_brake_max: float = 2.0
    guard: bool = True
    guard_factor: float = 2.0
    guard_burst: float = 3.0
    guard_s: float = 0.3
    guard_rejoin_s: float = 5.0
    guard_drive_start_s: float = 2.0
    yield_s: float = 4.0

    def descent_brake(self, vx: float, vy: float) -> tuple[float, float]:
        """Horizontal acceleration (m/s^2, world) braking the dead-reckoned horizontal speed at
        `descent_gain`, at most `descent_brake_max` (a tilt of about 12 deg)."""
        ax, ay = -self.descent_gain * vx, -self.descent_gain * vy
        scale = min(1.0, self.descent_brake_max / max(math.hypot(ax, ay), 1e-9))
        return ax * scale, ay * scale

    def descent_accel_cmd(self, vz: float) -> float:
        """Vertical acceleration (m/s^2) steering the dead-reckoned vertical speed to -descent_speed."""
        a = self.descent_gain * (-self.descent_speed - vz)
        return min(max(a, -self.descent_accel), self.descent_accel)


@dataclass(slots=True)
class EmergencyDescent:
    """One emergency landing (`VehicleController._emergency`): when it began (or went blind again);
    blind, when its motors may stop (set at the predicted touchdown); with poses, the landing in
    place (`common.flight.landing.LandInPlace`); `column`: where (x, y) the take-off or landing of
    its plan it lost its poses in stands on the ground, its foot (None: it was not in one), and
    `beneath` where (x, y) its reference was then; with poses back within the guard's reach of
    `beneath` it lands over the foot (`VehicleController._back_over`); `aside`: where on the ground
    it comes down beside a body in its column (`VehicleController._beside_a_body`), once chosen."""

    start: float
    landing: LandInPlace
    cut: float | None = None
    column: tuple[float, float] | None = None
    beneath: tuple[float, float] | None = None
    aside: tuple[float, float, float] | None = None


def _since(since: float | None, holds: bool, now: float) -> float | None:
    """Since when a condition that `holds` now has held (None: it does not)."""
    return (now if since is None else since) if holds else None


class FaultMonitor:
    """Battery and link health of one vehicle from its telemetry and estimated charge."""

    def __init__(self, model: VehicleModel, params: FaultParams = FaultParams()) -> None:
        self.model = model
        self.params = params
        self.last_telemetry: Telemetry | None = None
        self._telemetry_at = -math.inf
        self._vbat_low_since: float | None = None
        self._vbat_critical_since: float | None = None

    def on_telemetry(self, tel: Telemetry, now: float) -> None:
        self.last_telemetry = tel
        self._telemetry_at = now
        measured = tel.vbat > 0.0  # 0: not measured yet (no log block came)
        low = measured and tel.vbat < self.params.vbat_low
        critical = measured and tel.vbat < self.params.vbat_critical
        self._vbat_low_since = _since(self._vbat_low_since, low, now)
        self._vbat_critical_since = _since(self._vbat_critical_since, critical, now)

    def low_battery(self, charge_used_ah: float, now: float) -> bool:
        return charge_used_ah >= self.model.usable_ah or self._long_enough(self._vbat_low_since, now)

    def reserve_spent(self, charge_used_ah: float, now: float) -> bool:
        """The battery's reserve is gone too: the charge used reaches the capacity, or the voltage
        stays under `vbat_critical` for `vbat_low_s`."""
        return charge_used_ah >= self.model.capacity_ah or self._long_enough(self._vbat_critical_since, now)

    def _long_enough(self, since: float | None, now: float) -> bool:
        """A voltage condition has held since `since` (None: it does not) for `vbat_low_s`."""
        return since is not None and now - since >= self.params.vbat_low_s

    def link_lost(self, now: float) -> bool:
        tel = self.last_telemetry
        if tel is None:
            return False
        return not tel.link_ok or now - self._telemetry_at > self.params.link_timeout_s


STRAIGHT_DOWN = "below"
"""The node name of a fault landing straight down from where the vehicle is (`safe_landing_steps`)."""
ASIDE = "aside"
"""The node name of a fault landing onto a spot beside the vehicle under its plan's flights (`safe_landing_steps`)."""
ASIDE_REACH = 0.5
"""m: how far from the vehicle, in the horizontal, a fault landing with every node taken and a body
below the vehicle may come down beside it (about three columns, `in_column`, of the shipped maps)."""
ASIDE_STEP = 0.05
"""m: the spacing of the spots tried along each of the plan's flights (`spots_under_flights`)."""


def landing_nodes(plan: Sequence[PlanStep]) -> list[PlanStep]:
    """The entries of `plan` where it lands or from where it takes off."""
    return [s for i, s in enumerate(plan)
            if s.edge == "land" or (i + 1 < len(plan) and plan[i + 1].edge == "takeoff")]


def in_column(node: tuple[float, float, float], body: tuple[float, float, float], model: VehicleModel) -> bool:
    """Whether `body` is in the column a fault landing onto `node` comes down through: within two
    radii and a margin of it in the horizontal."""
    return math.hypot(node[0] - body[0], node[1] - body[1]) < 2.0 * model.radius + model.margin


def clear_spot(pos: tuple[float, float, float], xy: tuple[float, float], model: VehicleModel,
               bodies: Sequence[tuple[float, float, float]]) -> bool:
    """Whether a landing from `pos` may come down on the ground at `xy`: none of the `bodies`
    below `pos` in the column there (`in_column`), none in the way of the level flight there
    (`in_way`)."""
    spot = (xy[0], xy[1], 0.0)
    return (all(not in_column(spot, b, model) for b in bodies if b[2] < pos[2])
            and not any(in_way(pos, spot, b, model) for b in bodies))


def spot_beside(pos: tuple[float, float, float], plan: Sequence[PlanStep], model: VehicleModel,
                bodies: Sequence[tuple[float, float, float]], ground: MapSpec | None,
                floor: float) -> tuple[float, float] | None:
    """The nearest spot beside `pos` under the plan's flights (`spots_under_flights`) that a
    landing may come down on, down to `floor`: off the map's no-fly zones and obstacles
    (`off_the_graph`) and clear of the `bodies` (`clear_spot`); None if there is none."""
    spots = off_the_graph(pos, spots_under_flights(pos, plan), floor, model, ground)
    return next((xy for xy in spots if clear_spot(pos, xy, model, bodies)), None)


def in_way(pos: tuple[float, float, float], node: tuple[float, float, float], body: tuple[float, float, float],
           model: VehicleModel, beyond: bool = True) -> bool:
    """Whether `body` is in the way of a fault landing's level flight from `pos` to above `node`:
    at its level (within a height and a margin) and within two radii and a margin of its line in the
    horizontal, ahead of it (a body the flight only moves away from is not in its way); not
    `beyond`: only between the two (one past `node` is not on the way there)."""
    if abs(body[2] - pos[2]) >= model.height + model.margin:
        return False
    along, off = _projection(body, pos, node)
    return along > 0.0 and (beyond or along < 1.0) and off < 2.0 * model.radius + model.margin


def _projection(p: tuple[float, float, float], a: tuple[float, float, float],
                b: tuple[float, float, float]) -> tuple[float, float]:
    """In the horizontal: where `p` projects onto the line a-b (0 at a, 1 at b; 0 if a is b), and
    how far `p` is from the segment a-b."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    px, py = p[0] - a[0], p[1] - a[1]
    length2 = dx * dx + dy * dy
    along = (px * dx + py * dy) / length2 if length2 > 0.0 else 0.0
    f = min(max(along, 0.0), 1.0)
    return along, math.hypot(px - f * dx, py - f * dy)


def spots_under_flights(pos: tuple[float, float, float], plan: Sequence[PlanStep],
                        reach: float = ASIDE_REACH, step: float = ASIDE_STEP) -> list[tuple[float, float]]:
    """Points at most `step` m apart along the plan's flights (its `fly` edges, ends included, in
    the horizontal) within `reach` of `pos`, nearest first: under the airspace the plan flies in,
    which the planner keeps a body's radius clear of the map's no-fly zones and obstacles at the
    flight's height (any other spot nearby may be in one; below the flight there may still be an
    obstacle: `off_the_graph`)."""
    spots: list[tuple[float, tuple[float, float]]] = []
    for a, b in pairwise(plan):
        if b.edge != "fly":
            continue
        (ax, ay, _), (bx, by, _) = a.pos, b.pos
        length = math.hypot(bx - ax, by - ay)
        if _projection(pos, a.pos, b.pos)[1] > reach:
            continue  # (most of a plan's flights pass far from where it is)
        n = max(1, math.ceil(length / step))
        for k in range(n + 1):  # (both ends: `step` apart at most)
            x, y = ax + k / n * (bx - ax), ay + k / n * (by - ay)
            d = math.hypot(x - pos[0], y - pos[1])
            if d <= reach:
                spots.append((d, (x, y)))
    spots.sort()
    return [xy for _, xy in spots]


def off_the_graph(pos: tuple[float, float, float], spots: list[tuple[float, float]], floor: float,
                  model: VehicleModel, ground: MapSpec | None) -> list[tuple[float, float]]:
    """The `spots` a descent from `pos`'s height to `floor` may come down on: its column (the body
    from the floor up to that height) clear of the map's no-fly zones and obstacles (`ground`: the
    map; None: unknown, every spot)."""
    if ground is None or not spots:
        return spots
    top = pos[2] + model.height
    pts = np.array([(x, y, 0.5 * (floor + top)) for x, y in spots])
    blocked = touches_keep_out(ground, pts, model.radius, top - floor)
    return [xy for xy, no in zip(spots, blocked.tolist(), strict=True) if not no]


def safe_landing_steps(pos: tuple[float, float, float], t: float, plan: Sequence[PlanStep],
                       model: VehicleModel, bodies: Iterable[tuple[float, float, float]] = (),
                       ground: MapSpec | None = None) -> list[PlanStep] | None:
    """Path entries from `pos` at time `t`: level flight to above the plan's ground node nearest
    in the horizontal, then a descent onto it, at the model's fly and land speeds. The nodes where
    the plan takes off or lands come first: they are under the airspace it flies in (other ground
    nodes, e.g. a parking spot next to a landing node, may lie under a no-fly zone). A node with one
    of the other `bodies` below the vehicle in its column (two radii and a margin of it: a vehicle
    parked there, or another's fault landing heading there), or with one in the way of the level
    flight there (`in_way`: a vehicle hovering, held, between them; in an 80-vehicle soak's abort
    four flew into such), is passed over for the next nearest. With every node taken or out of the
    way, straight down onto the plan's lowest ground (node `STRAIGHT_DOWN`), if no body is below the
    vehicle in its own column (the column a replan keeps clear below a vehicle that left:
    `services/mission/sweeps.py`); else down onto the nearest spot beside it under the plan's
    flights (`spots_under_flights`, node `ASIDE`) whose column is clear and whose way is (held
    vehicles hovering in a cluster, each with one lower beside it: in an 80-vehicle soak's abort
    five hovered on for 40 s); else None: there is nowhere to land without landing on a body (the
    nearest node all the same would come down onto the vehicle parked there). A spot off the graph
    (straight down, beside it) whose column touches one of `ground`'s no-fly zones or obstacles is
    never chosen (`off_the_graph`: a building under a flight)."""
    nodes = landing_nodes(plan) or [s for s in plan if s.kind != "air"]
    bodies = list(bodies)

    def clear(xy: tuple[float, float]) -> bool:
        return clear_spot(pos, xy, model, bodies)

    free = [s for s in nodes if clear(s.pos[:2])]
    if free:
        target = min(free, key=lambda s: math.hypot(s.pos[0] - pos[0], s.pos[1] - pos[1]))
    else:
        floor = min((s.pos[2] for s in nodes), default=0.0)
        if off_the_graph(pos, [pos[:2]], floor, model, ground) and clear(pos[:2]):
            target = PlanStep(node=STRAIGHT_DOWN, t=0.0, pos=(pos[0], pos[1], floor), kind="land")
        else:
            aside = spot_beside(pos, plan, model, bodies, ground, floor)
            if aside is None:
                return None
            target = PlanStep(node=ASIDE, t=0.0, pos=(aside[0], aside[1], floor), kind="land")
    gx, gy, gz = target.pos
    steps = [PlanStep(node="fault", t=t, pos=pos, kind="air")]
    reach = math.hypot(gx - pos[0], gy - pos[1])
    if reach > 0.01:
        t += reach / model.speed.fly
        steps.append(PlanStep(node=f"above-{target.node}", t=t, pos=(gx, gy, pos[2]), kind="air", edge="fly"))
    t += max(pos[2] - gz, _MIN_DESCENT) / model.speed.land  # already down (it sank): still a step in time
    steps.append(PlanStep(node=target.node, t=t, pos=(gx, gy, gz), kind=target.kind, edge="land"))
    return steps
