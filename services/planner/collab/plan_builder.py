"""Building a team plan (002 §IV-E) from a team path on the SLC lattice: each transition becomes
the cheapest controller action that makes it, consecutive UGV motions merge, and every
GOTOLANDMARK_DYN gets its sync points. The plan's data types live in `common.domain.team_plan`.
"""

from __future__ import annotations

import math

from common.domain.team_plan import (
    PLAN_FORMAT,
    Altitude,
    DroneAction,
    GoToLandmarkDyn,
    GoToLandmarkStat,
    MetricMotion,
    MetricStep,
    MetricTurn,
    Step,
    TeamPlan,
    Vec3,
    WallFollowing,
)
from common.team.sensing import DIRS
from services.planner.collab.lattice import Lattice


class _TeamPlanBuilder:
    """Turns a team path into the two robots' step lists with sync points and merged UGV motions."""

    def __init__(self) -> None:
        self.drone: list[Step] = []
        self.ugv: list[Step] = []
        self.ugv_barrier = 0
        self.ugv_mergeable = False

    def add_drone(self, action: DroneAction, end: Vec3, cost: float, coupled: bool) -> None:
        self.drone.append(Step(action, end, cost, len(self.ugv) if coupled else 0))
        if coupled:
            self.ugv_barrier = len(self.drone)
            self.ugv_mergeable = False

    def add_ugv(self, motion: MetricMotion, end: Vec3, cost: float) -> None:
        last = self.ugv[-1] if self.ugv and self.ugv_mergeable else None
        if last is not None and isinstance(last.action, MetricMotion):
            prev = last.action
            if motion.turn_deg == 0.0 or prev.distance_m == 0.0:
                merged = MetricMotion(prev.turn_deg + motion.turn_deg, prev.distance_m + motion.distance_m)
                self.ugv[-1] = Step(merged, end, last.cost + cost, last.wait_for)
                return
        self.ugv.append(Step(motion, end, cost, self.ugv_barrier))
        self.ugv_mergeable = True


def _xyz(lat: Lattice, d: int) -> Vec3:
    k, r, c = lat.drone_pose(d)
    x, y = lat.s.env.center(r, c)
    return (x, y, lat.s.env.z_levels[k])


def _ugv_pose(lat: Lattice, u: int) -> Vec3:
    r, c, heading = lat.ugv_pose(u)
    x, y = lat.s.env.center(r, c)
    return (x, y, 45.0 * heading)


def build_team_plan(
    lat: Lattice, path: list[int], planner: str, cost: float, eps: float, planning_time_s: float, expansions: int
) -> TeamPlan:
    """A team path (`Lattice.team_id` states) -> TeamPlan, relabelling each transition with the cheapest
    controller that makes it (002 §III-A: several controller/trigger pairs may join two states)."""
    env, res = lat.s.env, lat.s.env.resolution
    b = _TeamPlanBuilder()
    for a, z in zip(path, path[1:], strict=False):
        (d, u, _), (d2, u2, _) = lat.team_decode(a), lat.team_decode(z)
        if u != u2:
            r, c, h = lat.ugv_pose(u)
            r2, c2, h2 = lat.ugv_pose(u2)
            step_cost = next(cst for v, cst in lat.ugv_succ(u) if v == u2)
            if (r, c) == (r2, c2):
                motion = MetricMotion(turn_deg=45.0 * (((h2 - h + 4) % 8) - 4))
            else:
                motion = MetricMotion(distance_m=math.hypot(r2 - r, c2 - c) * res)
            b.add_ugv(motion, _ugv_pose(lat, u2), step_cost)
            continue
        step_cost, label = lat.drone_label(d, d2, u // 9)
        end = _xyz(lat, d2)
        kind = label[0]
        if kind == "WF":
            _, side, heading, trig = label
            b.add_drone(WallFollowing(side, 45.0 * heading, trig), end, step_cost, False)
        elif kind == "STAT":
            b.add_drone(GoToLandmarkStat(env.landmarks[label[1]].id, end), end, step_cost, False)
        elif kind == "METRIC":
            _, heading, n = label
            turn = lat.m.cost_metric_turn + lat.m.cost_action
            b.add_drone(MetricTurn(45.0 * heading), _xyz(lat, d), turn, False)
            b.add_drone(MetricStep(n * math.hypot(*DIRS[heading]) * res), end, step_cost - turn, False)
        elif kind == "CORNER":  # 002 fn. 3: METRICSTEP(0.5 m) -> METRICTURN(+-90) -> METRICSTEP(1.0 m)
            _, heading, turn, n1, n2 = label
            m, k, r, c = lat.m, *lat.drone_pose(d)
            mid = _xyz(lat, lat.drone_id(k, r + DIRS[heading][0] * n1, c + DIRS[heading][1] * n1))
            align = m.cost_metric_turn + m.cost_action
            b.add_drone(MetricTurn(45.0 * heading), _xyz(lat, d), align, False)
            b.add_drone(MetricStep(n1 * res), mid, n1 * res * m.cost_metric, False)
            b.add_drone(MetricTurn(45.0 * ((heading + turn) % 8)), mid, m.cost_metric_turn, False)
            b.add_drone(MetricStep(n2 * res), end, step_cost - align - n1 * res * m.cost_metric - m.cost_metric_turn, False)
        elif kind == "ALT":
            b.add_drone(Altitude(end[2]), end, step_cost, False)
        else:
            ux, uy, _ = _ugv_pose(lat, u)
            offset = (end[0] - ux, end[1] - uy, end[2] - lat.m.ugv_height)
            b.add_drone(GoToLandmarkDyn(offset, end), end, step_cost, True)
    d0, u0, _ = lat.team_decode(path[0])
    return TeamPlan(
        format=PLAN_FORMAT,
        map=env.name,
        planner=planner,
        drone_start=_xyz(lat, d0),
        ugv_start=_ugv_pose(lat, u0),
        goal=_xyz(lat, lat.team_drone(path[-1])),
        drone=tuple(b.drone),
        ugv=tuple(b.ugv),
        cost=cost,
        epsilon=eps,
        planning_time_s=planning_time_s,
        expansions=expansions,
    )
