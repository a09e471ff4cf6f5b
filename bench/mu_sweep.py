"""Paper 000 eq. 3: how mu trades time for energy, on the town with its 8-vehicle mission.

For mu = 0, 0.1, ..., 1: the total energy (J, eq. 1-2 plus waits) and the makespan (s) of the plan,
as the independent validator recomputes them, for prioritized SIPP on the base graph, SIPP on the
uniform-time-step graph and the ILP on the uniform-time-step graph (each ILP run within its own time
limit: when HiGHS does not close the gap in time, the plan is its best incumbent and the table gives
the gap). On the one-time-step graph eq. 3's normalisers differ from the base graph's, so planners
there get `equivalent_mu(mu)`: every row of one mu minimises the same cost (the base graph's). mu = 0 minimises time only, mu = 1 energy only: vehicles then drive and wait on the ground
where they can and fly only where they must (over the gap between the two road regions).

    python -m bench.mu_sweep [--scenario maps/scenarios/town_8.yaml] [--ilp-time-limit 10] [--no-ilp] [--out out]
"""

from __future__ import annotations

import numpy as np

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.domain.mapfile import MAPS_DIR
from services.planner.graph.fleet_graph import equivalent_mu
from services.planner.maps.loading import GraphProblem, load_graph
from services.planner.maps.tasks import load_scenario
from services.planner.registry import run_planner
from services.planner.validate import validate_plan


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--scenario", default=str(MAPS_DIR / "scenarios" / "town_8.yaml"))
    parser.add_argument("--sipp-time-limit", type=float, default=30.0)
    parser.add_argument("--ilp-time-limit", type=float, default=10.0)
    parser.add_argument("--no-ilp", action="store_true", help="SIPP only")
    args = parser.parse_args()

    variants = [("sipp", False), ("sipp", True)] + ([] if args.no_ilp else [("ilp", True)])
    problems = {}
    for uniform in (False, True):
        graph = load_graph("town", uniform=uniform)
        problems[uniform] = GraphProblem(graph, "town", load_scenario(args.scenario, graph))
    mus = [round(m, 1) for m in np.linspace(0.0, 1.0, 11)]
    results: dict[str, list[tuple[float, float] | None]] = {}
    rows = []
    for planner, uniform in variants:
        label = f"{planner} ({'uniform' if uniform else 'base'})"
        limit = args.ilp_time_limit if planner == "ilp" else args.sipp_time_limit
        results[label] = []
        for mu in mus:
            plan_mu = equivalent_mu(mu, problems[False].graph.scale, problems[uniform].graph.scale) if uniform else mu
            plan, result = run_planner(problems[uniform], planner, plan_mu, limit, 0)
            if plan is None:
                results[label].append(None)
                rows.append([label, mu, "failed", "", "", "", "", result.error[:60]])
                continue
            report = validate_plan(plan)
            results[label].append((report.energy, report.makespan))
            gap = f"{result.mip_gap:.1e}" if result.mip_gap is not None else ""
            rows.append([label, f"{mu:.1f}", "yes" if report.ok else "NO", f"{report.energy:.1f}",
                         f"{report.makespan:.1f}", f"{report.cost:.3f}", f"{result.planning_time_s:.2f}", gap])
    n = len(problems[True].tasks)
    print(f"town, {n} vehicles ({args.scenario}), energy and makespan as the validator recomputes them")
    print(format_table(["planner", "mu", "valid", "energy J", "makespan s", "cost", "time s", "gap"], rows))

    fig, (ax_e, ax_m) = new_figure(2)
    for i, (label, series) in enumerate(results.items()):
        energy = [s[0] if s else np.nan for s in series]
        makespan = [s[1] if s else np.nan for s in series]
        ax_e.plot(mus, energy, "o-", color=f"C{i}", label=label)
        ax_m.plot(mus, makespan, "s-", color=f"C{i}", label=label)
    ax_e.set(xlabel="mu (eq. 3 energy weight)", ylabel="total energy (J)", title=f"energy, town, {n} vehicles")
    ax_m.set(xlabel="mu (eq. 3 energy weight)", ylabel="makespan (s)", title="makespan")
    ax_e.legend()
    ax_m.legend()
    print(f"wrote {save_figure(fig, args.out, 'mu_sweep')}")


if __name__ == "__main__":
    main()
