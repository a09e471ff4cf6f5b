"""Paper 000 Fig. 6: prioritized planning lets the lowest-priority car fly over traffic (6a); the
optimal planner coordinates everyone so that none has to fly (6b).

The named scenario maps/scenarios/fig6.yaml on the 125-node fig6 map: SIPP on the base graph with
mu, the ILP on its one-time-step graph with the weight that ranks plans as mu does on the base
graph (`equivalent_mu`); both plans validated, costs recomputed on the base graph's normalisers.
Writes out/fig6.json and out/fig6.png (`--out`): a top view of each plan, driving solid, flying
dashed and thick, with the flier's takeoff and landing marked.

    python -m bench.fig6 [--mu 0.5] [--out out]
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.domain.mapfile import MAPS_DIR, load_map
from services.planner.graph.fleet_graph import FleetGraph, equivalent_mu
from services.planner.maps.loading import GraphProblem, load_graph
from services.planner.maps.tasks import load_scenario
from services.planner.registry import run_planner
from services.planner.validate import validate_plan

SCENARIO = MAPS_DIR / "scenarios" / "fig6.yaml"


def run(mu: float = 0.5, time_limit: float = 60.0, log: Callable[[str], None] = print) -> dict:
    base, step = load_graph("fig6"), load_graph("fig6", uniform=True)
    tasks = load_scenario(SCENARIO, base)
    out: dict = {"map": "fig6", "scenario": str(SCENARIO.relative_to(MAPS_DIR.parent)), "mu": mu, "planners": {}}
    for planner, graph, plan_mu in (("sipp", base, mu), ("ilp", step, equivalent_mu(mu, base.scale, step.scale))):
        plan, result = run_planner(GraphProblem(graph, "fig6", tasks), planner, plan_mu, time_limit, 0)
        if plan is None:
            raise RuntimeError(f"{planner} found no plan for {SCENARIO}: {result.error}")
        report = validate_plan(plan)
        paths = {v: [(e.node, e.t) for e in p] for v, p in plan.paths.items()}
        out["planners"][planner] = {
            "mu": plan_mu, "valid": report.ok, "seconds": result.planning_time_s,
            "cost": report.cost_on(base.scale, mu), "energy_j": report.energy, "makespan_s": report.makespan,
            "fliers": [v for v, p in paths.items() if any(graph.airborne[graph.index[n]] for n, _ in p)],
            "priority": result.priority, "paths": paths,
        }
        log(f"{planner}: valid {report.ok}, cost {out['planners'][planner]['cost']:.3f}, "
            f"fliers {out['planners'][planner]['fliers']}")
    return out


def table(results: dict) -> tuple[list[str], list[list]]:
    rows = []
    for p, r in results["planners"].items():
        lowest = r["priority"][-1] if r["priority"] else "-"
        rows.append([p, "yes" if r["valid"] else "NO", ", ".join(r["fliers"]) or "none", lowest, f"{r['cost']:.3f}",
                     f"{r['energy_j']:.1f}", f"{r['makespan_s']:.0f}", f"{r['seconds']:.3f}"])
    return ["planner", "valid", "vehicles that fly", "lowest priority", "cost", "energy J", "makespan s", "time s"], rows


def _draw(ax, graph: FleetGraph, paths: dict, title: str) -> None:
    spec = load_map("fig6")
    for zone in spec.no_fly:
        ax.fill(*np.array(zone.polygon).T, color="tab:red", alpha=0.15)
    for (u, v), k in zip(graph.edges, graph.edge_kinds, strict=True):
        if k == "drive":
            ax.plot(*graph.pos[[u, v], :2].T, color="0.85", lw=1.0, zorder=0)
    kinds = np.array(graph.kinds)
    park = kinds == "parking"
    ax.scatter(graph.pos[park, 0], graph.pos[park, 1], marker="s", s=10, c="0.6", zorder=1)
    for i, (vid, path) in enumerate(sorted(paths.items())):
        pts = np.array([graph.pos[graph.index[n]] for n, _ in path])
        air = np.array([graph.airborne[graph.index[n]] for n, _ in path])
        colour = f"C{i}"
        for a in range(len(pts) - 1):
            up = air[a] or air[a + 1]
            ax.plot(*pts[a:a + 2, :2].T, color=colour, lw=3.0 if up else 1.6, ls="--" if up else "-", zorder=2)
        ax.scatter(*pts[0, :2], marker="o", s=40, color=colour, edgecolors="k", zorder=3)
        ax.scatter(*pts[-1, :2], marker="*", s=90, color=colour, edgecolors="k", zorder=3, label=vid)
        if air.any():
            first, last = np.flatnonzero(air)[[0, -1]]
            ax.annotate("takeoff", pts[first, :2], xytext=(4, 6), textcoords="offset points", fontsize=7, color=colour)
            ax.annotate("landing", pts[last, :2], xytext=(4, -10), textcoords="offset points", fontsize=7, color=colour)
    ax.set_title(title, fontsize=9)
    ax.set_aspect("equal")
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))


def figure(results: dict, out: str | Path, name: str = "fig6") -> Path:
    base = load_graph("fig6")
    fig, axes = new_figure(2, width=5.2, height=4.4)
    for ax, (p, label) in zip(axes, (("sipp", "(a) prioritized SIPP"), ("ilp", "(b) ILP")), strict=True):
        r = results["planners"][p]
        graph = base if p == "sipp" else load_graph("fig6", uniform=True)
        flying = ", ".join(r["fliers"]) or "nobody"
        _draw(ax, graph, r["paths"], f"{label}: {flying} flies; cost {r['cost']:.2f}")
    return save_figure(fig, out, name)


def main(argv: list[str] | None = None) -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--mu", type=float, default=0.5)
    parser.add_argument("--time-limit", type=float, default=60.0)
    args = parser.parse_args(argv)
    results = run(args.mu, args.time_limit)
    print(format_table(*table(results)))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fig6.json").write_text(json.dumps(results, indent=1))
    print(f"wrote {out / 'fig6.json'} and {figure(results, out)}")


if __name__ == "__main__":
    main()
