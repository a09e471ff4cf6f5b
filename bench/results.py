"""`make results`: every paper reproduction, recorded side by side with the papers' numbers.

Runs paper 000's Fig. 6 (bench.fig6), Fig. 7 (bench.fig7), Table II (the planner's battery model, and
endurance and power measured in the simulator by bench.endurance), the 934-node scale run
(bench.scale_city) and the MovingAI scale run (bench.movingai, when ../shared holds the benchmark
files), and paper 002's Tables I-II (bench.collab_experiment, a modest number of problems per map);
writes docs/results.md (tables beside the papers', the date, the machine, the commit), the figures
as PNGs under docs/results/ (committed) and every run's data as JSON under out/results/.

    python -m bench.results [--quick] [--collab-instances 20] [--docs docs] [--data out/results]
    python -m bench.results --only table2

`--quick` shrinks every run (a smoke test of the whole pipeline, not results to keep). `--only table2`
reruns Table II alone (about a minute) and replaces only its section of an existing results.md,
stamped with its own date and commit.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from bench import collab_experiment, endurance, fig6, fig7, movingai, scale_city
from common.domain.mapfile import load_map

REPO = Path(__file__).resolve().parent.parent
OWN_PATHS = ("services/planner", "common/domain", "common/team", "bench", "maps", "services/sim",
             "services/executor")
TABLE2_PATHS = ("bench/endurance.py", "bench/results.py", "common/domain", "common/flight", "common/crazyflie",
                "services/sim/crazyflie", "services/executor", "maps")
"""The code Table II's measurement runs (`--only table2` stamps its section with their state)."""


def md_table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    lines = ["| " + " | ".join(str(h) for h in headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def machine() -> dict:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count() or 0
    return {"cores": os.cpu_count() or 0, "usable_cores": usable, "cpu": cpu, "python": platform.python_version(),
            "system": f"{platform.system()} {platform.release()}"}


def commit(paths: Sequence[str] = OWN_PATHS) -> dict:
    """HEAD, and whether `paths` (the code a run measures) have uncommitted changes."""
    dirty = _git("status", "--porcelain", "--", *paths)
    return {"commit": _git("rev-parse", "HEAD"), "short": _git("rev-parse", "--short", "HEAD"),
            "subject": _shorten(_git("log", "-1", "--format=%s"), 90), "local_changes": bool(dirty)}


def _shorten(text: str, n: int) -> str:
    return text if len(text) <= n else text[: n - 3].rsplit(" ", 1)[0] + " ..."


# -- paper 000 Table II from the planner's battery model ----------------------------------------------

TABLE2_PAPER = {  # vehicle: speed m/s, run time min, max distance m, average power W, cost of transport
    "Crazyflie": (0.3, 5.7, 103, 6.86, 81.8),
    "Flying Car": (0.3, 5.0, 90, 7.83, 64.9),
    "Wheels": (0.1, 42, 252, 0.60, 14.9),
}


def table2(log: Callable[[str], None] | None = None) -> dict:
    """What the planner's model (eq. 4-5 with the shipped maps' vehicle) implies for Table II, and
    what the simulator measures with that vehicle (`bench.endurance`)."""
    model = load_map("fig6").vehicle
    energy_j = model.capacity_ah * model.voltage * 3600.0
    out = {"capacity_ah": model.capacity_ah, "reserve_ah": model.reserve_ah, "voltage": model.voltage,
           "energy_j": energy_j, "mass": model.mass, "power_fly": model.power.fly,
           "power_drive": model.power.drive, "power_idle": model.power.idle, "rows": {},
           "sim": endurance.measure_all(model, log)}
    for name, power, speed in (("Flying Car", model.power.fly, model.speed.fly),
                               ("Wheels", model.power.drive, model.speed.drive)):
        seconds = model.run_time_s(power)
        out["rows"][name] = {
            "speed": speed, "run_min": seconds / 60, "distance_m": seconds * speed, "power_w": power,
            "cot": model.cost_of_transport(power, speed), "usable_min": model.run_time_s(power, usable=True) / 60,
        }
    paper = {k: v[1] * 60 * v[3] for k, v in TABLE2_PAPER.items()}  # J delivered in the paper's runs
    out["paper_energy_j"] = paper
    return out


# -- the report ------------------------------------------------------------------------------------------


def _f(x: float | None, spec: str = ".3f") -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def section_fig6(r: dict) -> str:
    sipp, ilp = r["planners"]["sipp"], r["planners"]["ilp"]
    rows = [[p, "yes" if x["valid"] else "NO", ", ".join(x["fliers"]) or "nobody",
             x["priority"][-1] if x["priority"] else "-", f"{x['cost']:.3f}", f"{x['energy_j']:.1f}",
             f"{x['makespan_s']:.0f}", f"{x['seconds']:.3f}"]
            for p, x in (("prioritized SIPP (base graph)", sipp), ("ILP (one-time-step graph)", ilp))]
    lowest_flies = sipp["fliers"] == sipp["priority"][-1:]
    verdict = ("reproduced: the lowest-priority SIPP car flies over the traffic, the ILP keeps everyone on the "
               "ground at a lower cost" if lowest_flies and not ilp["fliers"] and ilp["cost"] < sipp["cost"]
               else "NOT reproduced in this run")
    return f"""### Fig. 6: prioritized vs optimal planning

Scenario `{r['scenario']}` on the 125-node `fig6` map, mu = {r['mu']}; the ILP plans with mu' =
{ilp['mu']:.3f} on its one-time-step graph (the same ranking of plans, `equivalent_mu`); costs are eq. 3
recomputed by the validator with the base graph's W_max and t_max. Paper: "(a) in priority planning,
the lowest priority car flies over traffic; (b) the optimal planner coordinates all robots
simultaneously so none have to fly". Here: **{verdict}**.

{md_table(["planner", "valid", "flies", "lowest priority", "cost", "energy J", "makespan s", "planning s"], rows)}

![Fig. 6](results/fig6.png)
"""


def section_fig7(r: dict) -> str:
    headers, rows, sum_headers, summary = fig7.tables(r)
    all_ = r["summary"]["all"]
    sipp, ilp = all_["sipp"]["mean_cost"], all_["ilp"]["mean_cost"]
    diff = (sipp - ilp) / sipp if sipp and ilp else math.nan
    verdict = ("**the paper's cost gap is reproduced**" if diff > 0.5 else
               "**the paper's cost gap is not reproduced** on random scenarios of this map")
    return f"""### Fig. 7: planning time and cost, SIPP vs ILP

{r['trials']} random scenarios (seeds 0..{r['trials'] - 1}) for each of {', '.join(map(str, r['sizes']))} vehicles on
`{r['map']}` ({r['base_nodes']} nodes; the ILP's one-time-step graph has {r['step_nodes']} nodes, dt =
{r['dt']:g} s, no edge slower than its kind's speed), mu = {r['mu']} (ILP: mu' = {r['ilp_mu']:.3f}),
time limit {r['time_limit_s']:g} s. SIPP on the base graph, the ILP on its one-time-step graph; every
plan checked by the validator, which recomputes both costs on one definition (eq. 3 with the base
graph's W_max = {r['scale']['w_max']:.2f} J, t_max = {r['scale']['t_max']:.2f} s); mean cost over the
{all_['both_solved']} scenarios both planners solved. Warm planning times (per-graph tables built
first).

{md_table(sum_headers, summary)}

The paper: the optimal planner's mean cost is 91 % below the priority planner's (0.155 vs 1.76, on
its own cost scale), its mean time 1.25 s against 0.106 s. Here the ILP's mean cost is
{_f(100 * abs(diff), '.1f')} % {'above' if diff < 0 else 'below'} SIPP's: {verdict}: on {all_['ilp_cheaper']} of {all_['both_solved']}
scenarios the ILP is cheaper, on {all_['sipp_cheaper']} SIPP is (it plans in continuous time and may
wait a fraction of the ILP's 2 s step), on the rest they tie; few vehicles ever fly
(mean fliers per scenario: SIPP {_f(all_['sipp']['mean_fliers'], '.2f')}, ILP
{_f(all_['ilp']['mean_fliers'], '.2f')}). The time ordering is the paper's (SIPP about
{_f(all_['ilp']['mean_s'] / max(all_['sipp']['mean_s'], 1e-9), '.0f')}x faster). Fig. 6's scenario
shows where prioritized planning costs more (its last car has to fly), but random tasks between the
rim spots of a 7 x 7 grid rarely congest it that much.

Per size:

{md_table(headers, rows)}

![Fig. 7](results/fig7.png)
"""


TABLE2_HEADING = "### Table II: energetics"


def section_table2(r: dict, stamp: str = "") -> str:
    """Table II: the paper's rows, the planner's model (eq. 4-5) and the simulator's measurement
    (bench.endurance), with the battery model's parameters and the paper's inconsistency (§VII-A)."""
    sim = r["sim"]
    measured = {"Flying Car": sim["fly"], "Wheels": sim["drive"]}
    rows = []
    for name, paper in TABLE2_PAPER.items():
        ours = r["rows"].get(name)
        rows.append([name, "paper", paper[0], paper[1], paper[2], f"{paper[3]:.2f}", paper[4]])
        if ours:
            rows.append([name, "planner's model (eq. 4-5)", ours["speed"], f"{ours['run_min']:.1f}",
                         f"{ours['distance_m']:.0f}", f"{ours['power_w']:.2f}", f"{ours['cot']:.1f}"])
        else:
            rows.append([name, "planner's model", "not modelled: stock Crazyflies (capabilities `fly`) are planned "
                         "with the flying car's model", "", "", "", ""])
        m = measured.get(name)
        if m:
            rows.append([name, "simulator (measured)", f"{m['speed']:.3f}", f"{m['run_min']:.1f}",
                         f"{m['distance_m']:.0f}", f"{m['power_w']:.2f}", f"{m['cot']:.1f}"])
        else:
            rows.append([name, "simulator", "not simulated: the simulator draws its vehicle model's Table II "
                         "power at that model's weight, so a stock Crazyflie's 6.86 W would be put in, "
                         "not measured", "", "", "", ""])
    pe = r["paper_energy_j"]
    fly, drive = sim["fly"], sim["drive"]
    fly_model, drive_model = r["rows"]["Flying Car"], r["rows"]["Wheels"]
    sag = fly["cruise_power_w"] / r["voltage"] * sim["r_internal"]
    return f"""{TABLE2_HEADING}

The planner's battery model (`common/domain/vehicle_model.py`, eq. 4-5; the shipped maps' vehicle):
capacity {r['capacity_ah']:.3f} Ah at {r['voltage']:g} V = {r['energy_j']:.0f} J (fitted to the paper's
5.0 min of flight at 7.83 W), of which {r['capacity_ah'] - r['reserve_ah']:.3f} Ah may be planned (reserve
{r['reserve_ah']:.3f} Ah: flight {fly_model['usable_min']:.1f} min, driving {drive_model['usable_min']:.1f} min);
mass {r['mass'] * 1000:.0f} g; cost of transport P / (m g v).

The simulator's battery (`services/sim/crazyflie/physics.py`), measured by `bench.endurance`: the same
capacity and Table II powers (flight {r['power_fly']:.2f} W at hover thrust, scaled by (thrust /
weight)^1.5; driving {r['power_drive']:.2f} W at 0.1 m/s, scaled by wheel speed; {r['power_idle']:.2f} W for the
electronics, an estimate), a Li-Po open-circuit curve (4.20 V full, 3.27 V empty) and
{sim['r_internal']:g} ohm internal resistance. The executor's control stack flies a 24-gon circuit at 0.5 m
(drives one on the floor) from a full battery, 100 Hz, faster than real time, until its low-battery
rule fires with no reserve kept: the loaded voltage under {sim['vbat_low']:g} V for 1 s. Measured speed,
run time, distance in ground truth, average power (charge drawn x {r['voltage']:g} V / run time):

{md_table(["vehicle", "source", "speed m/s", "run time min", "max dist m", "ave power W", "COT"], rows)}

In the simulator a flight ends at {fly['run_min']:.1f} min, before the {fly_model['run_min']:.1f} min the
capacity holds: the {fly['cruise_power_w'] / r['voltage']:.1f} A of flight sags the cell {sag:.2f} V, so the loaded
voltage reaches {sim['vbat_low']:g} V with {100 * fly['soc_left']:.0f} % of the charge left. That is within the
fleet's {100 * r['reserve_ah'] / r['capacity_ah']:.0f} % reserve: a plan that keeps it lands by
{fly_model['usable_min']:.1f} min, before the voltage rule. Driving draws
{drive['cruise_power_w'] / r['voltage'] * 1000:.0f} mA, the sag is negligible and the run uses the cell to
{100 * drive['soc_left']:.0f} %: {drive['run_min']:.0f} min, {drive['run_min'] / 42:.1f}x the paper's 42.

The paper is not self-consistent: its flights deliver {pe['Flying Car']:.0f} J (7.83 W x 5.0 min) and
{pe['Crazyflie']:.0f} J (Crazyflie, 6.86 W x 5.7 min), one battery's worth, but its driving run
delivers only {pe['Wheels']:.0f} J (0.60 W x 42 min), 64 % of it. A Li-Po gives more of its charge at a low
current, not less (less sag, as measured here), so no battery model reproduces both run times with
the listed powers. Either the driving run's average power was nearer
{pe['Flying Car'] / (42 * 60):.2f} W (0.60 W measured at the wheel motors' driver without the
Crazyflie's electronics and radio would be {pe['Flying Car'] / (42 * 60) - 0.60:.2f} W short), or the run ended
before the battery did (a motor driver stalling the 41 g car at a voltage the Crazyflie still flies
on). The model keeps the paper's powers, whose ratio (the COT, {fly_model['cot']:.1f} vs
{drive_model['cot']:.1f}) is what eq. 1-3 trade off, and fits the capacity to flight, which decides
whether a plan fits its battery; so it predicts {drive_model['run_min']:.0f} min of driving where the paper
measured 42, and for long drives the battery constraint (eq. 6) is as optimistic as that.
{stamp}"""


def section_city(r: dict) -> str:
    headers, rows = scale_city.table(r)
    biggest = max((x["vehicles"] for x in r["runs"] if x["ok"]), default=0)
    return f"""### The 934-node map (Fig. 8, §VII-B: "we could plan for up to 80 vehicles in the large map")

Prioritized SIPP on `city934` ({r['nodes']} nodes, {r['edges']} edges), {r['trials']} random scenarios per
fleet size, mu = {r['mu']}, time limit {r['time_limit_s']:g} s, every plan validated; per-graph tables
built once in {r['tables_s']:.1f} s. Largest fleet solved: {biggest} vehicles (paper: 80). Beyond 75
vehicles some goals are other vehicles' starts (150 spots).

{md_table(headers, rows)}

![city934](results/scale_city.png)
"""


def section_movingai(r: dict | None, reason: str = "") -> str:
    if r is None:
        return f"""### MovingAI scale run

Not run: {reason}
"""
    headers, rows = movingai.table(r)
    solved = [x["agents"] for x in r["runs"] if x["ok"]]
    return f"""### MovingAI scale run (MAPF benchmark, Stern et al. 2019)

Prioritized SIPP with restarts on `{r['map']}` ({r['cells']} free cells) with the first k agents of
`{r['scen']}`, unit cells and speed, vertex and swap conflicts only (continuous time), mu = 0 (sum of
costs), time limit {r['time_limit_s']:g} s, every plan validated. Solved up to {max(solved, default=0)}
agents. (The paper reports no MovingAI run; this is the planner at scale on a standard benchmark.)

{md_table(headers, rows)}

![MovingAI](results/movingai.png)
"""


def section_collab(r: dict) -> str:
    parts = [f"""## Paper 002: Tables I-II (PAD vs full-dimensional ARA*)

{r['instances']} seeded problems per map (the paper: 50), {r['time_limit']:g} s to the first solution +
up to {r['improve']:g} s to improve (the paper: 3 min + 5 s; `python -m bench.collab_experiment
--paper-limits`), the paper's drone primitives (corner groups of metric controllers, WALLFOLLOWING's
OBSTACLE trigger), PAD with eps_track {r['eps_track']:g}. Averages over the problems both planners
solved, as in the paper; costs are metres here, the paper's own units there; expansions are not
comparable (different lattices).
"""]
    headers = ["map", "algorithm", "time avg s", "std", "min", "max", "iter. avg", "expans. avg", "cost avg",
               "eps avg", "success %"]
    for name, m in r["maps"].items():
        rows = []
        for method in collab_experiment.METHODS:
            v = m["summary"][method]
            rows.append([name, collab_experiment.LABELS[method], *(_f(x, ".2f") for x in v[:4]),
                         _f(v[4], ".2f") if v[4] is not None else "n/a", _f(v[5], ".0f"), _f(v[6], ".1f"),
                         _f(v[7], ".2f"), f"{v[8]:.0f} @{r['time_limit']:g}s"])
        for method in collab_experiment.METHODS:
            v = collab_experiment.PAPER[name][method]
            rows.append([name, "paper " + collab_experiment.LABELS[method], *(f"{x:.2f}" for x in v[:4]),
                         f"{v[4]:.2f}" if v[4] is not None else "n/a", f"{v[5]:.0f}", f"{v[6]:.0f}", f"{v[7]:.2f}",
                         f"{v[8]:.0f} @3min"])
        parts.append(md_table(headers, rows) + "\n\n" + m["limits"] + "\n")
    conf, cub = (r["maps"][n]["summary"] for n in collab_experiment.MAPS)
    faster = [n for n, s in zip(collab_experiment.MAPS, (conf, cub), strict=True) if s["pad"][0] < s["arastar"][0]]
    parts.append(f"""Against the paper: PAD's success rate is {conf['pad'][8]:.0f} % and {cub['pad'][8]:.0f} % (paper 100 %),
ARA*'s {conf['arastar'][8]:.0f} % and {cub['arastar'][8]:.0f} % (paper 82 % and 38 % within 3 min). PAD averages
{_f(conf['pad'][4], '.2f')} and {_f(cub['pad'][4], '.2f')} iterations (paper 1.59 and 1.26). Mean planning
time: PAD is faster than ARA* on {', '.join(faster) if faster else 'neither map'}; in the paper PAD is
slower on the conference map (20.05 s vs 9.37 s) and level on the cubicles (12.74 s vs 12.33 s), so
{'the time ordering is reversed here' if faster else 'the time ordering matches'}. Absolute times are about an
order of magnitude below the paper's (smaller lattice: 0.5 m cells, two altitudes).

![002](results/collab_experiment.png)
""")
    return "\n".join(parts)


def write_report(path: Path, sections: list[str], meta: dict) -> None:
    m, c = meta["machine"], meta["commit"]
    local = " (with uncommitted changes to the code it measures)" if c["local_changes"] else ""
    head = f"""# Results: the papers reproduced

Generated by `make results` (`python -m bench.results`); do not edit by hand, rerun it.

- date: {meta['date']}
- machine: {m['cores']} cores ({m['usable_cores']} usable; shared with other work, so times vary), {m['cpu']},
  {m['system']}, Python {m['python']}
- commit: `{c['short']}` {c['subject']}{local}
- run time: {meta['run_s'] / 60:.1f} min{' (--quick: a smoke run, not results)' if meta['quick'] else ''}
- data: every run as JSON under `{meta['data']}` (not committed); figures under `docs/results/`

## Paper 000: Araki et al., flying cars
"""
    path.write_text(head + "\n" + "\n".join(sections))


def _now() -> str:
    return dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def replace_section(path: Path, heading: str, text: str) -> None:
    """Replace the section of `path` that starts at the line `heading` (up to the next heading of
    its level or above) with `text`; the rest of the report is kept as the full run wrote it."""
    if not path.is_file():
        raise SystemExit(f"{path}: no report to update; run `python -m bench.results` first")
    lines = path.read_text().splitlines(keepends=True)
    try:
        start = next(i for i, line in enumerate(lines) if line.rstrip() == heading)
    except StopIteration:
        raise SystemExit(f"{path}: no section {heading!r} to replace") from None
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith(("## ", "### "))), len(lines))
    path.write_text("".join(lines[:start]) + text.rstrip("\n") + "\n\n" + "".join(lines[end:]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench.results", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny runs: check the pipeline, not results")
    parser.add_argument("--collab-instances", type=int, default=20)
    parser.add_argument("--docs", default=str(REPO / "docs"), help="where results.md and results/*.png go")
    parser.add_argument("--data", default=str(REPO / "out" / "results"), help="where the JSON goes")
    parser.add_argument("--only", choices=["table2"], help="rerun one section of an existing results.md")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    docs, data = Path(args.docs), Path(args.data)
    figs = docs / "results"
    figs.mkdir(parents=True, exist_ok=True)
    data.mkdir(parents=True, exist_ok=True)
    log: Callable[[str], None] = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    q = args.quick

    def save(name: str, obj: dict) -> None:
        (data / f"{name}.json").write_text(json.dumps(obj, indent=1, default=str))

    if args.only == "table2":
        r2 = table2(log)
        save("table2", r2)
        c = commit(TABLE2_PATHS)
        stamp = (f"\n_This section rerun alone (`python -m bench.results --only table2`, "
                 f"{time.perf_counter() - t0:.0f} s) on {_now()} at commit `{c['short']}`"
                 f"{' with uncommitted changes to the code it measures' if c['local_changes'] else ''}._\n")
        replace_section(docs / "results.md", TABLE2_HEADING, section_table2(r2, stamp))
        log(f"updated Table II in {docs / 'results.md'}")
        return 0

    sections = []
    log("== Fig. 6")
    r6 = fig6.run(log=log)
    save("fig6", r6)
    fig6.figure(r6, figs)
    sections.append(section_fig6(r6))

    log("== Fig. 7")
    r7 = fig7.run([3, 4] if q else [3, 4, 5, 6], 2 if q else 20, 0.5, 30.0, log=log)
    save("fig7", r7)
    fig7.figure(r7, figs)
    sections.append(section_fig7(r7))

    log("== Table II")
    r2 = table2(log)
    save("table2", r2)
    sections.append(section_table2(r2))

    log("== city934")
    rc = scale_city.run([20, 40] if q else [20, 40, 80, 120], 1 if q else 5, 0.5, 60.0, log=log)
    save("scale_city", rc)
    scale_city.figure(rc, figs)
    sections.append(section_city(rc))

    log("== MovingAI")
    map_path = movingai.BENCH_DIR / "random-32-32-10.map"
    scen_path = movingai.BENCH_DIR / "random-32-32-10-random-1.scen"
    if map_path.is_file() and scen_path.is_file():
        agents = [50, 100] if q else [50, 100, 150, 200, 250, 300, 350, 400, 450]
        rm = movingai.run(str(map_path), str(scen_path), agents, 60.0, log=log)
        save("movingai", rm)
        movingai.figure(rm, figs)
        sections.append(section_movingai(rm))
    else:
        sections.append(section_movingai(None, f"the benchmark files are missing ({map_path.parent})"))

    log("== paper 002")
    instances = 2 if q else args.collab_instances
    rcol: dict = {"instances": instances, "time_limit": 10.0, "improve": 1.0, "eps_track": collab_experiment.EPS_TRACK,
                  "maps": {}}
    runs_by_map = {}
    for name in collab_experiment.MAPS:
        runs, example = collab_experiment.run_map(name, instances, 10.0, 1.0)
        runs_by_map[name] = (runs, example)
        rcol["maps"][name] = {"summary": collab_experiment.summarize(runs),
                              "limits": collab_experiment.format_limits(name, runs, 10.0),
                              "runs": [vars(x) for x in runs]}
    collab_experiment.plot(figs / "collab_experiment.png", runs_by_map, 10.0)
    save("collab_experiment", rcol)
    collab_section = section_collab(rcol)

    meta = {"date": _now(), "machine": machine(), "commit": commit(),
            "run_s": time.perf_counter() - t0, "quick": q, "data": os.path.relpath(data, REPO)}
    save("meta", meta)
    write_report(docs / "results.md", sections + [collab_section], meta)
    log(f"wrote {docs / 'results.md'} in {meta['run_s'] / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
