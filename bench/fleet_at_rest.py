"""What the fleet costs while nothing moves (issue 15): the soak's deployment (`bench.soak`: a
router, the planner, two executors, the gateways five radios to a process, the simulator, the
motion-capture bridge) with `--vehicles` parked on city934 and no mission, each process's CPU from
/proc over `--seconds` after `--warmup`, and within each process its threads' CPU grouped: the
event loop (the process's main thread), its other Python threads (a gateway's: cflib's per link and
the radios' senders), zenoh's (by name). On 2026-12-07 (80 vehicles, fortieth session) this was
0.90-1.06 of the two cores before any vehicle moved (two runs an hour apart): the floor under
every mission's figures.

    python -m bench.fleet_at_rest [--vehicles 80] [--warmup 30] [--seconds 30]
"""

from __future__ import annotations

import json
import os
import random
import re
import time
from collections import defaultdict
from pathlib import Path

from bench.machine_cpu import task_cpu_seconds
from bench.soak import MAP, draw_tasks, proc_sample, soak_fleet
from bench.tables import bench_parser, format_table, new_figure, save_figure
from services.planner.maps.loading import load_graph

ZENOH_THREAD = re.compile(r"^(rx|tx|net|app|acc|keepalive)-\d+$")
"""zenoh's runtime threads (Linux thread names)."""


def thread_cpu(pid: int) -> dict[str, float]:
    """CPU seconds so far of each thread group of `pid`: "event loop" (its main thread), "zenoh",
    "other Python threads" (unnamed: they carry the process's name); empty if it is gone."""
    groups: dict[str, float] = defaultdict(float)
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return {}
    for tid in tids:
        try:
            stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1:stat.rindex(")")]
        group = "event loop" if tid == str(pid) else "zenoh" if ZENOH_THREAD.match(name) else "other Python threads"
        groups[group] += task_cpu_seconds(stat)
    return dict(groups)


def measure(vehicles: int, warmup: float, seconds: float, run_dir: Path) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """Each process's CPU (% of a core) and its thread groups' over `seconds`, after `warmup`."""
    graph = load_graph(MAP)
    rng = random.Random(0)
    starts = {f"cf{i + 1:02d}": s for i, s in enumerate(rng.sample(sorted(graph.endpoints()), vehicles))}
    with soak_fleet(MAP, draw_tasks(graph, starts, rng), run_dir, 2, 8, 50.0) as fleet:
        pids = {p["instance"]: p["pid"] for p in json.loads((fleet.run_dir / "up.json").read_text())}
        time.sleep(warmup)
        t0 = time.monotonic()
        before = {name: (proc_sample(pid), thread_cpu(pid)) for name, pid in pids.items()}
        time.sleep(seconds)
        after = {name: (proc_sample(pid), thread_cpu(pid)) for name, pid in pids.items()}
        elapsed = time.monotonic() - t0
    processes: dict[str, float] = {}
    threads: dict[str, dict[str, float]] = {}
    for name, ((a, ta), (b, tb)) in ((n, (before[n], after[n])) for n in pids):
        if a is None or b is None:
            continue
        processes[name] = 100.0 * (b[1] - a[1]) / elapsed
        threads[name] = {g: 100.0 * (tb[g] - ta.get(g, 0.0)) / elapsed for g in tb}
    return processes, threads


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--vehicles", type=int, default=80)
    parser.add_argument("--warmup", type=float, default=30.0, help="s after the fleet is up before measuring")
    parser.add_argument("--seconds", type=float, default=30.0, help="s measured")
    parser.add_argument("--run-dir", default="out/fleet_at_rest", help="the deployment's run directory")
    args = parser.parse_args()
    processes, threads = measure(args.vehicles, args.warmup, args.seconds, Path(args.run_dir))
    groups = ("event loop", "other Python threads", "zenoh")
    names = sorted(processes, key=lambda n: -processes[n])
    print(format_table(["process", "CPU % of a core", *groups],
                       [[n, f"{processes[n]:.1f}", *(f"{threads[n].get(g, 0.0):.1f}" for g in groups)] for n in names]
                       + [["all", f"{sum(processes.values()):.1f}", "", "", ""]]))
    print(f"{args.vehicles} vehicles parked, no mission; CPU from /proc over {args.seconds:.0f} s after "
          f"{args.warmup:.0f} s; thread groups: the main thread, zenoh's named threads, the rest")
    fig, (ax,) = new_figure(width=7.0)
    bottom = [0.0] * len(names)
    for g in groups:
        values = [threads[n].get(g, 0.0) for n in names]
        ax.bar(names, values, bottom=bottom, label=g)
        bottom = [b + v for b, v in zip(bottom, values, strict=True)]
    ax.set_ylabel("% of a core")
    ax.set_title(f"The fleet at rest: {args.vehicles} vehicles parked, {sum(processes.values()):.0f} % in all")
    ax.tick_params(axis="x", rotation=30)
    ax.legend(fontsize=7)
    print(f"saved {save_figure(fig, args.out, 'fleet_at_rest')}")


if __name__ == "__main__":
    main()
