"""Lifelong operation through faults (issue 16): N simulated vehicles on city934 take random tasks
for M minutes (`fleet mission run --lifelong`: every vehicle that arrives gets a random free parking
spot, planned against the others' paths; a vehicle whose goal a fault put out of reach stops short
and gets a new one) while a fault is injected every `--fault-every` seconds
from another process with `fleet sim fault` (in turn: battery below reserve, a 1.5 s radio blackout,
a 2 s motion-capture loss), on a vehicle in the air if there is one, else one driving. The fleet
plans the others on around each faulted vehicle. Printed: tasks done and per minute, the faults
and what the fleet did, replanning times, contacts in ground truth; `lifelong.png` plots tasks done
over time.

    python -m bench.lifelong --vehicles 16 --minutes 5 --fault-every 60
"""

from __future__ import annotations

import asyncio
import os
import random
import subprocess
import sys
import time
from pathlib import Path

from bench.soak import MAP, draw_tasks, soak_fleet
from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.bus.messages import VehicleState
from common.bus.pubsub import subscribe
from common.bus.session import open_session
from common.deploy.local import LocalFleet
from common.domain.vehicle_model import VehicleModel
from services.mission.client import MissionTiming
from services.mission.runner import MissionRunner, MissionSpec
from services.planner.maps.loading import load_graph

REPO = Path(__file__).resolve().parents[1]
MODEL = VehicleModel()
FAULTS = (("battery", ["--charge-used", f"{MODEL.capacity_ah - 0.5 * MODEL.reserve_ah:.4f}"]),
          ("radio_blackout", ["--duration", "1.5"]),
          ("mocap_dropout", ["--duration", "2.0"]))


def sim_fault(fleet: LocalFleet, vid: str, kind: str, extra: list[str]) -> str:
    """`fleet sim fault` from another process, as an operator would; its output."""
    env = {**os.environ, **fleet.credentials.env("mission")}
    proc = subprocess.run([sys.executable, "-m", "services.cli", "sim", "fault", vid, kind, *extra,
                           "--connect", fleet.endpoint, "--fleet", fleet.keys.fleet],
                          cwd=REPO, capture_output=True, text=True, timeout=60, env=env)
    return (proc.stdout + proc.stderr).strip().splitlines()[-1] if proc.stdout + proc.stderr else f"exit {proc.returncode}"


async def lifelong(fleet: LocalFleet, spec: MissionSpec, fault_every: float, seed: int) -> tuple[MissionRunner, list]:
    states: dict[str, VehicleState] = {}
    session = open_session(fleet.client_config())
    subscribe(session, fleet.keys.all_vehicles("state"), VehicleState, lambda s, _k: states.__setitem__(s.vid, s))
    runner = MissionRunner(spec, fleet.client_config(), fleet.keys, progress=False)
    mission = asyncio.create_task(runner.run())
    rng = random.Random(seed)
    injected: list[tuple[float, str, str, str]] = []
    done: list[tuple[float, int]] = []
    try:
        while runner.t0 is None and not mission.done():
            await asyncio.sleep(0.2)
        next_fault = (runner.t0 or time.time()) + fault_every
        while not mission.done():
            await asyncio.sleep(0.5)
            now = time.time()
            done.append((now - (runner.t0 or now), runner.tasks_done))
            if now < next_fault or now - (runner.t0 or now) > spec.lifelong_s:
                continue
            live = [v for v, s in states.items() if v not in runner.left and s.mission == spec.mission]
            flying = [v for v in live if states[v].mode == "flying"]
            driving = [v for v in live if states[v].mode == "driving"]
            if not flying and not driving:
                continue
            vid = rng.choice(flying or driving)
            kind, extra = FAULTS[len(injected) % len(FAULTS)]
            said = await asyncio.to_thread(sim_fault, fleet, vid, kind, extra)
            injected.append((now - (runner.t0 or now), vid, f"{kind} ({states[vid].mode})", said))
            next_fault = now + fault_every
        await mission
    finally:
        session.close()
    return runner, [injected, done]


def contact_episodes(runner: MissionRunner) -> list[list[object]]:
    """Each pair of bodies that touched in ground truth: from and to (mission time), the deepest
    overlap and how many samples."""
    episodes: dict[tuple[str, str], list[float]] = {}
    t0 = runner.t0 or 0.0
    for t, a, b, gap in runner.sep.contacts if runner.sep is not None else []:
        e = episodes.setdefault(tuple(sorted((a, b))), [t - t0, t - t0, gap, 0])
        e[1], e[2], e[3] = t - t0, min(e[2], gap), e[3] + 1
    return [[f"{a}-{b}", f"{e[0]:.1f}", f"{e[1]:.1f}", f"{100 * e[2]:.1f}", e[3]] for (a, b), e in episodes.items()]


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--vehicles", type=int, default=16)
    parser.add_argument("--minutes", type=float, default=5.0)
    parser.add_argument("--fault-every", type=float, default=60.0, help="s between injected faults")
    parser.add_argument("--executors", type=int, default=2)
    parser.add_argument("--per-radio", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--run-dir", default="out/lifelong/run")
    args = parser.parse_args()
    graph = load_graph(MAP)
    rng = random.Random(args.seed)
    starts = {f"cf{i + 1:02d}": s for i, s in enumerate(rng.sample(sorted(graph.endpoints()), args.vehicles))}
    tasks = draw_tasks(graph, starts, rng)
    spec = MissionSpec(map=MAP, tasks=tasks, planner="sipp", time_limit=60.0, slack_s=60.0,
                       timing=MissionTiming(ready_timeout_s=60.0), lifelong_s=60.0 * args.minutes, seed=args.seed)
    with soak_fleet(MAP, tasks, Path(args.run_dir), args.executors, args.per_radio, 50.0, fleet="lifelong") as fleet:
        runner, (injected, done) = asyncio.run(lifelong(fleet, spec, args.fault_every, args.seed))
    result = runner.result
    assert result is not None
    print(result.summary())
    print(format_table(["pair", "from s", "to s", "deepest cm", "samples"], contact_episodes(runner)))
    print(format_table(["t s", "vehicle", "fault", "fleet sim fault said"],
                       [[f"{t:.0f}", v, k, said] for t, v, k, said in injected]))
    left = dict(runner.left)
    ms = sorted(1e3 * t for t in result.replans)
    minutes = result.duration_s / 60
    print(format_table(
        ["vehicles", "minutes", "tasks done", "tasks per minute", "faults", "vehicles left", "stopped short",
         "others not arrived", "replans", "replan ms median", "max", "contacts"],
        [[args.vehicles, f"{minutes:.1f}", result.tasks_done, f"{result.tasks_done / minutes:.1f}", len(injected),
          len(left), len(runner.stranded), sum(1 for v, r in result.vehicles.items() if v not in left and not r.arrived),
          len(ms),
          f"{ms[len(ms) // 2] if ms else 0:.0f}", f"{ms[-1] if ms else 0:.0f}", result.contacts]]))
    fig, (ax,) = new_figure()
    ax.plot([t / 60 for t, _ in done], [n for _, n in done])
    for fault in injected:
        ax.axvline(fault[0] / 60, color="red", alpha=0.4)
    ax.set(xlabel="minutes", ylabel="tasks done", title=f"lifelong, {args.vehicles} vehicles on {MAP} (faults in red)")
    print(f"saved {save_figure(fig, args.out, 'lifelong')}")


if __name__ == "__main__":
    main()
