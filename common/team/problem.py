"""A ground-air team's problem on the lattice of a map (002 §III, §V-C): where the drone starts and
must go, where the UGV starts; checked against the map (free cells, UGV headings)."""

from __future__ import annotations

from dataclasses import dataclass

from common.domain.team_plan import Vec3
from common.errors import InputError
from common.team.sensing import Sensing


@dataclass(frozen=True)
class TeamProblem:
    """Drone start and goal (level, row, col); UGV start (row, col, heading 0..7)."""

    drone_start: tuple[int, int, int]
    ugv_start: tuple[int, int, int]
    goal: tuple[int, int, int]


def check_problem(sensing: Sensing, problem: TeamProblem, source: str = "problem") -> None:
    """InputError unless the drone's start and goal are free and the UGV may stand at its start."""
    s = sensing
    for name, (k, r, c) in (("drone_start", problem.drone_start), ("goal", problem.goal)):
        if not (0 <= k < s.levels and s.drone_free(k, r, c)):
            raise InputError(source, name, f"level {k} cell ({r}, {c}) is not free for the drone")
    r, c, heading = problem.ugv_start
    if not (s.ugv_ok(r, c) and 0 <= heading < 8):
        raise InputError(source, "ugv_start", f"cell ({r}, {c}) heading {heading} is not allowed for the UGV")


def problem_in_metres(sensing: Sensing, drone_start: Vec3, ugv_start: Vec3, goal: Vec3,
                      source: str = "problem") -> TeamProblem:
    """A problem given in metres and degrees (drone x, y, z; UGV x, y, heading_deg; goal x, y, z),
    on the lattice and checked (InputError naming the field)."""
    env = sensing.env
    problem = TeamProblem(
        drone_start=(env.level_of(drone_start[2]), *env.cell_of(drone_start[0], drone_start[1])),
        ugv_start=(*env.cell_of(ugv_start[0], ugv_start[1]), round(ugv_start[2] / 45.0) % 8),
        goal=(env.level_of(goal[2]), *env.cell_of(goal[0], goal[1])),
    )
    check_problem(sensing, problem, source)
    return problem
