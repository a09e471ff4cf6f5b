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


def run(sizes: list[int], trials: int, mu: float, time_limit: float, log=print) -> dict:
    """SIPP on `trials` seeded scenarios per fleet size; every plan validated. JSON-able."""
    graph = load_graph("city934")
    t0 = time.perf_counter()
    plan_sipp(graph, random_tasks(graph, 2, 0), mu, time_limit, 0)  # build the per-graph tables
    tables_s = time.perf_counter() - t0
    log(f"city934: {graph.n_nodes} nodes, {graph.n_edges} edges; tables built in {tables_s:.2f} s")
    runs = []
    for n in sizes:
        for seed in range(trials):
            tasks = city_tasks(graph, n, seed)
            result = plan_sipp(graph, tasks, mu, time_limit, seed)
            report = validate_plan(to_plan(graph, "city934", "sipp", mu, tasks, result)) if result.ok else None
            runs.append({
                "vehicles": n, "seed": seed, "ok": result.ok, "valid": bool(report and report.ok),
                "seconds": result.planning_time_s, "cost": result.cost if result.ok else None,
                "orders": result.stats.get("orders", 0), "makespan_s": report.makespan if report else None,
                "fliers": sum(any(graph.airborne[graph.index[e.node]] for e in p) for p in result.paths.values()),
                "error": result.error,
            })
        log(f"  {n} vehicles: {sum(r['ok'] for r in runs if r['vehicles'] == n)}/{trials} solved")
    return {"map": "city934", "nodes": graph.n_nodes, "edges": graph.n_edges, "mu": mu, "time_limit_s": time_limit,
            "sizes": sizes, "trials": trials, "tables_s": tables_s, "runs": runs}


def table(results: dict) -> tuple[list[str], list[list]]:
    rows = []
    for n in results["sizes"]:
        mine = [r for r in results["runs"] if r["vehicles"] == n]
        solved = [r for r in mine if r["ok"]]
        times = [r["seconds"] for r in mine]
        rows.append([
            n, f"{len(solved)}/{len(mine)}", sum(r["valid"] for r in mine), f"{statistics.median(times):.3f}",
            f"{max(times):.3f}", f"{statistics.mean(r['cost'] for r in solved):.2f}" if solved else "-",
            f"{statistics.mean(r['cost'] / n for r in solved):.3f}" if solved else "-",
            f"{statistics.mean(r['fliers'] for r in solved):.1f}" if solved else "-",
            f"{statistics.mean(r['orders'] for r in mine):.1f}",
        ])
    return ["vehicles", "solved", "valid", "median s", "max s", "mean cost", "cost/vehicle", "fliers", "orders"], rows


def figure(results: dict, out, name: str = "scale_city"):
    sizes, runs, mu = results["sizes"], results["runs"], results["mu"]
    times = {n: [r["seconds"] for r in runs if r["vehicles"] == n] for n in sizes}
    costs = {n: [r["cost"] / n for r in runs if r["vehicles"] == n and r["ok"]] for n in sizes}
    fig, (ax_t, ax_c) = new_figure(2)
    ax_t.plot(sizes, [statistics.median(times[n]) for n in sizes], "o-", label="median")
    for n in sizes:
        ax_t.scatter([n] * len(times[n]), times[n], s=10, color="grey", alpha=0.6)
    ax_t.set(xlabel="vehicles", ylabel="planning time (s)", title="SIPP planning time, city934")
    ax_t.legend()
    ax_c.plot(sizes, [statistics.mean(costs[n]) if costs[n] else float("nan") for n in sizes], "s-", color="C1")
    ax_c.set(xlabel="vehicles", ylabel="mean eq. 3 cost per vehicle", title=f"cost per vehicle (mu = {mu})")
    return save_figure(fig, out, name)


def main(argv: list[str] | None = None) -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[20, 40, 80, 120])
    parser.add_argument("--trials", type=int, default=5, help="random scenarios per size")
    parser.add_argument("--mu", type=float, default=0.5)
    parser.add_argument("--time-limit", type=float, default=60.0)
    args = parser.parse_args(argv)
    results = run(args.sizes, args.trials, args.mu, args.time_limit)
    print(f"\nSIPP on city934, mu = {args.mu}, {args.trials} random scenarios per size")
    print(format_table(*table(results)))
    print(f"wrote {figure(results, args.out)}")


if __name__ == "__main__":
    main()
