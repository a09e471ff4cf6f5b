"""PAD vs full-dimensional ARA* on the two generated office maps (paper 002 §V-D, Tables I-II):
seeded start/goal pairs, success within a time limit, planning time, expansions, path cost and
final epsilon; one table per map with the paper's figures beside ours, and a PNG.

The drone's primitives are the paper's (`--slc paper`, the default): metric motions only in corner
groups (METRICSTEP 0.5 m -> METRICTURN +-90 -> METRICSTEP 1.0 m) and WALLFOLLOWING's OBSTACLE
trigger; PAD tracks with eps_track 2.0, under which it needs more than one iteration on a good share
of the problems, as in the paper. `--paper-limits` is the paper's 3 min to the first solution plus
up to 5 s to improve (a long run: failures cost 3 min each); the default is 10 s + 1 s.

    .venv/bin/python -m bench.collab_experiment [--instances 50] [--time-limit 10] [--improve 1] [--paper-limits]
                                                [--slc paper|free] [--eps-track 2.0]
                                                [--out out/collab_experiment.png] [--json out/collab_experiment.json]
"""

from __future__ import annotations

import argparse
import json
import statistics as st
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from common.team.maps import load_env
from common.team.problem import TeamProblem
from services.planner.collab.instances import sample_problem
from services.planner.collab.lattice import SlcOptions
from services.planner.collab.pad import PadConfig
from services.planner.collab.planner import Method, TeamPlanner, TeamPlanOutcome

MAPS = ("office-conference", "office-cubicles")
METHODS: tuple[Method, ...] = ("pad", "arastar")
LABELS = {"pad": "PAD MR SLC", "arastar": "Full-D ARA* MR SLC"}
PAPER_LIMITS = (180.0, 5.0)  # 002 §V-D: 3 minutes to the first solution, then up to 5 s to improve
EPS_TRACK = 2.0
# 002 Tables I and II: time avg, std, min, max; iterations; expansions; cost; final eps; success %.
PAPER = {
    "office-conference": {
        "pad": (20.05, 22.00, 1.19, 91.58, 1.59, 7348, 24401, 1.36, 100),
        "arastar": (9.37, 20.32, 0.08, 128.04, None, 1385, 23960, 1.30, 82),
    },
    "office-cubicles": {
        "pad": (12.74, 9.95, 1.19, 40.00, 1.26, 2736, 36112, 1.31, 100),
        "arastar": (12.33, 22.23, 0.01, 88.65, None, 960, 38083, 1.38, 38),
    },
}


@dataclass
class Run:
    map: str
    seed: int
    method: str
    solved: bool
    first_solution_s: float | None
    planning_time_s: float
    expansions: int
    iterations: int
    cost: float
    eps: float


def run_map(name: str, instances: int, time_limit: float, improve_s: float, log=sys.stderr,
            options: SlcOptions | None = None, eps_track: float = EPS_TRACK) -> tuple[list[Run], dict]:
    """Both planners on `instances` seeded problems of map `name`; also one example PAD plan."""
    t0 = time.perf_counter()
    planner = TeamPlanner(load_env(name), options=SlcOptions.paper() if options is None else options)
    pad_config = PadConfig(eps_track=eps_track)
    problems: list[TeamProblem] = [sample_problem(planner, seed) for seed in range(instances)]
    print(f"[{name}] graph and {instances} problems ready in {time.perf_counter() - t0:.1f} s", file=log, flush=True)
    runs, example = [], {}
    for seed, problem in enumerate(problems):
        for method in METHODS:
            out: TeamPlanOutcome = planner.plan(problem, method, time_limit, improve_s, pad_config=pad_config)
            solved = out.first_solution_s is not None and out.first_solution_s <= time_limit
            runs.append(Run(name, seed, method, solved, out.first_solution_s, out.planning_time_s, out.expansions,
                            out.iterations, out.cost, out.eps))
            if method == "pad" and solved and _variety(out.plan) > _variety(example.get("plan")):
                example = {"planner": planner, "plan": out.plan}
        tail = " ".join(f"{r.method}={f'{r.planning_time_s:.2f}s' if r.solved else 'FAIL'}" for r in runs[-2:])
        print(f"[{name}] seed {seed:2d}: {tail}", file=log, flush=True)
    return runs, example


def _variety(plan) -> tuple[int, int]:
    """Example plans for the figure: most kinds of controllers, then fewest steps."""
    if plan is None:
        return (-1, 0)
    return (len({type(s.action) for s in plan.drone}), -len(plan.drone) - len(plan.ugv))


def _mean(xs: list[float]) -> float:
    return st.mean(xs) if xs else float("nan")


def summarize(runs: list[Run]) -> dict[str, tuple]:
    """Per method: the paper's columns. Time, iterations, expansions, cost and eps are averaged over
    the problems both planners solved (as in 002 §V-D); success over all problems."""
    solved = [{r.seed for r in runs if r.method == m and r.solved} for m in METHODS]
    both = set.intersection(*solved)
    out = {}
    for method in METHODS:
        mine = [r for r in runs if r.method == method]
        common = [r for r in mine if r.seed in both]
        times = [r.planning_time_s for r in common]
        out[method] = (
            _mean(times), st.pstdev(times) if times else float("nan"),
            min(times, default=float("nan")), max(times, default=float("nan")),
            _mean([r.iterations for r in common]) if method == "pad" else None,
            _mean([r.expansions for r in common]), _mean([r.cost for r in common]), _mean([r.eps for r in common]),
            100.0 * sum(r.solved for r in mine) / len(mine),
        )
    return out


def format_table(name: str, summary: dict[str, tuple], time_limit: float, improve_s: float, instances: int) -> str:
    head = (f"{'':22s}{'Planning Time (s)':^31s}  {'Iter.':>5s} {'Expans.':>8s} {'Cost':>8s} {'Eps':>5s}  "
            f"{'Success %':>9s}")
    sub = f"{'Algorithm':22s}{'Avg':>7s} {'Std':>7s} {'Min':>7s} {'Max':>7s}  {'Avg':>5s} {'Avg':>8s} {'Avg':>8s} {'Avg':>5s}  "
    lines = [f"{name}: {instances} problems, limit {time_limit:g} s to the first solution + up to {improve_s:g} s to "
             f"improve; averages over problems both solved", head, sub + f"{f'@{time_limit:g}s':>9s}"]

    def row(label: str, v: tuple, limit: str) -> str:
        it = "n/a" if v[4] is None else f"{v[4]:.2f}"
        return (f"{label:22s}{v[0]:7.2f} {v[1]:7.2f} {v[2]:7.2f} {v[3]:7.2f}  {it:>5s} {v[5]:8.0f} {v[6]:8.1f} "
                f"{v[7]:5.2f}  {v[8]:6.0f}{limit}")

    for method in METHODS:
        lines.append(row(LABELS[method], summary[method], ""))
    for method in METHODS:
        lines.append(row("  paper " + LABELS[method][:14], PAPER[name][method], " @3min"))
    return "\n".join(lines)


def format_limits(name: str, runs: list[Run], time_limit: float) -> str:
    """Success within shorter limits, from the same runs' first-solution times."""
    limits = [t for t in (0.5, 1.0, 2.0, 3.0, 5.0) if t < time_limit] + [time_limit]
    cells = []
    for method in METHODS:
        mine = [r for r in runs if r.method == method]
        pct = [100.0 * sum(r.solved and r.first_solution_s <= t for r in mine) / len(mine) for t in limits]
        cells.append(f"{LABELS[method]}: " + " ".join(f"{p:.0f}%" for p in pct))
    return f"{name}: success within {', '.join(f'{t:g}' for t in limits)} s -- " + "; ".join(cells)


def plot(path: Path, results: dict[str, tuple[list[Run], dict]], time_limit: float) -> None:
    """Per map: the map with an example PAD team plan, and each problem's planning time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from services.planner.collab.draw import draw_map, draw_plan

    fig, axes = plt.subplots(2, len(results), figsize=(7 * len(results), 9), squeeze=False)
    for j, (name, (runs, example)) in enumerate(results.items()):
        ax = axes[0][j]
        if example:
            draw_map(ax, example["planner"].env)
            draw_plan(ax, example["plan"])
        ax.set_title(f"{name}: example PAD team plan")
        ax = axes[1][j]
        fail_y = 2.0 * time_limit
        for method, marker, color in zip(METHODS, ("o", "x"), ("tab:blue", "tab:orange"), strict=True):
            mine = [r for r in runs if r.method == method]
            ok = [r for r in mine if r.solved]
            bad = [r for r in mine if not r.solved]
            label = f"{LABELS[method]} ({100 * len(ok) / len(mine):.0f}% solved)"
            ax.scatter([r.seed for r in ok], [r.planning_time_s for r in ok], marker=marker, color=color, label=label)
            if bad:
                ax.scatter([r.seed for r in bad], [fail_y] * len(bad), marker="v", color=color, edgecolor="red", s=60)
        ax.axhline(time_limit, color="grey", linestyle="--", linewidth=0.8)
        ax.text(0, fail_y * 1.15, f"not solved within {time_limit:g} s", color="red", fontsize=8)
        ax.set_yscale("log")
        ax.set_ylim(top=fail_y * 1.6)
        ax.set_xlabel("problem (seed)")
        ax.set_ylabel("planning time: first solution + improvement (s)")
        ax.legend(loc="lower right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(instances: int, time_limit: float, improve_s: float, png: Path, json_path: Path | None, maps=MAPS,
        options: SlcOptions | None = None, eps_track: float = EPS_TRACK) -> str:
    """The whole experiment; returns the printed tables."""
    results = {name: run_map(name, instances, time_limit, improve_s, options=options, eps_track=eps_track)
               for name in maps}
    tables = [
        format_table(n, summarize(r), time_limit, improve_s, instances) + "\n" + format_limits(n, r, time_limit)
        for n, (r, _) in results.items()
    ]
    plot(png, results, time_limit)
    if json_path:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps([asdict(r) for runs, _ in results.values() for r in runs], indent=1))
    return "\n\n".join(tables)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench.collab_experiment", description=__doc__.splitlines()[0])
    parser.add_argument("--instances", type=int, default=50)
    parser.add_argument("--time-limit", type=float, default=10.0)
    parser.add_argument("--improve", type=float, default=1.0)
    parser.add_argument("--out", default="out/collab_experiment.png")
    parser.add_argument("--json", default="out/collab_experiment.json", help="per-run results ('' for none)")
    parser.add_argument("--paper-limits", action="store_true",
                        help=f"the paper's limits: {PAPER_LIMITS[0]:g} s to the first solution + {PAPER_LIMITS[1]:g} s "
                        "to improve (overrides --time-limit and --improve)")
    parser.add_argument("--slc", choices=["paper", "free"], default="paper",
                        help="drone primitives: the paper's (corner groups, OBSTACLE trigger) or free metric steps")
    parser.add_argument("--eps-track", type=float, default=EPS_TRACK, help="PAD's tracking bound eps_track")
    parser.add_argument("--dry-run", action="store_true", help="print the settings as JSON and exit")
    args = parser.parse_args(argv)
    if args.paper_limits:
        args.time_limit, args.improve = PAPER_LIMITS
    if args.instances < 1 or args.time_limit <= 0 or args.improve < 0 or args.eps_track < 1:
        parser.error("--instances, --time-limit must be positive, --improve not negative, --eps-track at least 1")
    options = SlcOptions.paper() if args.slc == "paper" else SlcOptions()
    if args.dry_run:
        print(json.dumps({"instances": args.instances, "time_limit": args.time_limit, "improve": args.improve,
                          "slc": asdict(options), "eps_track": args.eps_track}))
        return 0
    print(run(args.instances, args.time_limit, args.improve, Path(args.out), Path(args.json) if args.json else None,
              options=options, eps_track=args.eps_track))
    print(f"\nfigure: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
