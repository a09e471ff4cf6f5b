"""Replanning time after one fault (issue 16): N vehicles on city934 with random tasks (as the soak
draws them) are planned with SIPP (or the ILP); then, at several instants of the plan, one airborne
vehicle leaves (it comes straight down and rests: the sweeps the mission client gives the planner,
`services/mission/sweeps.py`) and the planner plans the others on from 1 s later (`Replan` with
stranding, as missions ask: services/planner/sipp/replan.py, ilp/replan.py). Printed: how long
each replan took (the whole request: graph, replan, validation of the spliced plan), how many
vehicles it replanned, whether it found a plan, which planner made it and how many vehicles it
stopped short of their goals; `replan.png` plots the times.

    python -m bench.replan --vehicles 16 80 --faults 10 [--planner ilp]
"""

from __future__ import annotations

import random
import statistics
import time

from bench.soak import MAP, draw_tasks
from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.bus.messages import PlanRequest, Replan
from common.domain.planfile import Plan
from services.mission.runner import plan_end
from services.mission.sweeps import left_vehicle
from services.planner.maps.loading import load_graph
from services.planner.registry import solve


def faults(plan: Plan, n: int, rng: random.Random) -> list[tuple[str, float]]:
    """`n` (vehicle, time) pairs at which the vehicle is airborne."""
    nodes = plan.graph.nodes
    out = []
    air = {vid: [e.t for e in path if nodes[e.node].kind == "air"] for vid, path in plan.paths.items()}
    flyers = sorted(v for v, ts in air.items() if ts)
    for _ in range(n):
        vid = rng.choice(flyers)
        out.append((vid, rng.uniform(air[vid][0], air[vid][-1])))
    return out


def run(vehicles: int, n_faults: int, seed: int, planner: str) -> list[dict]:
    graph = load_graph(MAP)
    rng = random.Random(seed)
    starts = {f"cf{i + 1:02d}": s for i, s in enumerate(rng.sample(sorted(graph.endpoints()), vehicles))}
    reply = solve(PlanRequest(map=MAP, tasks=draw_tasks(graph, starts, rng), planner=planner, time_limit=60))
    assert reply.ok and reply.plan is not None, reply.error
    base = reply.plan
    rows = []
    for vid, t in faults(base, n_faults, rng):
        here = base.position(vid, t)
        sweeps = left_vehicle(vid, "emergency_landing", here, t, 0.0, None, plan_end(base))  # as the mission gives them
        at = t + 1.0
        moving = sum(1 for v, p in base.paths.items() if v != vid and p[-1].t > at)
        started = time.perf_counter()
        answer = solve(PlanRequest(map=MAP, tasks={}, time_limit=1.0, planner=planner,
                                   replan=Replan(base=base, at=at, left=[vid], sweeps=sweeps, strand=True)))
        took = time.perf_counter() - started
        short = 0 if answer.plan is None else sum(t.goal != base.tasks[v].goal for v, t in answer.plan.tasks.items())
        rows.append({"vehicles": vehicles, "fault": vid, "t": t, "replanned": moving, "ok": answer.ok,
                     "seconds": took, "error": answer.error, "short": short, "by": answer.planner})
    return rows


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--vehicles", type=int, nargs="+", default=[16, 80])
    parser.add_argument("--faults", type=int, default=10, help="faults per fleet size")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--planner", choices=["sipp", "ilp"], default="sipp",
                        help="plans the mission and plans it on (ilp: SIPP takes over when it finds no plan in time)")
    args = parser.parse_args()
    results = {n: run(n, args.faults, args.seed, args.planner) for n in args.vehicles}
    table = []
    for n, rows in results.items():
        ms = sorted(1e3 * r["seconds"] for r in rows)
        table.append([n, args.planner, len(rows), sum(r["ok"] for r in rows),
                      sum(r["by"] == args.planner for r in rows), sum(r["short"] for r in rows),
                      f"{statistics.mean(r['replanned'] for r in rows):.0f}", f"{statistics.median(ms):.0f}",
                      f"{ms[-1]:.0f}"])
    print(format_table(["vehicles", "planner", "faults", "replanned ok", f"by {args.planner}", "stopped short",
                        "moving vehicles replanned (mean)", "replan ms median", "max"], table))
    for rows in results.values():
        for r in rows:
            if not r["ok"]:
                print(f"  {r['vehicles']} vehicles, {r['fault']} at {r['t']:.1f} s: {r['error']}")
    fig, (ax,) = new_figure()
    ax.boxplot([[1e3 * r["seconds"] for r in rows] for rows in results.values()], tick_labels=[str(n) for n in results])
    ax.set(xlabel="vehicles", ylabel="ms", title=f"replanning after one fault ({MAP})")
    print(f"saved {save_figure(fig, args.out, 'replan')}")


if __name__ == "__main__":
    main()
