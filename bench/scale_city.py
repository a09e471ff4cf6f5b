"""Prioritized SIPP on the 934-node city (paper 000 §VII-B: "up to 80 vehicles in the large map").

For each fleet size, several seeded random scenarios: planning time, eq. 3 cost (total and per
vehicle), priority orders tried, solved, and the independent validator's verdict. The city has 150
parking spots, so from 76 vehicles on some goals are other vehicles' starts (they must leave first).
Times are warm: the graph, its contact windows and the planner's per-graph tables are built before
the clock starts (`fleet plan` pays them once per map per process).

    python -m bench.scale_city [--sizes 20 40 80 120] [--trials 5] [--mu 0.5] [--out out]
"""

from __future__ import annotations

import random
import statistics
import time

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.domain.planfile import Task
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.maps.loading import load_graph
from services.planner.maps.tasks import random_tasks
from services.planner.result import to_plan
from services.planner.sipp.planner import plan_sipp
from services.planner.validate import validate_plan


def city_tasks(graph: FleetGraph, n: int, seed: int) -> dict[str, Task]:
    """n vehicles on distinct starts with distinct goals; beyond half the spots, goals reuse other
    vehicles' starts (never a vehicle's own)."""
    spots = sorted(graph.endpoints())
    if 2 * n <= len(spots):
        return random_tasks(graph, n, seed)
    rng = random.Random(seed)
    starts = rng.sample(spots, n)
    free = [s for s in spots if s not in set(starts)]
    goals = free + rng.sample(starts, n - len(free))
    while True:
        rng.shuffle(goals)
        if all(s != g for s, g in zip(starts, goals, strict=True)):
            break
    width = len(str(n))
    return {f"cf{i + 1:0{width}d}": Task(start=s, goal=g) for i, (s, g) in enumerate(zip(starts, goals, strict=True))}


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[20, 40, 80, 120])
    parser.add_argument("--trials", type=int, default=5, help="random scenarios per size")
    parser.add_argument("--mu", type=float, default=0.5)
    parser.add_argument("--time-limit", type=float, default=60.0)
    args = parser.parse_args()

    graph = load_graph("city934")
    t0 = time.perf_counter()
    plan_sipp(graph, random_tasks(graph, 2, 0), args.mu, args.time_limit, 0)  # build the per-graph tables
    print(f"city934: {graph.n_nodes} nodes, {graph.n_edges} edges; tables built in {time.perf_counter() - t0:.2f} s")

    rows, times, costs = [], {}, {}
    for n in args.sizes:
        runs = []
        for seed in range(args.trials):
            tasks = city_tasks(graph, n, seed)
            result = plan_sipp(graph, tasks, args.mu, args.time_limit, seed)
            valid = result.ok and validate_plan(to_plan(graph, "city934", "sipp", args.mu, tasks, result)).ok
            runs.append((result, valid))
        solved = [r for r, _ in runs if r.ok]
        times[n] = [r.planning_time_s for r, _ in runs]
        costs[n] = [r.cost / n for r in solved]
        rows.append([
            n, f"{len(solved)}/{len(runs)}", sum(v for _, v in runs),
            f"{statistics.median(times[n]):.3f}", f"{max(times[n]):.3f}",
            f"{statistics.mean(r.cost for r in solved):.2f}" if solved else "-",
            f"{statistics.mean(costs[n]):.3f}" if solved else "-",
            f"{statistics.mean(r.stats['orders'] for r, _ in runs):.1f}",
        ])
    headers = ["vehicles", "solved", "valid", "median s", "max s", "mean cost", "cost/vehicle", "orders"]
    print(f"\nSIPP on city934, mu = {args.mu}, {args.trials} random scenarios per size")
    print(format_table(headers, rows))

    fig, (ax_t, ax_c) = new_figure(2)
    sizes = list(times)
    ax_t.plot(sizes, [statistics.median(times[n]) for n in sizes], "o-", label="median")
    for n in sizes:
        ax_t.scatter([n] * len(times[n]), times[n], s=10, color="grey", alpha=0.6)
    ax_t.set(xlabel="vehicles", ylabel="planning time (s)", title="SIPP planning time, city934")
    ax_t.legend()
    ax_c.plot(sizes, [statistics.mean(costs[n]) if costs[n] else float("nan") for n in sizes], "s-", color="C1")
    ax_c.set(xlabel="vehicles", ylabel="mean eq. 3 cost per vehicle", title=f"cost per vehicle (mu = {args.mu})")
    print(f"wrote {save_figure(fig, args.out, 'scale_city')}")


if __name__ == "__main__":
    main()
