"""Paper 000 Fig. 7 / §VII-B: prioritized SIPP vs the multi-commodity flow ILP on grid125.

20 random scenarios (services.planner.maps.tasks.random_tasks, seeds 0..19) for each of 3, 4, 5 and 6
vehicles, both planners on the uniform-time-step graph (dt = 4 s), every plan checked by the
independent validator; mean and median planning time and mean eq. 3 cost (as the validator
recomputes it) per planner, beside the paper's figures. Times are warm: the graph, its contact
windows and each planner's per-graph tables are built before the clock starts (`fleet plan` pays
them once per map per process; the cold cost is printed once).

The ILP is optimal among plans on its time grid (to its MIP gap); SIPP plans in continuous time and
may wait a fraction of a step, so on a few scenarios it can be a little cheaper. The table counts
them.

    python -m bench.fig7 [--sizes 3 4 5 6] [--trials 20] [--mu 0.5] [--time-limit 30] [--out out]
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass

from bench.tables import bench_parser, format_table, new_figure, save_figure
from services.planner.maps.loading import GraphProblem, load_graph
from services.planner.maps.tasks import random_tasks
from services.planner.registry import run_planner
from services.planner.validate import validate_plan

PLANNERS = ("sipp", "ilp")
PAPER = {"sipp": (0.106, 1.76), "ilp": (1.25, 0.155)}  # Fig. 7: mean planning time (s), mean cost


@dataclass(frozen=True)
class Run:
    ok: bool
    valid: bool
    seconds: float
    cost: float  # as the validator recomputes it (NaN when no plan)
    gap: float | None


def run(problem: GraphProblem, planner: str, mu: float, time_limit: float, seed: int) -> Run:
    plan, result = run_planner(problem, planner, mu, time_limit, seed)
    if plan is None:
        return Run(False, False, result.planning_time_s, float("nan"), None)
    report = validate_plan(plan)
    return Run(True, report.ok, result.planning_time_s, report.cost, result.mip_gap)


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[3, 4, 5, 6])
    parser.add_argument("--trials", type=int, default=20, help="random scenarios (seeds 0..trials-1) per size")
    parser.add_argument("--mu", type=float, default=0.5)
    parser.add_argument("--time-limit", type=float, default=30.0)
    args = parser.parse_args()

    graph = load_graph("grid125", uniform=True)
    warm = GraphProblem(graph, "grid125", random_tasks(graph, 2, 0))
    t0 = time.perf_counter()
    for planner in PLANNERS:
        run_planner(warm, planner, args.mu, args.time_limit, 0)
    print(f"grid125 (uniform, dt = {graph.dt:g} s): {graph.n_nodes} nodes, {graph.n_edges} edges; "
          f"per-graph tables built in {time.perf_counter() - t0:.2f} s")

    runs: dict[tuple[int, str], list[Run]] = {}
    cheaper_sipp: dict[int, int] = {}
    for n in args.sizes:
        for seed in range(args.trials):
            problem = GraphProblem(graph, "grid125", random_tasks(graph, n, seed))
            pair = {p: run(problem, p, args.mu, args.time_limit, seed) for p in PLANNERS}
            for p, r in pair.items():
                runs.setdefault((n, p), []).append(r)
            cheaper_sipp[n] = cheaper_sipp.get(n, 0) + (pair["sipp"].cost < pair["ilp"].cost * (1 - 1e-6))

    rows = []
    for n in args.sizes:
        for p in PLANNERS:
            rs = runs[(n, p)]
            solved = [r for r in rs if r.ok]
            gaps = [r.gap for r in solved if r.gap is not None]
            rows.append([
                n, p, f"{len(solved)}/{len(rs)}", sum(r.valid for r in rs),
                f"{statistics.mean(r.seconds for r in rs):.3f}", f"{statistics.median(r.seconds for r in rs):.3f}",
                f"{max(r.seconds for r in rs):.3f}",
                f"{statistics.mean(r.cost for r in solved):.3f}" if solved else "-",
                f"{max(gaps):.1e}" if gaps else "-",
                cheaper_sipp[n] if p == "ilp" else "",
            ])
    headers = ["vehicles", "planner", "solved", "valid", "mean s", "median s", "max s", "mean cost", "max gap",
               "SIPP cheaper"]
    print(f"\ngrid125, mu = {args.mu}, {args.trials} random scenarios per size, uniform graph, warm times")
    print(format_table(headers, rows))

    summary = []
    for p in PLANNERS:
        rs = [r for n in args.sizes for r in runs[(n, p)]]
        costs = [r.cost for r in rs if r.ok]
        summary.append([p, f"{statistics.mean(r.seconds for r in rs):.3f}", f"{statistics.median(r.seconds for r in rs):.3f}",
                        f"{statistics.mean(costs):.3f}", f"{PAPER[p][0]:.3f}", f"{PAPER[p][1]:.3f}"])
    print("\nall sizes, beside paper 000 Fig. 7 (the paper's cost is on its own scale)")
    print(format_table(["planner", "mean s", "median s", "mean cost", "paper mean s", "paper cost"], summary))
    for n in args.sizes:
        ilp = statistics.mean(r.cost for r in runs[(n, "ilp")] if r.ok)
        sipp = statistics.mean(r.cost for r in runs[(n, "sipp")] if r.ok)
        print(f"{n} vehicles: ILP mean cost {ilp:.4f} {'<=' if ilp <= sipp * (1 + 1e-9) else '>'} SIPP {sipp:.4f}")

    fig, (ax_t, ax_c) = new_figure(2)
    sizes = list(args.sizes)
    for i, p in enumerate(PLANNERS):
        ax_t.plot(sizes, [statistics.mean(r.seconds for r in runs[(n, p)]) for n in sizes], "o-", color=f"C{i}",
                  label=f"{p} mean")
        ax_t.plot(sizes, [statistics.median(r.seconds for r in runs[(n, p)]) for n in sizes], "o--", color=f"C{i}",
                  label=f"{p} median")
        ax_c.plot(sizes, [statistics.mean(r.cost for r in runs[(n, p)] if r.ok) for n in sizes], "s-", color=f"C{i}",
                  label=p)
    ax_t.set(xlabel="vehicles", ylabel="planning time (s)", yscale="log", title="planning time, grid125", xticks=sizes)
    ax_c.set(xlabel="vehicles", ylabel="mean eq. 3 cost", title=f"cost (mu = {args.mu})", xticks=sizes)
    ax_t.legend()
    ax_c.legend()
    print(f"wrote {save_figure(fig, args.out, 'fig7')}")


if __name__ == "__main__":
    main()
