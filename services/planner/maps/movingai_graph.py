"""MovingAI MAPF benchmarks (Stern et al. 2019): a `.map` grid becomes a ground graph of unit-length,
4-connected drive edges (optionally with an air layer above, blocked cells as low buildings), and a
`.scen` file gives the tasks. Bodies of radius 0.25 and unit speed make vertex and swap conflicts,
and nothing else, bring two bodies into contact: the standard MAPF semantics.
"""

from __future__ import annotations

from pathlib import Path

from common.domain.mapfile import AirRegion, MapSpec, Obstacle, RoadNode, Roads, read_text
from common.domain.movingai import read_grid
from common.domain.planfile import Task
from common.domain.vehicle_model import Speeds, VehicleModel
from common.errors import InputError
from services.planner.graph.fleet_graph import FleetGraph, build_graph

GRID_MODEL = VehicleModel(radius=0.25, height=0.5, speed=Speeds(drive=1.0, takeoff=1.0, fly=1.0, land=1.0))


def cell_id(x: int, y: int) -> str:
    return f"{x}_{y}"


def movingai_spec(path: str | Path, air: bool = False) -> MapSpec:
    free = read_grid(path)
    h, w = free.shape
    nodes = {cell_id(x, y): RoadNode(float(x), float(y)) for y in range(h) for x in range(w) if free[y, x]}
    edges = [
        (cell_id(x, y), cell_id(x + dx, y + dy))
        for y in range(h)
        for x in range(w)
        for dx, dy in ((1, 0), (0, 1))
        if free[y, x] and y + dy < h and x + dx < w and free[y + dy, x + dx]
    ]
    obstacles = [
        Obstacle(name=f"cell_{x}_{y}", min=(x - 0.5, y - 0.5, -0.5), max=(x + 0.5, y + 0.5, 0.5))
        for y in range(h) for x in range(w) if not free[y, x]
    ] if air else []
    return MapSpec(
        name=Path(path).stem,
        roads=Roads(nodes=nodes, two_way=edges),
        air=AirRegion(bounds=(0, 0, w - 1, h - 1), layers=[1.5], spacing=1.0, diagonals=False) if air else None,
        obstacles=obstacles,
        vehicle=GRID_MODEL,
        time_step=1.0,
    )


def load_movingai(path: str | Path, air: bool = False) -> FleetGraph:
    return build_graph(movingai_spec(path, air), source=str(path), open_endpoints=True)


def load_scen(path: str | Path, graph: FleetGraph, agents: int) -> dict[str, Task]:
    """The first `agents` tasks of a `.scen` file (x = column, y = row). A grid may have several
    connected components (isolated free cells, closed rooms); only the ones the tasks use matter,
    and a task whose start and goal lie in different components is an InputError naming its line."""
    lines = [ln for ln in read_text(Path(path)).splitlines() if ln.strip()]
    if not lines or not lines[0].startswith("version"):
        raise InputError(str(path), "line 1", "not a MovingAI scenario (expected 'version 1')")
    rows = lines[1:]
    if agents < 1 or agents > len(rows):
        raise InputError(str(path), "--agents", f"needs 1 <= K <= {len(rows)}, got {agents}")
    tasks: dict[str, Task] = {}
    width = len(str(agents))
    for i, line in enumerate(rows[:agents]):
        parts = line.split("\t")
        try:
            sx, sy, gx, gy = (int(v) for v in parts[4:8])
        except ValueError:
            raise InputError(str(path), f"line {i + 2}", "expected start_x start_y goal_x goal_y integers") from None
        start, goal = cell_id(sx, sy), cell_id(gx, gy)
        for what, node in (("start", start), ("goal", goal)):
            if node not in graph.index:
                raise InputError(str(path), f"line {i + 2}", f"{what} {node} is not a free cell of {graph.name}")
        if not graph.joined(start, goal):
            raise InputError(str(path), f"line {i + 2}", f"start {start} and goal {goal} are in different connected "
                             f"components of {graph.name}: no path joins them")
        tasks[f"a{i:0{width}d}"] = Task(start=start, goal=goal)
    return tasks
