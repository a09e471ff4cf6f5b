"""SLC controllers, triggers and the forward simulation Phi(s, c, tau) (002 §III-A, §III-B).

Drone controllers: WALLFOLLOWING left/right (IR side sensors; intrinsic triggers WALL_END and
OBSTACLE, perceptual triggers OPENING_LEFT/RIGHT and LANDMARK_SIGHTED), GOTOLANDMARK_STAT (a
static landmark in view), GOTOLANDMARK_DYN (the UGV's markers in view and range), METRICTURN and
METRICSTEP (short optical-flow motions, only where `no_metric` does not forbid them; the paper
always groups them to turn corners, METRICSTEP(0.5 m) -> METRICTURN(+-90) -> METRICSTEP(1.0 m):
`corner_target`) and ALTITUDE (laser altimeter). The UGV has metric motion primitives (forward one
cell, turn 45 degrees).

OBSTACLE (002 §V-A: "when an obstacle was within a certain distance of the front or back of the
UAV"): intrinsic, when the next cell of the flight is blocked and sensed; and perceptual, when an
obstacle first comes within `OBSTACLE_CELLS` of the IR sensor facing the direction of travel. The
drone keeps its yaw parallel to the wall and may fly along it forwards or backwards, so that sensor
is its front or its back one; the lattice's WALLFOLLOWING heading is the direction of travel, so one
rule serves both (in a static world the sensor facing away from the travel sees only the free cells
just flown through, and could not trigger).

Everything works on lattice cells: a drone pose is (level, row, col, heading), a UGV pose
(row, col, heading); headings are 0..7 in steps of 45 degrees counter-clockwise from +x. The same
functions serve the planner (edges of the graph) and the simulator (executing a plan).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from common.team.sensing import DIRS, Sensing

Side = Literal["left", "right"]

# Triggers (002 §III-A): intrinsic ones end a controller by default, perceptual ones on request.
WALL_END = "WALL_END"
OBSTACLE = "OBSTACLE"
ARRIVED = "ARRIVED"
OPENING_LEFT = "OPENING_LEFT"
OPENING_RIGHT = "OPENING_RIGHT"
LANDMARK_SIGHTED = "LANDMARK_SIGHTED"

OBSTACLE_CELLS = 2
"""OBSTACLE as a perceptual trigger: an obstacle within this many cells (1 m) ahead of the travel."""
CORNER_M = (0.5, 1.0)
"""The paper's corner group: METRICSTEP(0.5 m) -> METRICTURN(+-90 deg) -> METRICSTEP(1.0 m) (002 fn. 3)."""


@dataclass(frozen=True)
class DronePose:
    level: int
    row: int
    col: int
    heading: int = 0


@dataclass(frozen=True)
class UgvPose:
    row: int
    col: int
    heading: int = 0


@dataclass(frozen=True)
class WallFollowController:
    side: Side
    heading: int


@dataclass(frozen=True)
class GoToLandmarkStatController:
    landmark: int
    target: tuple[int, int]


@dataclass(frozen=True)
class GoToLandmarkDynController:
    target: tuple[int, int]


@dataclass(frozen=True)
class MetricTurnController:
    heading: int


@dataclass(frozen=True)
class MetricStepController:
    cells: int


@dataclass(frozen=True)
class AltitudeController:
    level: int


@dataclass(frozen=True)
class UgvForwardController:
    pass


@dataclass(frozen=True)
class UgvTurnController:
    delta: int
    """+1 = 45 degrees counter-clockwise, -1 = clockwise."""


DroneController = WallFollowController | GoToLandmarkStatController | GoToLandmarkDynController | MetricTurnController | MetricStepController | AltitudeController
UgvController = UgvForwardController | UgvTurnController


def triggers(c: DroneController | UgvController) -> tuple[str, ...]:
    """T(c): the perceptual triggers that may stop controller c early (002 §III-A)."""
    if isinstance(c, WallFollowController):
        return (OPENING_RIGHT if c.side == "left" else OPENING_LEFT, LANDMARK_SIGHTED)
    return ()


def wall_side(side: Side, heading: int) -> int:
    """The cardinal heading pointing from the drone to the wall it follows."""
    return (heading + 2) % 8 if side == "left" else (heading + 6) % 8


def follow_wall(s: Sensing, k: int, r: int, c: int, side: Side, heading: int) -> dict[str | None, tuple[int, int, int]]:
    """Phi for WALLFOLLOWING, all triggers in one walk: {trigger: (row, col, cells travelled)}.

    Key None is the intrinsic end: OBSTACLE (the sensor facing the travel, front or back, sees the
    cell ahead blocked) or WALL_END (the side reading differs from the distance held at the start:
    the wall ended, opened or jogged). Perceptual triggers fire at the first cell where they are
    sensed, if before the intrinsic end; OBSTACLE also fires perceptually where an obstacle first
    comes within OBSTACLE_CELLS ahead (when it is already that close at the start, it does not). A blocked cell ahead that the sensors cannot see (an obstacle top below the
    drone's altitude but within its clearance) would be a crash: then there is no intrinsic end
    and only earlier perceptual triggers remain. Empty when no wall is within IR range (002 §III-B).
    """
    perp = wall_side(side, heading)
    opp = (perp + 4) % 8
    held = s.side_range(k, r, c, perp)
    if held == 0 or heading % 2:
        return {}
    opening = OPENING_RIGHT if side == "left" else OPENING_LEFT
    dr, dc = DIRS[heading]
    out: dict[str | None, tuple[int, int, int]] = {}
    opp_wall = s.side_range(k, r, c, opp) > 0
    bits = s.landmarks_seen(k, r, c)
    near = _obstacle_ahead(s, k, r, c, dr, dc)
    n = 0
    while True:
        r2, c2 = r + dr, c + dc
        if not s.drone_free(k, r2, c2):
            if n and s.front_sensed(k, r2, c2):
                out[None] = (r, c, n)
            return out
        r, c, n = r2, c2, n + 1
        now_near = _obstacle_ahead(s, k, r, c, dr, dc)
        if now_near and not near and OBSTACLE not in out:
            out[OBSTACLE] = (r, c, n)
        near = now_near
        if s.side_range(k, r, c, perp) != held:
            out[None] = (r, c, n)
            return out
        now_wall = s.side_range(k, r, c, opp) > 0
        if opp_wall and not now_wall and opening not in out:
            out[opening] = (r, c, n)
        opp_wall = now_wall
        now_bits = s.landmarks_seen(k, r, c)
        if now_bits & ~bits and LANDMARK_SIGHTED not in out:
            out[LANDMARK_SIGHTED] = (r, c, n)
        bits = now_bits


def _obstacle_ahead(s: Sensing, k: int, r: int, c: int, dr: int, dc: int) -> bool:
    """The IR sensor facing the travel sees an obstacle within OBSTACLE_CELLS."""
    return any(s.front_sensed(k, r + dr * j, c + dc * j) for j in range(1, OBSTACLE_CELLS + 1))


def landmark_cell(s: Sensing, i: int) -> tuple[int, int]:
    lm = s.env.landmarks[i]
    return s.env.cell_of(lm.x, lm.y)


def stat_targets(s: Sensing, k: int, r: int, c: int, i: int) -> list[tuple[int, int]]:
    """Phi for GOTOLANDMARK_STAT(i): targets near landmark i reachable in a straight flight that
    keeps it in view. Empty when landmark i is not in view (the precondition)."""
    bit = 1 << i
    if not s.landmarks_seen(k, r, c) & bit:
        return []
    lr, lc = landmark_cell(s, i)
    m = s.model.station_cells
    out = []
    for r2 in range(lr - m, lr + m + 1):
        for c2 in range(lc - m, lc + m + 1):
            if (r2, c2) != (r, c) and s.drone_free(k, r2, c2) and all(
                s.drone_free(k, a, b) and s.landmarks_seen(k, a, b) & bit for a, b in s.flight_cells(r, c, r2, c2)
            ):
                out.append((r2, c2))
    return out


def dyn_targets(s: Sensing, k: int, r: int, c: int, ur: int, uc: int) -> list[tuple[int, int]]:
    """Phi for GOTOLANDMARK_DYN with the UGV in (ur, uc): targets near the UGV reachable in a straight
    flight that keeps its markers in view and range. Empty when the drone does not see the UGV."""
    if not s.sees_ugv(k, r, c, ur, uc):
        return []
    m = s.model.station_cells
    out = []
    for r2 in range(ur - m, ur + m + 1):
        for c2 in range(uc - m, uc + m + 1):
            if (r2, c2) != (r, c) and s.drone_free(k, r2, c2) and all(
                s.drone_free(k, a, b) and s.sees_ugv(k, a, b, ur, uc) for a, b in s.flight_cells(r, c, r2, c2)
            ):
                out.append((r2, c2))
    return out


def metric_target(s: Sensing, k: int, r: int, c: int, heading: int, cells: int) -> tuple[int, int] | None:
    """Phi for METRICSTEP(cells) along `heading`: the end cell, or None where not allowed."""
    dr, dc = DIRS[heading]
    r2, c2 = r + dr * cells, c + dc * cells
    for a, b in s.flight_cells(r, c, r2, c2):
        if not (s.drone_free(k, a, b) and s.metric_allowed(a, b)):
            return None
    return r2, c2


def corner_target(
    s: Sensing, k: int, r: int, c: int, heading: int, turn: int, cells: tuple[int, int]
) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """Phi of the paper's metric group for turning a corner (002 fn. 3): METRICSTEP(cells[0]) along
    cardinal `heading`, METRICTURN to heading + turn (turn +2 = 90 deg counter-clockwise, -2
    clockwise), METRICSTEP(cells[1]). Returns (the cell after the first step, the end cell), or None
    where a step is blocked or metric motion is not allowed (the turn happens in the middle cell)."""
    if heading % 2 or turn not in (2, -2):
        return None
    mid = metric_target(s, k, r, c, heading, cells[0])
    if mid is None or not s.metric_allowed(*mid):
        return None
    end = metric_target(s, k, *mid, (heading + turn) % 8, cells[1])
    return None if end is None else (mid, end)


def altitude_ok(s: Sensing, k: int, r: int, c: int, k2: int) -> bool:
    """Phi precondition for ALTITUDE(k2): the column between the two levels is free."""
    return k2 != k and all(s.drone_free(j, r, c) for j in range(min(k, k2), max(k, k2) + 1))


def ugv_forward(s: Sensing, r: int, c: int, heading: int) -> tuple[int, int] | None:
    """The UGV's forward primitive: one cell along its heading, no corner cutting."""
    dr, dc = DIRS[heading]
    if not s.ugv_ok(r + dr, c + dc):
        return None
    if dr and dc and not (s.ugv_ok(r + dr, c) and s.ugv_ok(r, c + dc)):
        return None
    return r + dr, c + dc


def phi(
    s: Sensing, pose: DronePose, ctl: DroneController, trigger: str | None = None, ugv: UgvPose | None = None
) -> DronePose | None:
    """Phi(s, c, tau) (002 §III-A): run drone controller `ctl` from `pose` until `trigger` or an
    intrinsic trigger, whichever comes first. None when `ctl` is not in C(s) (or needs the UGV)."""
    k, r, c = pose.level, pose.row, pose.col
    if isinstance(ctl, WallFollowController):
        out = follow_wall(s, k, r, c, ctl.side, ctl.heading)
        end = out.get(trigger) or out.get(None)
        return DronePose(k, end[0], end[1], ctl.heading) if end else None
    if isinstance(ctl, GoToLandmarkStatController):
        ok = ctl.target in stat_targets(s, k, r, c, ctl.landmark)
        return DronePose(k, *ctl.target, pose.heading) if ok else None
    if isinstance(ctl, GoToLandmarkDynController):
        ok = ugv is not None and ctl.target in dyn_targets(s, k, r, c, ugv.row, ugv.col)
        return DronePose(k, *ctl.target, pose.heading) if ok else None
    if isinstance(ctl, MetricTurnController):
        return DronePose(k, r, c, ctl.heading) if s.metric_allowed(r, c) else None
    if isinstance(ctl, MetricStepController):
        end = metric_target(s, k, r, c, pose.heading, ctl.cells)
        return DronePose(k, *end, pose.heading) if end else None
    return DronePose(ctl.level, r, c, pose.heading) if altitude_ok(s, k, r, c, ctl.level) else None


def phi_ugv(s: Sensing, pose: UgvPose, ctl: UgvController) -> UgvPose | None:
    """The UGV's metric motion primitives (002 §III-B: METRICMOTION)."""
    if isinstance(ctl, UgvTurnController):
        return UgvPose(pose.row, pose.col, (pose.heading + ctl.delta) % 8)
    end = ugv_forward(s, pose.row, pose.col, pose.heading)
    return UgvPose(*end, pose.heading) if end else None
