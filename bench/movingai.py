"""Prioritized SIPP on the MovingAI benchmark random-32-32-10 (Stern et al. 2019) with the first
50, 100, ..., 300 agents of its scenario: solved or not, planning time, restarts, sum of costs.

Grid semantics (services/planner/maps/movingai_graph.py): unit cells, unit speed, bodies of radius 0.25, so
only vertex and swap conflicts bring bodies into contact, in continuous time. mu = 0, so the eq. 3
cost is the sum over agents of their arrival times (t_max = 1 s), the usual sum of costs.

    python -m bench.movingai [--agents 50 100 ... 300] [--time-limit 60] [--scen ...] [--out out]
"""

from __future__ import annotations

import time
from pathlib import Path

from bench.tables import bench_parser, format_table, new_figure, save_figure
from services.planner.maps.movingai_graph import load_movingai, load_scen
from services.planner.result import to_plan
from services.planner.sipp.planner import plan_sipp
from services.planner.validate import validate_plan

BENCH_DIR = Path(__file__).resolve().parent.parent.parent / "shared" / "benchmarks" / "movingai"


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--map", default=str(BENCH_DIR / "random-32-32-10.map"))
    parser.add_argument("--scen", default=str(BENCH_DIR / "random-32-32-10-random-1.scen"))
    parser.add_argument("--agents", type=int, nargs="+", default=[50, 100, 150, 200, 250, 300])
    parser.add_argument("--time-limit", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for path in (args.map, args.scen):
        if not Path(path).is_file():
            parser.error(f"{path} is missing: the MovingAI benchmark files live in ../shared/benchmarks/movingai "
                         "(or give --map and --scen)")

    graph = load_movingai(args.map)
    t0 = time.perf_counter()
    plan_sipp(graph, load_scen(args.scen, graph, 1), 0.0, args.time_limit, args.seed)  # per-graph tables
    print(f"{graph.name}: {graph.n_nodes} cells, {graph.n_edges} edges; tables built in {time.perf_counter() - t0:.2f} s")

    rows, points = [], []
    for k in args.agents:
        tasks = load_scen(args.scen, graph, k)
        result = plan_sipp(graph, tasks, 0.0, args.time_limit, args.seed)
        valid = result.ok and validate_plan(to_plan(graph, graph.name, "sipp", 0.0, tasks, result)).ok
        soc = sum(p[-1].t for p in result.paths.values()) if result.ok else float("nan")
        rows.append([
            k, "yes" if result.ok else "no", "yes" if valid else "-", f"{result.planning_time_s:.2f}",
            int(result.stats.get("orders", 0)), f"{soc:.1f}" if result.ok else "-",
            f"{soc / k:.2f}" if result.ok else "-",
        ])
        points.append((k, result.planning_time_s, result.ok))
        print(f"  {k} agents: {'solved' if result.ok else 'unsolved: ' + result.error} in {result.planning_time_s:.2f} s", flush=True)
    print(f"\nSIPP with restarts on {graph.name}, {Path(args.scen).name}, time limit {args.time_limit:g} s")
    print(format_table(["agents", "solved", "valid", "time s", "orders", "sum of costs", "per agent"], rows))

    fig, (ax,) = new_figure()
    ax.plot([k for k, _, _ in points], [t for _, t, _ in points], "-", color="grey")
    for ok, marker, label in ((True, "o", "solved"), (False, "x", "unsolved")):
        pts = [(k, t) for k, t, s in points if s == ok]
        if pts:
            ax.scatter(*zip(*pts, strict=True), marker=marker, label=label, zorder=3)
    ax.axhline(args.time_limit, ls="--", color="red", lw=0.8, label="time limit")
    ax.set(xlabel="agents", ylabel="planning time (s)", yscale="log", title=f"SIPP on {graph.name}")
    ax.legend()
    print(f"wrote {save_figure(fig, args.out, 'movingai')}")


if __name__ == "__main__":
    main()
