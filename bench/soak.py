"""Soak: many simulated vehicles through back-to-back missions for a set time (issue 8).

The fleet runs as in `fleet demo` (a router process with access control, every service a process,
simulated Crazyflies), sized for a large fleet: gateways with `--subscribe-each` and log blocks at
5 Hz (`LOG_PERIOD_S`), `--radios-per-gateway` radios to a gateway process, the simulator's ground
truth at `--truth-hz`, no telemetry recorder. Missions on the city934 map follow each other: each
starts where the last one left the vehicles, with fresh goals. Collected while it runs:

- every service's `stats/<service>/<instance>` (common/bus/stats.py): dropped messages, refusals,
  the executors' missed control deadlines and pose-to-command latency, the simulator's lag;
- each process's resident memory and CPU time from /proc, every `--sample-s` seconds;
- the machine's CPU every second: how busy its cores were and what its host took (`bench.machine_cpu`).

Printed as tables at the end; `soak.png` plots memory and latency over time. With `--trace FILE`
a recorder process keeps every vehicle's ground truth, state, events and telemetry for tracing a
contact or a hold by time afterwards (`bench/trace.py`).

    python -m bench.soak [--minutes 5] [--vehicles 80] [--executors 2] [--per-radio 8] [--truth-hz 50] [--sim-priority 5]
                         [--trace FILE] [--no-plan-clock] [--control offboard|onboard] [--radios-per-gateway 5]
    FLEET_SOAK_MINUTES=20 make soak        # the same through pytest -m soak (tests/test_soak.py)
"""

from __future__ import annotations

import asyncio
import json
import os
import random
import shutil
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from bench.machine_cpu import MachineCpu, sample_machine, task_cpu_seconds
from bench.tables import bench_parser, cpu_probe, format_table, new_figure, save_figure
from common.bus.messages import ControlMode, ServiceStats, SimTruth
from common.bus.pubsub import subscribe
from common.bus.session import open_session
from common.deploy.local import LocalFleet
from common.deploy.radios import GatewayParams
from common.domain.planfile import Task
from services.mission.client import MissionTiming
from services.mission.demo import local_fleet
from services.mission.runner import MissionResult, MissionRunner, MissionSpec
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.maps.loading import load_graph
from services.planner.service import RECENT as RECENT_PLANS

MAP = "city934"
SIM_PRIORITY = 5
"""Nice levels the soak's simulator raises its CPU priority by (`fleet sim --priority`, where the
system allows it): it stands for the physical world, which does not wait for a loaded machine.
Starved, it stalled for 0.3-0.5 s at a time, and the fleet failed on what a lab would not see:
every body lost by the motion capture at once, stops that reached the wheels that late, blind
descents that drifted onto parked vehicles. 32-vehicle one-minute soaks on 2026-12-06, one after
another (one run of each with the planner's priority lowered too): raised, 6 missions of 9 OK and
no contact; not raised, 3 of 7 OK, two with contacts (-3.3 and -8.9 cm), the simulator behind
real time 1-92 times a run against 20-360 (docs/reliability.md, "Last results"). `fleet sim`
itself leaves its priority by default: a raised one cost `tests/test_fleet_up.py`'s flight reruns
in CI (docs/radio.md). What it moves is
where the machine's shortage shows: two raised runs had the executors and gateways starved instead,
take-offs landed on stale commands and touched down at 1.2-1.8 m/s."""
SERVICES = ("executor", "gateway", "sim", "mocap", "planner")
FAILED_PLANS = "failed-plans"
"""The folder of the run directory the planner keeps the requests it could not plan in (`fleet
planner --keep-failed`)."""
END_TRUTH_S = 1.0
"""How long the soak listens to the simulator's ground truth at its end (every vehicle's, at `truth_hz`)."""
REST_WAIT_S = 40.0
"""s the soak waits at its end for every vehicle to be at rest on the ground (ground truth): a
failed mission's abort lands the vehicles still in the air, by their safe landings (to a node,
then down), which the soak's end overtook: a 32-vehicle soak judged cf10 "not at rest" while it
was coming down."""
_PAGE_KB = os.sysconf("SC_PAGE_SIZE") / 1024


def draw_tasks(graph: FleetGraph, starts: dict[str, str], rng: random.Random) -> dict[str, Task]:
    """Fresh distinct goals for vehicles at `starts`: free spots first, then (beyond half the spots)
    other vehicles' starts, never a vehicle's own."""
    spots = sorted(graph.endpoints())
    taken = set(starts.values())
    free = [s for s in spots if s not in taken]
    rng.shuffle(free)
    goals = free[:len(starts)] + rng.sample(sorted(taken), max(0, len(starts) - len(free)))
    while True:
        rng.shuffle(goals)
        if all(g != s for g, s in zip(goals, starts.values(), strict=True)):
            return {vid: Task(start=s, goal=g) for (vid, s), g in zip(starts.items(), goals, strict=True)}


MACHINE_WINDOW_S = 1.0
"""s between samples of the machine's CPU (`bench.machine_cpu`): its worst window of steal."""

LOG_PERIOD_S = 0.2
"""s: the soak's gateways have the firmware stream its log block (battery, supervisor, RSSI) at 5 Hz,
not 10: telemetry goes out at 5 Hz anyway (`status_hz`), a lost link is still judged after 1 s
(five blocks), and an idle fleet of 80 costs 1.06 cores instead of 1.26 (gateways 4.9-5.2 % each
instead of 6.3-6.6, the simulator 32 % instead of 38, 2026-12-05)."""


RADIOS_EACH = 5
"""Radios per gateway process: each process costs its overhead besides its radios' work (an idle
gateway of 8 vehicles takes 5-6 % of a core): in 1-minute 80-vehicle soaks the gateways took
69-72 % of a core as ten processes, 50-53 % as two of five radios, 48 % as one, the whole fleet
165-169 %, 155-161 % and 147 % (2026-12-06, docs/radio.md "Several radios in one process")."""


def soak_fleet(map_name: str, tasks: dict[str, Task], run_dir: Path, executors: int, per_radio: int,
               truth_hz: float, fleet: str = "soak", thrust_spread: float = 0.0,
               sim_priority: int = SIM_PRIORITY, plan_clock: bool = True, control: ControlMode = "offboard",
               radios_each: int = RADIOS_EACH):
    """The demo's fleet (services.mission.demo), minus the recorder, tuned for a large fleet
    (`LOG_PERIOD_S`); `sim_priority`: nice levels the simulator raises its priority by (`fleet sim
    --priority`); `plan_clock` False: the executors run plans on the wall clock (`fleet executor
    --no-plan-clock`); `control`: every vehicle's control mode (docs/control.md); `radios_each`:
    radios per gateway process."""
    return local_fleet(map_name, tasks, run_dir, executors, per_radio, fleet=fleet, without={"telemetry"},
                       extra_args={"sim": ["--truth-hz", str(truth_hz), "--thrust-spread", str(thrust_spread),
                                           "--priority", str(sim_priority)],
                                   "executor": [] if plan_clock else ["--no-plan-clock"],
                                   "planner": ["--keep-failed", str(run_dir / FAILED_PLANS)]},
                       gateway=GatewayParams(log_period_s=LOG_PERIOD_S), control=control, radios_each=radios_each)


@contextmanager
def recording(fleet: LocalFleet, path: Path | None) -> Iterator[None]:
    """`bench.trace record` into `path` (None: nothing) while the block runs, as the operator's role."""
    if path is None:
        yield
        return
    env = {**os.environ, "FLEET_ZENOH_USER": "mission",
           "FLEET_ZENOH_PASSWORD_FILE": str(fleet.credentials.password_file("mission"))}
    env.pop("FLEET_ZENOH_PASSWORD", None)
    recorder = subprocess.Popen([sys.executable, "-m", "bench.trace", "record", str(path), "--connect", fleet.endpoint,
                                 "--fleet", fleet.keys.fleet], stdin=subprocess.PIPE, env=env)
    try:
        yield
    finally:
        assert recorder.stdin is not None
        recorder.stdin.close()
        try:
            recorder.wait(30.0)
        except subprocess.TimeoutExpired:
            recorder.kill()


def proc_sample(pid: int) -> tuple[float, float] | None:
    """(resident MB, CPU seconds) of a process, None if it is gone."""
    try:
        rss_pages = int(Path(f"/proc/{pid}/statm").read_text().split()[1])
        cpu = task_cpu_seconds(Path(f"/proc/{pid}/stat").read_text())
    except (OSError, IndexError, ValueError):
        return None
    return rss_pages * _PAGE_KB / 1024, cpu


@dataclass
class SoakLog:
    """Everything collected while the soak runs."""

    started: float = field(default_factory=time.time)
    stats: dict[str, ServiceStats] = field(default_factory=dict)  # "service/instance" -> latest
    first_stats: dict[str, ServiceStats] = field(default_factory=dict)
    series: dict[str, list[tuple[float, float, float]]] = field(default_factory=lambda: defaultdict(list))
    """instance -> (t, RSS MB, CPU s)."""
    latency: dict[str, list[tuple[float, float, float]]] = field(default_factory=lambda: defaultdict(list))
    """executor instance -> (t, pose-to-command p99 ms, missed deadlines so far)."""
    missions: list[MissionResult] = field(default_factory=list)
    idle_from: float | None = None
    """s into the soak when a mission failed: from then on the fleet runs on without missions."""
    flights: int = 0
    """Vehicle trips whose plan takes to the air."""
    load: list[float] = field(default_factory=list)
    """The machine's 1-minute load average at each process sample (other work shares the cores)."""
    final: dict[str, SimTruth] = field(default_factory=dict)
    """Each vehicle's ground truth once the soak is over (`END_TRUTH_S`): where the fleet left it."""
    vehicles: int = 0
    rest_after: float = 0.0
    """s from the last mission's end until every vehicle was at rest (`REST_WAIT_S` at most)."""
    probe_ms: tuple[float, float] = (0.0, 0.0)
    """The machine's speed before the fleet started (`bench.tables.cpu_probe`: wall, CPU ms)."""
    own: list[tuple[float, float, float]] = field(default_factory=list)
    """This process (the mission and the soak's own listening) as `series` has the
    fleet's: (t, RSS MB, CPU s). Not a service: its memory holds what the soak collects."""
    machine: MachineCpu = field(default_factory=MachineCpu)
    """The machine's CPU, busy and stolen by its host, every `MACHINE_WINDOW_S` (`bench.machine_cpu`)."""

    def sim_figures(self) -> dict[str, float | str]:
        """The simulators' latest figures, summed (hardest touchdown: the largest; `hardest`: the
        three hardest touchdowns, m/s)."""
        sims = [st.figures for st in self.stats.values() if st.service == "sim"]
        hardest = sorted(((v, k.split(":", 1)[1]) for f in sims for k, v in f.items() if k.startswith("touchdown_mps:")),
                         reverse=True)
        return {"touchdown_max_mps": max((f.get("touchdown_max_mps", 0.0) for f in sims), default=0.0),
                "watchdog_cuts": sum(f.get("watchdog_cuts", 0.0) for f in sims),
                "hardest": ", ".join(f"{vid} {v:.2f}" for v, vid in hardest[:3])}

    def not_at_rest(self) -> list[str]:
        """Vehicles the soak left in the air or with motors running (ground truth)."""
        return sorted(vid for vid, truth in self.final.items() if truth.airborne or truth.motors)

    def on_stats(self, msg: ServiceStats) -> None:
        name = f"{msg.service}/{msg.instance}"
        self.first_stats.setdefault(name, msg)
        self.stats[name] = msg
        if msg.service == "executor":
            self.latency[msg.instance].append((msg.t - self.started, msg.figures.get("pose_to_cmd_p99_ms", 0.0),
                                               msg.figures.get("missed", 0.0)))


async def sample_processes(log: SoakLog, pids: dict[str, int], every_s: float) -> None:
    while True:
        now = time.time() - log.started
        log.load.append(os.getloadavg()[0])
        for name, pid in pids.items():
            sample = proc_sample(pid)
            if sample is not None:
                log.series[name].append((now, *sample))
        own = proc_sample(os.getpid())
        if own is not None:
            log.own.append((now, *own))
        await asyncio.sleep(every_s)


async def soak(fleet: LocalFleet, graph: FleetGraph, tasks: dict[str, Task], seconds: float, sample_s: float,
               seed: int) -> SoakLog:
    """Missions back to back for `seconds` (the last one is flown to its end); after a failed one
    the services run on without missions until the time is up (memory, drops and deadlines still
    count: every executor ticks and every pose flows whether the vehicles move or not)."""
    log = SoakLog(vehicles=len(tasks))
    pids = {p["instance"]: p["pid"] for p in json.loads((fleet.run_dir / "up.json").read_text())}
    session = open_session(fleet.client_config())
    for service in SERVICES:  # one subscription per service: what the router's access control grants
        subscribe(session, fleet.keys.all_stats(service), ServiceStats, lambda m, _k: log.on_stats(m))
    sampler = asyncio.create_task(sample_processes(log, pids, sample_s))
    machine = asyncio.create_task(sample_machine(log.machine, MACHINE_WINDOW_S))
    rng = random.Random(seed)
    try:
        while time.time() - log.started < seconds:
            spec = MissionSpec(map=MAP, tasks=tasks, planner="sipp", time_limit=60.0, timing=MissionTiming(ready_timeout_s=60.0),
                               slack_s=30.0, mission=f"soak{len(log.missions) + 1:03d}")
            runner = MissionRunner(spec, fleet.client_config(), fleet.keys, progress=False)
            await runner.run()
            result = runner.result
            assert result is not None
            log.missions.append(result)
            first = runner.first_plan  # (`runner.plan` is the last replan's: the vehicles that stayed)
            if first is not None:
                log.flights += sum(any(first.graph.nodes[e.node].kind == "air" for e in path)
                                   for path in first.paths.values())
            print(f"[{time.time() - log.started:6.0f} s] {result.summary().splitlines()[0]}; "
                  f"{sum(r.arrived for r in result.vehicles.values())}/{len(tasks)} arrived, "
                  f"contacts {result.contacts}, the plan's clock waited {result.delay_s:.1f} s", flush=True)
            if not result.ok:  # the vehicles are wherever the abort left them: no next mission
                print(result.summary(), flush=True)
                log.idle_from = time.time() - log.started
                await asyncio.sleep(max(0.0, seconds - log.idle_from))
                break
            tasks = draw_tasks(graph, {vid: t.goal for vid, t in tasks.items()}, rng)
        truths = subscribe(session, fleet.keys.all_sim_truth, SimTruth,
                           lambda m, _k: log.final.__setitem__(m.vid, m))
        ended = time.time()
        await asyncio.sleep(max(END_TRUTH_S, 2.5))  # every vehicle's truth, everyone's last stats
        while (log.not_at_rest() or len(log.final) < log.vehicles) and time.time() - ended < REST_WAIT_S:
            await asyncio.sleep(0.5)
        log.rest_after = time.time() - ended
        truths.close()
    finally:
        sampler.cancel()
        machine.cancel()
        session.close()
    return log


def mb_per_min(points: list[tuple[float, float, float]]) -> float:
    """Memory growth (MB/min) from the first third of the run to the last (warm-up excluded)."""
    if len(points) < 6:
        return 0.0
    third = len(points) // 3
    early, late = points[third:2 * third], points[2 * third:]
    t0, m0 = sum(p[0] for p in early) / len(early), sum(p[1] for p in early) / len(early)
    t1, m1 = sum(p[0] for p in late) / len(late), sum(p[1] for p in late) / len(late)
    return 60.0 * (m1 - m0) / (t1 - t0) if t1 > t0 else 0.0


def report(log: SoakLog, seconds: float) -> str:
    """The tables: missions, each service's drops and figures, each process's memory and CPU."""
    elapsed = time.time() - log.started
    ok = sum(m.ok for m in log.missions)
    arrived = sum(sum(r.arrived for r in m.vehicles.values()) for m in log.missions)
    flights = sum(len(m.vehicles) for m in log.missions)
    gap = min((m.min_gap for m in log.missions), default=float("inf"))
    lines = [f"soak: {elapsed / 60:.1f} min (asked {seconds / 60:.1f}), missions {ok}/{len(log.missions)} OK, "
             f"{arrived}/{flights} vehicle trips arrived ({log.flights} with flights), contacts {sum(m.contacts for m in log.missions)}, "
             f"closest bodies {100 * gap:.1f} cm; machine load average {min(log.load, default=0):.1f}-"
             f"{max(log.load, default=0):.1f} on {os.cpu_count()} cores, its speed probe {log.probe_ms[0]:.0f} ms ({log.probe_ms[1]:.0f} ms CPU)"]
    if machine := log.machine.line(MACHINE_WINDOW_S):
        lines.append(machine)
    sim, aloft = log.sim_figures(), log.not_at_rest()
    lines.append(f"at the end (ground truth, {log.rest_after:.0f} s after the last mission): "
                 f"{len(log.final) - len(aloft)}/{log.vehicles} vehicles at rest "
                 f"on the ground{' (not: ' + ', '.join(aloft) + ')' if aloft else ''}; "
                 f"hardest touchdowns (m/s) {sim.get('hardest') or '-'}; motors cut in the air "
                 f"{sim.get('watchdog_cuts', 0):.0f}x")
    for m in log.missions:
        if not m.ok:
            lines.append(f"failed: {m.mission}: {m.reason}")
    if log.idle_from is not None:
        lines.append(f"no missions from {log.idle_from / 60:.1f} min on: the services ran on with the vehicles stopped")
    rows = []
    for name, st in sorted(log.stats.items()):
        first = log.first_stats[name]
        f = st.figures
        extra = ""
        if st.service == "executor":
            extra = (f"missed {f.get('missed', 0):.0f}/{f.get('ticks', 0):.0f} ticks, late p99 {f.get('late_p99_ms', 0):.1f} ms, "
                     f"tick p99 {f.get('cost_p99_ms', 0):.1f} ms, pose->cmd p50/p99/max "
                     f"{f.get('pose_to_cmd_p50_ms', 0):.0f}/{f.get('pose_to_cmd_p99_ms', 0):.0f}/"
                     f"{f.get('pose_to_cmd_max_ms', 0):.0f} ms, from the bridge p50/p99 "
                     f"{f.get('frame_to_cmd_p50_ms', 0):.1f}/{f.get('frame_to_cmd_p99_ms', 0):.1f} ms, poses "
                     f"rejected {f.get('poses_rejected', 0):.0f} (estimator restarts {f.get('estimator_restarts', 0):.0f}), "
                     f"slowed by its latency {f.get('slowed_cycles', 0):.0f} cycles; proximity stops spared by the plans "
                     f"{st.counters.get('proximity_kept_apart_by_plans', 0)}, pauses {st.counters.get('proximity_paused', 0)} "
                     f"(ended {st.counters.get('proximity_pause_ended', 0)}, held {st.counters.get('proximity_pause_held', 0)}), "
                     f"for their own tracking {st.counters.get('tracking_paused', 0)} (ended "
                     f"{st.counters.get('tracking_pause_ended', 0)}, held {st.counters.get('tracking_pause_held', 0)})")
        elif st.service == "sim":
            extra = (f"truth behind {st.counters.get('truth_behind', 0)}x, watchdog level/cut "
                     f"{f.get('watchdog_levels', 0):.0f}/{f.get('watchdog_cuts', 0):.0f}, radio lost "
                     f"{f.get('radio_lost', 0):.0f} congested {f.get('radio_congested', 0):.0f}")
        elif st.service == "mocap":
            extra = f"poses {f.get('poses', 0):.0f}, late frames dropped {f.get('late_frames', 0):.0f}"
        elif st.service == "planner":
            extra = (f"plans ok {st.counters.get('plans_ok', 0)}, failed {st.counters.get('plans_failed', 0)}, "
                     f"expired {st.counters.get('plans_expired', 0)}; waited p50/max "
                     f"{f.get('waited_p50_ms', 0):.0f}/{f.get('waited_max_ms', 0):.0f} ms, planned p50/max "
                     f"{f.get('planned_p50_ms', 0):.0f}/{f.get('planned_max_ms', 0):.0f} ms (latest {RECENT_PLANS})")
        elif st.service == "gateway":
            extra = (f"ticks {f.get('ticks', 0):.0f}, refused {sum(v for k, v in st.counters.items() if k.startswith('refused:'))}, "
                     f"radio_behind {st.counters.get('radio_behind', 0)}, pose->radio p50/p99 "
                     f"{f.get('pose_to_radio_p50_ms', 0):.1f}/{f.get('pose_to_radio_p99_ms', 0):.1f} ms, from the "
                     f"bridge {f.get('frame_to_radio_p50_ms', 0):.1f}/{f.get('frame_to_radio_p99_ms', 0):.1f} ms")
        rows.append([name, st.drops, st.drops - first.drops, extra])
    lines += ["", format_table(["service", "dropped", "of which in soak", "figures"], rows), ""]
    mem, total = [], 0.0
    own = [("soak (mission)", log.own)] if len(log.own) > 1 else []
    for name, points in [*sorted(log.series.items()), *own]:
        cpu = (points[-1][2] - points[0][2]) / max(points[-1][0] - points[0][0], 1e-9)
        total += cpu
        mem.append([name, f"{points[0][1]:.0f}", f"{max(p[1] for p in points):.0f}", f"{points[-1][1]:.0f}",
                    f"{mb_per_min(points):+.2f}", f"{100 * cpu:.0f}"])
    mem.append(["all", "", "", "", "", f"{100 * total:.0f}"])
    lines.append(format_table(["process", "RSS start MB", "max MB", "end MB", "growth MB/min", "CPU %"], mem))
    return "\n".join(lines)


def summary(log: SoakLog) -> dict:
    """What a test checks: each mission's verdict and each process's memory growth (MB/min)."""
    executors = [st.figures for st in log.stats.values() if st.service == "executor"]
    gateways = [st.figures for st in log.stats.values() if st.service == "gateway"]
    sim = log.sim_figures()
    return {"missions": [{"mission": m.mission, "ok": m.ok, "reason": m.reason, "contacts": m.contacts,
                          "delay_s": m.delay_s}
                         for m in log.missions],
            "flights": log.flights,
            "ticks": sum(f.get("ticks", 0.0) for f in executors),
            "missed": sum(f.get("missed", 0.0) for f in executors),
            "pose_to_cmd_p99_ms": max((f.get("pose_to_cmd_p99_ms", 0.0) for f in executors), default=0.0),
            **{f"{name}_ms": max((f.get(f"{name}_ms", 0.0) for f in gateways), default=0.0)
               for name in ("pose_to_radio_p50", "pose_to_radio_p99", "frame_to_radio_p50", "frame_to_radio_p99")},
            "growth_mb_per_min": {name: mb_per_min(points) for name, points in log.series.items()},
            "vehicles": log.vehicles, "heard_at_end": sorted(log.final), "not_at_rest": log.not_at_rest(),
            "rest_after_s": log.rest_after, "probe_ms": list(log.probe_ms), "machine": log.machine.figures(),
            "touchdown_max_mps": sim["touchdown_max_mps"], "watchdog_cuts": sim["watchdog_cuts"],
            "drops": {name: st.drops for name, st in log.stats.items()}}


def figure(log: SoakLog, out: str | Path) -> Path:
    fig, (ax1, ax2) = new_figure(2, width=6.0)
    for name, points in sorted(log.series.items()):
        ax1.plot([p[0] / 60 for p in points], [p[1] for p in points], label=name)
    ax1.set(xlabel="minutes", ylabel="resident MB", title="memory per process")
    ax1.legend(fontsize=6, ncol=2)
    for name, points in sorted(log.latency.items()):
        ax2.plot([p[0] / 60 for p in points], [p[1] for p in points], label=f"{name} p99")
    ax2.set(xlabel="minutes", ylabel="ms", title="pose-to-command latency (last 2000 ticks)")
    ax2.legend(fontsize=7)
    return save_figure(fig, out, "soak")


def run_soak(minutes: float, vehicles: int = 80, executors: int = 2, per_radio: int = 8, truth_hz: float = 50.0,
             sample_s: float = 5.0, seed: int = 0, run_dir: Path = Path("out/soak/run"),
             out: str | Path = "out", thrust_spread: float = 0.0, sim_priority: int = SIM_PRIORITY,
             trace: Path | None = None, plan_clock: bool = True, control: ControlMode = "offboard",
             radios_each: int = RADIOS_EACH) -> SoakLog:
    """Start the fleet, soak it for `minutes`, print the report and save the figure."""
    graph = load_graph(MAP)
    rng = random.Random(seed)
    spots = sorted(graph.endpoints())
    starts = {f"cf{i + 1:02d}": s for i, s in enumerate(rng.sample(spots, vehicles))}
    tasks = draw_tasks(graph, starts, rng)
    probe = cpu_probe()
    shutil.rmtree(run_dir / FAILED_PLANS, ignore_errors=True)  # (a run directory is reused: this run's only)
    with soak_fleet(MAP, tasks, run_dir, executors, per_radio, truth_hz, thrust_spread=thrust_spread,
                    sim_priority=sim_priority, plan_clock=plan_clock, control=control,
                    radios_each=radios_each) as fleet, recording(fleet, trace):
        log = asyncio.run(soak(fleet, graph, tasks, 60.0 * minutes, sample_s, seed))
    log.probe_ms = probe
    print(report(log, 60.0 * minutes))
    if kept := sorted((run_dir / FAILED_PLANS).glob("*.msgpack")):
        print(f"plan requests the planner could not plan, kept: {len(kept)} in {run_dir / FAILED_PLANS} "
              f"(`fleet replay-plan FILE` plans one again)")
    print(f"saved {figure(log, out)}")
    return log


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=float(os.environ.get("FLEET_SOAK_MINUTES", "5")))
    parser.add_argument("--vehicles", type=int, default=80)
    parser.add_argument("--executors", type=int, default=2)
    parser.add_argument("--per-radio", type=int, default=8)
    parser.add_argument("--truth-hz", type=float, default=50.0)
    parser.add_argument("--sample-s", type=float, default=5.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--thrust-spread", type=float, default=0.0, metavar="FRACTION",
                        help="the simulated units' thrust differs from the model by up to this fraction (`fleet sim`)")
    parser.add_argument("--sim-priority", type=int, default=SIM_PRIORITY, metavar="N",
                        help="the simulator raises its CPU priority by N nice levels (`fleet sim --priority`): "
                             "the world it stands for does not wait for a loaded machine")
    parser.add_argument("--run-dir", default="out/soak/run", help="logs and state of the fleet's processes")
    parser.add_argument("--summary", help="also write the verdicts and memory growth here (JSON)")
    parser.add_argument("--trace", type=Path, metavar="FILE",
                        help="record every vehicle's truth, state, events and telemetry here (`python -m bench.trace show`)")
    parser.add_argument("--no-plan-clock", dest="plan_clock", action="store_false",
                        help="the executors run plans on the wall clock (`fleet executor --no-plan-clock`): for comparison")
    parser.add_argument("--control", choices=["offboard", "onboard"], default="offboard",
                        help="every vehicle's control mode (docs/control.md, \"Onboard control mode\")")
    parser.add_argument("--radios-per-gateway", type=int, default=RADIOS_EACH, metavar="N",
                        help="gateway processes serve N radios each (`fleet gateway --radio a --radio b`)")
    args = parser.parse_args()
    log = run_soak(args.minutes, args.vehicles, args.executors, args.per_radio, args.truth_hz, args.sample_s,
                   args.seed, Path(args.run_dir), args.out, args.thrust_spread, args.sim_priority, args.trace,
                   args.plan_clock, args.control, args.radios_per_gateway)
    if args.summary:
        Path(args.summary).write_text(json.dumps(summary(log), indent=1))


if __name__ == "__main__":
    main()
