"""Team planning queries: PAD (002 §IV) or the full-dimensional ARA* baseline (002 §V-D) on the
SLC team graph of a map, returning a TeamPlan (002 §IV-E) and the effort spent."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Literal

from common.domain.team_plan import TeamPlan, Vec3
from common.errors import InputError
from common.team.env import Env
from common.team.sensing import Sensing
from common.team.team_model import TeamModel
from services.planner.collab.arastar import arastar
from services.planner.collab.lattice import Lattice, ugv_area
from services.planner.collab.pad import PadConfig, pad
from services.planner.collab.plan_builder import build_team_plan

Method = Literal["pad", "arastar"]


@dataclass(frozen=True)
class Problem:
    """Drone start and goal (level, row, col); UGV start (row, col, heading 0..7)."""

    drone_start: tuple[int, int, int]
    ugv_start: tuple[int, int, int]
    goal: tuple[int, int, int]


@dataclass(frozen=True)
class AraConfig:
    eps0: float = 2.0
    eps_step: float = 0.25


@dataclass
class Outcome:
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

    def __init__(self, env: Env, model: TeamModel | None = None) -> None:
        self.env = env
        self.sensing = Sensing(env, model or TeamModel())
        self._lattices: dict[bytes, Lattice] = {}

    def lattice(self, ugv_cell: tuple[int, int]) -> Lattice:
        area = ugv_area(self.sensing, ugv_cell)
        key = area.tobytes()
        if key not in self._lattices:
            self._lattices[key] = Lattice(self.sensing, area)
        return self._lattices[key]

    def check(self, problem: Problem, source: str = "problem") -> None:
        """InputError unless the drone's start and goal are free and the UGV may stand at its start."""
        s = self.sensing
        for name, (k, r, c) in (("drone_start", problem.drone_start), ("goal", problem.goal)):
            if not (0 <= k < s.levels and s.drone_free(k, r, c)):
                raise InputError(source, name, f"level {k} cell ({r}, {c}) is not free for the drone")
        r, c, heading = problem.ugv_start
        if not (s.ugv_ok(r, c) and 0 <= heading < 8):
            raise InputError(source, "ugv_start", f"cell ({r}, {c}) heading {heading} is not allowed for the UGV")

    def problem_at(self, drone_start: Vec3, ugv_start: Vec3, goal: Vec3, source: str = "problem") -> Problem:
        """A problem given in metres and degrees (drone x, y, z; UGV x, y, heading_deg; goal x, y, z),
        on the lattice and checked (InputError naming the field)."""
        env = self.env
        problem = Problem(
            drone_start=(env.level_of(drone_start[2]), *env.cell_of(drone_start[0], drone_start[1])),
            ugv_start=(*env.cell_of(ugv_start[0], ugv_start[1]), round(ugv_start[2] / 45.0) % 8),
            goal=(env.level_of(goal[2]), *env.cell_of(goal[0], goal[1])),
        )
        self.check(problem, source)
        return problem

    def plan(
        self,
        problem: Problem,
        method: Method = "pad",
        time_limit: float = math.inf,
        improve_s: float = 0.0,
        pad_config: PadConfig | None = None,
        ara_config: AraConfig | None = None,
    ) -> Outcome:
        """Plan from `problem`; `time_limit` bounds the first solution, `improve_s` the improvement
        after it (002 §V-D: first solution plus up to 5 s). The per-goal heuristic is timed."""
        self.check(problem)
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
        return Outcome(plan, first, elapsed, res.expansions, res.iterations, res.cost, res.eps, res.timed_out)
