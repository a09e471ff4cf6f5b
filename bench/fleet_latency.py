"""The executor's whole-process cost per vehicle and its pose-to-command latency over zenoh, for
8, 32, 80 and 200 vehicles (issue 15).

A router process (`fleet router`: not in this process, which runs Python besides, docs/bus.md);
executor processes (`fleet executor`) as in the deployment; this process
plays the motion capture and the gateways: it publishes one `PoseFrame` of every vehicle at 100 Hz
(each driving its plan, a 100 m road at 0.1 m/s, or hovering at 0.5 m with `--fly`), each
vehicle's telemetry at 5 Hz naming one of `--gateways` gateways, and receives the executors'
command batches (`gateway/<g>/cmd`). Measured after a warm-up:

- latency: a batch's arrival here - the capture time of the frame it fused (`CmdBatch.pose_t`):
  everything between the motion capture and the gateway's radio but the radio itself;
- commands per vehicle per second (the control rate achieved);
- the executors' CPU time from /proc (user + system, every thread: decoding, the event loop,
  publishing, the controllers), as % of one core, per vehicle-cycle in us (per command sent: a
  saturated executor runs fewer cycles than 100 a second, and its cost per cycle is what it
  spent on those), and as vehicles one core runs at 100 Hz.

    python -m bench.fleet_latency [--vehicles 8,32,80,200] [--executors 1] [--seconds 10] [--fly]
                                  [--no-plan-clock] [--repeat 1]

`--repeat K`: K runs of each fleet size, one after another, each with its own executors; the table
gives the run of median cost (of an even number, the costlier of the middle two) and the range
over the runs. On this 2-core virtual machine the same run's executor cost varies by +-10-15 %
from run to run (the host's load), so one run alone says little about a change of a few per cent.

`--no-plan-clock`: the executors run the plans on the wall clock (`fleet executor --no-plan-clock`),
to weigh what the plan's clock costs.
"""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.machine_cpu import task_cpu_seconds
from bench.tables import bench_parser, format_table, new_figure, plot_series, save_figure
from common.bus.keys import Keys
from common.bus.liveliness import watch_alive
from common.bus.messages import CmdBatch, FramePose, PlanStep, PoseFrame, Telemetry, VehiclePlan
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import ZenohConfig, open_session
from common.deploy.local import router_process
from common.domain.planfile import PlanModel
from common.domain.vehicle_model import VehicleModel

KEYS = Keys("bench")
SPEED = 0.1
RATE_HZ = 100.0
GATEWAYS = 4


def bench_plan(vid: str, y: float, t0: float, fly: bool) -> VehiclePlan:
    """A 100 m straight drive at 0.1 m/s, or a take-off to 0.5 m and a long hover: the executor
    controls the vehicle for the whole run."""
    m = VehicleModel()
    model = PlanModel(**{f: getattr(m, f) for f in m.__struct_fields__})
    if fly:
        steps = [PlanStep(node="a", t=0.0, pos=(0.0, y, 0.0), kind="helipad"),
                 PlanStep(node="h", t=1.0, pos=(0.0, y, 0.5), kind="air", edge="takeoff"),
                 PlanStep(node="h", t=1000.0, pos=(0.0, y, 0.5), kind="air")]
    else:
        steps = [PlanStep(node="a", t=0.0, pos=(0.0, y, 0.0), kind="land"),
                 PlanStep(node="b", t=100.0 / SPEED, pos=(100.0, y, 0.0), kind="land", edge="drive")]
    return VehiclePlan(vid=vid, mission="bench", map="bench", steps=steps, model=model, t0=t0)


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process `pid` (every thread), s."""
    return task_cpu_seconds(Path(f"/proc/{pid}/stat").read_text())


def where(t: float, t0: float, y: float, fly: bool) -> tuple[float, float, float]:
    """Where the vehicle is at `t` if it follows its plan exactly."""
    rel = max(0.0, t - t0)
    if fly:
        return 0.0, y, min(rel, 1.0) * 0.5
    return rel * SPEED, y, 0.0


async def measure(endpoint: str, n: int, executors: int, seconds: float, fly: bool,
                  plan_clock: bool = True) -> dict[str, float]:
    session = open_session(ZenohConfig.client(endpoint))
    env = {**os.environ, "FLEET_ZENOH_CONNECT": endpoint, "FLEET_NAME": KEYS.fleet}
    argv = [sys.executable, "-m", "services.cli", "executor", *([] if plan_clock else ["--no-plan-clock"])]
    procs = [subprocess.Popen(argv, env={**env, "FLEET_INSTANCE": f"ex{i}"},
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for i in range(executors)]
    try:
        alive = await watch_alive(session, KEYS, "executor")
        await alive.wait_until(lambda s: len(s) >= executors, timeout=30)
        alive.close()
        vids = [f"v{i:03d}" for i in range(n)]
        gateway = {v: f"g{i % GATEWAYS}" for i, v in enumerate(vids)}
        arrivals: list[tuple[float, float, int]] = []  # arrival, frame capture, commands
        subs = [subscribe(session, KEYS.gateway_cmd(g), CmdBatch,
                          lambda b, _k: arrivals.append((time.time(), b.pose_t, len(b.cmds))), maxlen=100_000)
                for g in sorted(set(gateway.values()))]
        frames = Publisher(session, KEYS.mocap_frame, PoseFrame)
        telemetry = {v: Publisher(session, KEYS.vehicle(v, "telemetry"), Telemetry) for v in vids}
        t0 = time.time() + 1.0
        plans = [(Publisher(session, KEYS.vehicle(v, "plan"), VehiclePlan), bench_plan(v, 0.5 * i, t0, fly))
                 for i, v in enumerate(vids)]
        start = time.time()
        next_tick = time.monotonic()
        seq = 0
        cpu0: list[float] | None = None
        measured_from = start + 2.0  # after the warm-up
        while time.time() - start < seconds + 2.0:
            now = time.time()
            seq += 1
            frames.put(PoseFrame(t=now, seq=seq, poses=[FramePose(v, *where(now, t0, 0.5 * i, fly), 0.0)
                                                           for i, v in enumerate(vids)]))
            # the plans again every 0.5 s of the warm-up: an executor alive may not have subscribed
            # yet, and a plan lost left its vehicle uncommanded (runs at 65, 46 and 0 commands a
            # vehicle a second, 2026-12-07); the same plan again changes nothing
            if now < measured_from and seq % 50 == 1:
                for publisher, plan in plans:
                    publisher.put(plan)
            if seq % 20 == 0:
                for v in vids:
                    telemetry[v].put(Telemetry(vid=v, t=now, gateway=gateway[v], vbat=4.0, link_quality=1.0,
                                               sent=0, dropped=0, cmd_rate_hz=100.0, owner=""))
            if cpu0 is None and now >= measured_from:
                cpu0 = [cpu_seconds(p.pid) for p in procs]
            next_tick += 1.0 / RATE_HZ
            await asyncio.sleep(max(0.0, next_tick - time.monotonic()))
        end = time.time()
        cpu1 = [cpu_seconds(p.pid) for p in procs]
        for sub in subs:
            sub.close()
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(timeout=10)
        session.close()
    assert cpu0 is not None
    window = [(a, t, c) for a, t, c in arrivals if a >= measured_from]
    span = end - measured_from
    lat_ms = 1e3 * np.array([a - t for a, t, _c in window if t > 0.0])
    cpu = sum(cpu1) - sum(cpu0)
    commands = sum(c for _a, _t, c in window)
    per_cycle_us = 1e6 * cpu / max(commands, 1)  # per cycle achieved: a saturated executor runs fewer than 100 a second
    return {"n": n, "executors": executors, "rate_hz": commands / n / span,
            "p50_ms": float(np.percentile(lat_ms, 50)), "p99_ms": float(np.percentile(lat_ms, 99)),
            "max_ms": float(lat_ms.max()), "cpu_pct": 100.0 * cpu / span, "us_per_cycle": per_cycle_us,
            "per_core": 1e6 / (RATE_HZ * per_cycle_us)}


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--vehicles", default="8,32,80,200")
    parser.add_argument("--executors", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--fly", action="store_true", help="hover instead of driving")
    parser.add_argument("--no-plan-clock", dest="plan_clock", action="store_false",
                        help="the executors run plans on the wall clock")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each fleet size (the median's is shown)")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as run_dir, router_process(Path(run_dir)) as endpoint:
        for n in (int(v) for v in args.vehicles.split(",")):
            runs = []
            for _ in range(max(args.repeat, 1)):
                r = asyncio.run(measure(endpoint, n, args.executors, args.seconds, args.fly, args.plan_clock))
                runs.append(r)
                print(f"{n} vehicles: {r}", flush=True)
            runs.sort(key=lambda r: r["per_core"])
            rows.append(runs[(len(runs) - 1) // 2] | {"range": (runs[0]["per_core"], runs[-1]["per_core"])})
    print(format_table(["vehicles", "executors", "cmd Hz/vehicle", "latency p50 ms", "p99 ms", "max ms",
                        "executor CPU %", "us/vehicle-cycle", "vehicles/core @100 Hz", "range"],
                       [[r["n"], r["executors"], f"{r['rate_hz']:.1f}", f"{r['p50_ms']:.1f}", f"{r['p99_ms']:.1f}",
                         f"{r['max_ms']:.1f}", f"{r['cpu_pct']:.0f}", f"{r['us_per_cycle']:.0f}",
                         f"{r['per_core']:.0f}", "{:.0f}-{:.0f}".format(*r["range"])] for r in rows]))
    print("latency: frame capture -> the executor's command batch received by a gateway's subscriber "
          "(this process), the radio excluded; CPU: the executor processes' user + system time"
          + (f"; each row the run of median cost of {args.repeat}, range: vehicles/core over them"
             if args.repeat > 1 else ""))
    fig, (ax1, ax2) = new_figure(2)
    ns = [r["n"] for r in rows]
    ax1.plot(ns, [r["per_core"] for r in rows], "o-")
    ax1.axhline(200, ls="--", c="0.5")
    ax1.set(xlabel="vehicles", ylabel="vehicles per core at 100 Hz", title="executor whole-process cost")
    plot_series(ax2, ns, {"p50": [r["p50_ms"] for r in rows], "p99": [r["p99_ms"] for r in rows]},
                xlabel="vehicles", ylabel="ms", title="frame capture -> command batch")
    print(f"saved {save_figure(fig, args.out, 'fleet_latency')}")


if __name__ == "__main__":
    main()
