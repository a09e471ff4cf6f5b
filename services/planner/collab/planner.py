"""Team planning queries: PAD (002 §IV) or the full-dimensional ARA* baseline (002 §V-D) on the
SLC team graph of a map, returning a TeamPlan (002 §IV-E) and the effort spent."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Literal

from common.domain.team_plan import TeamPlan, Vec3
from common.team.env import Env
from common.team.problem import TeamProblem, check_problem, problem_in_metres
from common.team.sensing import Sensing
from common.team.team_model import TeamModel
from services.planner.collab.arastar import arastar
from services.planner.collab.lattice import Lattice, SlcOptions, ugv_area
from services.planner.collab.pad import PadConfig, pad
from services.planner.collab.plan_builder import build_team_plan

Method = Literal["pad", "arastar"]


@dataclass(frozen=True)
class AraConfig:
    eps0: float = 2.0
    eps_step: float = 0.25


@dataclass
class TeamPlanOutcome:
    """A query's result: the plan (None if unsolved) and the figures of 002 Tables I-II."""

    plan: TeamPlan | None
    first_solution_s: float | None
    planning_time_s: float
    expansions: int
    iterations: int
    cost: float
    eps: float
    timed_out: bool


class TeamPlanner:
    """Plans on one map; the SLC graph of each UGV area is built once and reused across queries."""

    def __init__(self, env: Env, model: TeamModel | None = None, options: SlcOptions | None = None) -> None:
        self.env = env
        self.sensing = Sensing(env, model or TeamModel())
        self.options = options or SlcOptions()
        self._lattices: dict[bytes, Lattice] = {}

    def lattice(self, ugv_cell: tuple[int, int]) -> Lattice:
        area = ugv_area(self.sensing, ugv_cell)
        key = area.tobytes()
        if key not in self._lattices:
            self._lattices[key] = Lattice(self.sensing, area, self.options)
        return self._lattices[key]

    def problem_at(self, drone_start: Vec3, ugv_start: Vec3, goal: Vec3, source: str = "problem") -> TeamProblem:
        """`problem_in_metres` on this planner's map."""
        return problem_in_metres(self.sensing, drone_start, ugv_start, goal, source)

    def plan(
        self,
        problem: TeamProblem,
        method: Method = "pad",
        time_limit: float = math.inf,
        improve_s: float = 0.0,
        pad_config: PadConfig | None = None,
        ara_config: AraConfig | None = None,
    ) -> TeamPlanOutcome:
        """Plan from `problem`; `time_limit` bounds the first solution, `improve_s` the improvement
        after it (002 §V-D: first solution plus up to 5 s). The per-goal heuristic is timed."""
        check_problem(self.sensing, problem)
        lat = self.lattice(problem.ugv_start[:2])
        t0 = time.perf_counter()
        goal = lat.drone_id(*problem.goal)
        h = lat.cost_to_go(goal)
        start = lat.team_id(lat.drone_id(*problem.drone_start), lat.ugv_id(*problem.ugv_start))
        setup = time.perf_counter() - t0
        if method == "pad":
            res = pad(lat, start, goal, h, pad_config or PadConfig(), time_limit - setup, improve_s)
        else:
            hl, drone, cfg = h.tolist(), lat.team_drone, ara_config or AraConfig()
            res = arastar(
                start, lat.team_succ, lambda x: hl[drone(x)], lambda x: drone(x) == goal,
                cfg.eps0, cfg.eps_step, 1.0, time_limit - setup, improve_s,
            )
        elapsed = time.perf_counter() - t0
        first = None if res.first_solution_s is None else setup + res.first_solution_s
        plan = None
        if res.path is not None:
            plan = build_team_plan(lat, res.path, method, res.cost, res.eps, elapsed, res.expansions)
        return TeamPlanOutcome(plan, first, elapsed, res.expansions, res.iterations, res.cost, res.eps, res.timed_out)
