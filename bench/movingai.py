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


def run(map_path: str, scen_path: str, agents: list[int], time_limit: float, seed: int = 0, log=print) -> dict:
    """SIPP on the first k agents of the scenario for each k; every plan validated. JSON-able."""
    graph = load_movingai(map_path)
    t0 = time.perf_counter()
    plan_sipp(graph, load_scen(scen_path, graph, 1), 0.0, time_limit, seed)  # per-graph tables
    tables_s = time.perf_counter() - t0
    log(f"{graph.name}: {graph.n_nodes} cells, {graph.n_edges} edges; tables built in {tables_s:.2f} s")
    runs = []
    for k in agents:
        tasks = load_scen(scen_path, graph, k)
        result = plan_sipp(graph, tasks, 0.0, time_limit, seed)
        valid = result.ok and validate_plan(to_plan(graph, graph.name, "sipp", 0.0, tasks, result)).ok
        soc = sum(p[-1].t for p in result.paths.values()) if result.ok else None
        runs.append({"agents": k, "ok": result.ok, "valid": bool(valid), "seconds": result.planning_time_s,
                     "orders": int(result.stats.get("orders", 0)), "sum_of_costs": soc, "error": result.error})
        log(f"  {k} agents: {'solved' if result.ok else 'unsolved: ' + result.error} in {result.planning_time_s:.2f} s")
    return {"map": graph.name, "scen": Path(scen_path).name, "cells": graph.n_nodes, "time_limit_s": time_limit,
            "tables_s": tables_s, "runs": runs}


def table(results: dict) -> tuple[list[str], list[list]]:
    rows = [[r["agents"], "yes" if r["ok"] else "no", "yes" if r["valid"] else "-", f"{r['seconds']:.2f}", r["orders"],
             f"{r['sum_of_costs']:.1f}" if r["ok"] else "-", f"{r['sum_of_costs'] / r['agents']:.2f}" if r["ok"] else "-"]
            for r in results["runs"]]
    return ["agents", "solved", "valid", "time s", "orders", "sum of costs", "per agent"], rows


def figure(results: dict, out, name: str = "movingai"):
    points = [(r["agents"], r["seconds"], r["ok"]) for r in results["runs"]]
    fig, (ax,) = new_figure()
    ax.plot([k for k, _, _ in points], [t for _, t, _ in points], "-", color="grey")
    for ok, marker, label in ((True, "o", "solved"), (False, "x", "unsolved")):
        pts = [(k, t) for k, t, s in points if s == ok]
        if pts:
            ax.scatter(*zip(*pts, strict=True), marker=marker, label=label, zorder=3)
    ax.axhline(results["time_limit_s"], ls="--", color="red", lw=0.8, label="time limit")
    ax.set(xlabel="agents", ylabel="planning time (s)", yscale="log", title=f"SIPP on {results['map']}")
    ax.legend()
    return save_figure(fig, out, name)


def main(argv: list[str] | None = None) -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--map", default=str(BENCH_DIR / "random-32-32-10.map"))
    parser.add_argument("--scen", default=str(BENCH_DIR / "random-32-32-10-random-1.scen"))
    parser.add_argument("--agents", type=int, nargs="+", default=[50, 100, 150, 200, 250, 300])
    parser.add_argument("--time-limit", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    for path in (args.map, args.scen):
        if not Path(path).is_file():
            parser.error(f"{path} is missing: the MovingAI benchmark files live in ../shared/benchmarks/movingai "
                         "(or give --map and --scen)")
    results = run(args.map, args.scen, args.agents, args.time_limit, args.seed)
    print(f"\nSIPP with restarts on {results['map']}, {results['scen']}, time limit {args.time_limit:g} s")
    print(format_table(*table(results)))
    print(f"wrote {figure(results, args.out)}")


if __name__ == "__main__":
    main()
