"""Paper 000 Fig. 7 / §VII-B: prioritized SIPP vs the multi-commodity flow ILP on the 125-node map.

The paper's protocol: 20 random scenarios for each of 3, 4, 5 and 6 vehicles on the 125-node map of
Fig. 6 (here `fig6`, scenarios `random_tasks` seeds 0..19), both planners, mean planning time and
mean cost. As each planner is used in practice: SIPP on the map's base graph (125 nodes), the ILP on
its one-time-step graph (§V-E; on fig6 every edge keeps its kind's speed). Eq. 3 normalises by the
graph's largest edge energy and duration, which differ between the two graphs, so
- the ILP is given the weight `equivalent_mu(mu)` that ranks plans on its graph as mu ranks them on
  the base graph (both minimise the same cost), and
- both plans go through the independent validator, which recomputes their costs on one definition:
  eq. 3 with the base graph's W_max and t_max and mu (`ValidationReport.cost_on`).
The mean cost is over the scenarios both planners solved (the table counts the others). Times are
warm: the graphs, contact windows and per-graph tables are built before the clock starts (the cold
cost is printed once). Results: out/fig7.json and out/fig7.png (`--out`).

The ILP is optimal among plans on its 2 s time grid (to its MIP gap); SIPP plans in continuous time
and may wait a fraction of a step, so it can be a little cheaper on some scenarios: the table counts
them.

    python -m bench.fig7 [--sizes 3 4 5 6] [--trials 20] [--mu 0.5] [--time-limit 30] [--out out]
"""

from __future__ import annotations

import json
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from bench.tables import bench_parser, format_table, new_figure, save_figure
from services.planner.graph.fleet_graph import FleetGraph, equivalent_mu
from services.planner.maps.loading import GraphProblem, load_graph
from services.planner.maps.tasks import random_tasks
from services.planner.registry import run_planner
from services.planner.validate import validate_plan

MAP = "fig6"
PLANNERS = ("sipp", "ilp")
PAPER = {"sipp": (0.106, 1.76), "ilp": (1.25, 0.155)}  # Fig. 7: mean planning time (s), mean cost


@dataclass(frozen=True)
class Run:
    vehicles: int
    seed: int
    planner: str
    ok: bool
    valid: bool
    seconds: float
    cost: float  # eq. 3 on the base graph's normalisers, recomputed by the validator (NaN: no plan)
    own_cost: float  # eq. 3 as the plan file defines it (its graph's normalisers, its mu)
    energy_j: float
    makespan_s: float
    fliers: int  # vehicles whose path leaves the ground
    gap: float | None
    error: str = ""


def _fliers(graph: FleetGraph, paths: dict) -> int:
    return sum(any(graph.airborne[graph.index[e.node]] for e in path) for path in paths.values())


def run_one(problem: GraphProblem, base: FleetGraph, planner: str, mu: float, plan_mu: float, time_limit: float,
            seed: int, n: int) -> Run:
    plan, result = run_planner(problem, planner, plan_mu, time_limit, seed)
    if plan is None:
        nan = math.nan
        return Run(n, seed, planner, False, False, result.planning_time_s, nan, nan, nan, nan, 0, None, result.error)
    report = validate_plan(plan)
    return Run(n, seed, planner, True, report.ok, result.planning_time_s, report.cost_on(base.scale, mu), report.cost,
               report.energy, report.makespan, _fliers(problem.graph, plan.paths), result.mip_gap)


def run(sizes: list[int], trials: int, mu: float, time_limit: float, log: Callable[[str], None] = print) -> dict:
    """Every (size, seed, planner) run and the summary, as a JSON-able dict."""
    base, step = load_graph(MAP), load_graph(MAP, uniform=True)
    plan_mu = {"sipp": mu, "ilp": equivalent_mu(mu, base.scale, step.scale)}
    graphs = {"sipp": base, "ilp": step}
    t0 = time.perf_counter()
    for p in PLANNERS:
        run_planner(GraphProblem(graphs[p], MAP, random_tasks(base, 2, 0)), p, plan_mu[p], time_limit, 0)
    log(f"{MAP}: base graph {base.n_nodes} nodes / {base.n_edges} edges (SIPP), one-time-step graph "
        f"{step.n_nodes} nodes / {step.n_edges} edges, dt = {step.dt:g} s (ILP, largest slow-down "
        f"{step.slowdown().max():.0%}); per-graph tables built in {time.perf_counter() - t0:.2f} s")
    log(f"mu = {mu} on the base graph; the ILP plans with mu' = {plan_mu['ilp']:.4f} on its graph (same ranking)")
    runs: list[Run] = []
    for n in sizes:
        for seed in range(trials):
            tasks = random_tasks(base, n, seed)
            for p in PLANNERS:
                runs.append(run_one(GraphProblem(graphs[p], MAP, tasks), base, p, mu, plan_mu[p], time_limit, seed, n))
        log(f"  {n} vehicles: {trials} scenarios done")
    return {
        "map": MAP, "mu": mu, "ilp_mu": plan_mu["ilp"], "time_limit_s": time_limit, "sizes": sizes, "trials": trials,
        "base_nodes": base.n_nodes, "step_nodes": step.n_nodes, "dt": step.dt,
        "scale": {"w_max": base.scale.w_max, "t_max": base.scale.t_max},
        "runs": [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in asdict(r).items()} for r in runs],
        "summary": summarise(runs, sizes), "paper": PAPER,
    }


def _both(runs: list[Run]) -> list[tuple[Run, Run]]:
    """(sipp, ilp) pairs of the scenarios both planners solved with valid plans."""
    by = {(r.vehicles, r.seed, r.planner): r for r in runs}
    pairs = [(by[(r.vehicles, r.seed, "sipp")], r) for r in runs if r.planner == "ilp"]
    return [(s, i) for s, i in pairs if s.ok and s.valid and i.ok and i.valid]


def _summary_row(sel: list[Run]) -> dict:
    both = _both(sel)
    row: dict = {
        "scenarios": len(sel) // len(PLANNERS), "both_solved": len(both),
        "sipp_cheaper": sum(s.cost < i.cost * (1 - 1e-6) for s, i in both),
        "ilp_cheaper": sum(i.cost < s.cost * (1 - 1e-6) for s, i in both),
    }
    for k, p in enumerate(PLANNERS):
        mine = [r for r in sel if r.planner == p]
        row[p] = {
            "solved": sum(r.ok for r in mine), "valid": sum(r.valid for r in mine),
            "mean_s": statistics.mean(r.seconds for r in mine), "median_s": statistics.median(r.seconds for r in mine),
            "max_s": max(r.seconds for r in mine),
            "mean_cost": statistics.mean(pair[k].cost for pair in both) if both else None,
            "mean_fliers": statistics.mean(pair[k].fliers for pair in both) if both else None,
            "max_gap": max((r.gap for r in mine if r.gap is not None), default=None),
        }
    return row


def summarise(runs: list[Run], sizes: list[int]) -> dict:
    """Per size and over all sizes: solved, valid, times, and the mean cost over the scenarios both
    planners solved."""
    return {"by_size": {str(n): _summary_row([r for r in runs if r.vehicles == n]) for n in sizes},
            "all": _summary_row(runs)}


def _fmt(x: float | None, spec: str = ".3f") -> str:
    return "-" if x is None else format(x, spec)


def tables(results: dict) -> tuple[list[str], list[list], list[str], list[list]]:
    """(headers, rows) per size and planner, and the summary beside the paper."""
    by = results["summary"]["by_size"]
    headers = ["vehicles", "planner", "solved", "valid", "mean s", "median s", "max s",
               "mean cost (both solved)", "fliers/scenario", "cheaper on"]
    rows = []
    for n in results["sizes"]:
        row = by[str(n)]
        for p in PLANNERS:
            s = row[p]
            rows.append([n, p, f"{s['solved']}/{row['scenarios']}", s["valid"], f"{s['mean_s']:.3f}",
                         f"{s['median_s']:.3f}", f"{s['max_s']:.3f}", _fmt(s["mean_cost"]),
                         _fmt(s["mean_fliers"], ".2f"), row[f"{p}_cheaper"]])
    all_ = results["summary"]["all"]
    summary = [[p, f"{all_[p]['mean_s']:.3f}", f"{all_[p]['median_s']:.3f}", _fmt(all_[p]["mean_cost"]),
                f"{PAPER[p][0]:.3f}", f"{PAPER[p][1]:.3f}"] for p in PLANNERS]
    return headers, rows, ["planner", "mean s", "median s", "mean cost", "paper mean s", "paper mean cost"], summary


def figure(results: dict, out: str | Path, name: str = "fig7") -> Path:
    by, sizes = results["summary"]["by_size"], results["sizes"]
    fig, (ax_t, ax_c) = new_figure(2)
    for i, p in enumerate(PLANNERS):
        ax_t.plot(sizes, [by[str(n)][p]["mean_s"] for n in sizes], "o-", color=f"C{i}", label=f"{p} mean")
        ax_t.plot(sizes, [by[str(n)][p]["median_s"] for n in sizes], "o--", color=f"C{i}", label=f"{p} median")
        ax_t.axhline(PAPER[p][0], color=f"C{i}", lw=0.8, ls=":", label=f"{p} paper mean")
        costs = [by[str(n)][p]["mean_cost"] for n in sizes]
        ax_c.plot(sizes, [math.nan if c is None else c for c in costs], "s-", color=f"C{i}", label=p)
    ax_t.set(xlabel="vehicles", ylabel="planning time (s)", yscale="log", xticks=sizes,
             title=f"planning time, {results['map']} ({results['base_nodes']} nodes)")
    ax_c.set(xlabel="vehicles", ylabel="mean eq. 3 cost (base graph's W_max, t_max)", xticks=sizes,
             title=f"cost over scenarios both solved (mu = {results['mu']})")
    ax_t.legend(fontsize=7)
    ax_c.legend(fontsize=7)
    return save_figure(fig, out, name)


def main(argv: list[str] | None = None) -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[3, 4, 5, 6])
    parser.add_argument("--trials", type=int, default=20, help="random scenarios (seeds 0..trials-1) per size")
    parser.add_argument("--mu", type=float, default=0.5)
    parser.add_argument("--time-limit", type=float, default=30.0)
    args = parser.parse_args(argv)
    if args.trials < 1 or not args.sizes or min(args.sizes) < 1:
        parser.error("--trials and --sizes must be positive")

    results = run(args.sizes, args.trials, args.mu, args.time_limit)
    headers, rows, sum_headers, summary = tables(results)
    print(f"\n{results['map']}, mu = {args.mu}, {args.trials} random scenarios per size; SIPP on the base graph, "
          "the ILP on its one-time-step graph; costs recomputed by the validator on the base graph's normalisers")
    print(format_table(headers, rows))
    print("\nall sizes, beside paper 000 Fig. 7 (the paper's cost is on its own scale)")
    print(format_table(sum_headers, summary))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fig7.json").write_text(json.dumps(results, indent=1))
    print(f"wrote {out / 'fig7.json'} and {figure(results, out)}")


if __name__ == "__main__":
    main()
