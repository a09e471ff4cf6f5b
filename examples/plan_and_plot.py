"""Plan a scenario on a map with the fleet's planner and draw the plan: the map's roads and air
grid, each vehicle's path from above, and its height over time. Nothing moves.

    python examples/plan_and_plot.py [--scenario maps/scenarios/town_8.yaml] [--planner sipp|ilp] [--out plan.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import yaml  # noqa: E402

from services.api import Fleet, Task  # noqa: E402

EDGE_STYLE = {"drive": ("0.6", 1.0), "takeoff": ("tab:green", 0.5), "fly": ("tab:blue", 0.3), "land": ("tab:orange", 0.5)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="maps/scenarios/town_8.yaml")
    parser.add_argument("--planner", default="sipp", choices=["sipp", "ilp"])
    parser.add_argument("--out", default="out/examples/plan.png")
    args = parser.parse_args()
    scenario = yaml.safe_load(Path(args.scenario).read_text())
    tasks = {vid: Task(**task) for vid, task in scenario["tasks"].items()}

    with Fleet.open(only=["planner"]) as fleet:  # planning needs only the planner
        plan = fleet.plan(scenario["map"], tasks, planner=args.planner)
    print(f"{plan.planner} on {plan.map}: {len(plan.paths)} vehicles, cost {plan.cost:.2f}, "
          f"makespan {max(p[-1].t for p in plan.paths.values()):.1f} s, planned in {plan.planning_time_s:.2f} s")

    nodes = plan.graph.nodes
    fig, (top, side) = plt.subplots(1, 2, figsize=(14, 5), gridspec_kw={"width_ratios": [2, 1]})
    for u, v, kind in plan.graph.edges:
        colour, width = EDGE_STYLE[kind]
        top.plot([nodes[u].pos[0], nodes[v].pos[0]], [nodes[u].pos[1], nodes[v].pos[1]], color=colour, lw=width, zorder=1)
    for vid, path in plan.paths.items():
        xs, ys, zs = zip(*(nodes[e.node].pos for e in path), strict=True)
        line, = top.plot(xs, ys, lw=2, label=vid, zorder=2)
        top.scatter([xs[0]], [ys[0]], color=line.get_color(), marker="o", zorder=3)
        top.scatter([xs[-1]], [ys[-1]], color=line.get_color(), marker="*", s=120, zorder=3)
        side.plot([e.t for e in path], zs, color=line.get_color(), label=vid)
    top.set(aspect="equal", title=f"{plan.map}: paths from above (o start, * goal)", xlabel="x (m)", ylabel="y (m)")
    side.set(title="height over time", xlabel="t (s)", ylabel="z (m)")
    top.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
