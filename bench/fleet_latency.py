"""Pose-to-command latency and achieved control rate of the executor service over zenoh, with 8, 32
and 80 vehicles (issue 6).

An in-process router; executor processes (`fleet executor`) as in the deployment; this process plays
motion capture: it publishes every vehicle's pose at 100 Hz (moving along its plan, a long drive at
0.1 m/s) and listens to the commands. Latency of a command = its arrival here - the capture time of
the newest pose of that vehicle published before the executor's tick (so it includes the wait for
the next 100 Hz tick, as on a real vehicle). Run: `python -m bench.fleet_latency`.
"""

from __future__ import annotations

import asyncio
import bisect
import os
import subprocess
import sys
import time
from collections import defaultdict

import numpy as np

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.bus.keys import Keys
from common.bus.liveliness import watch_alive
from common.bus.messages import Cmd, PlanStep, Pose, VehiclePlan
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import InProcessRouter, ZenohConfig, open_session
from common.domain.planfile import PlanModel
from common.domain.vehicle_model import VehicleModel

KEYS = Keys("bench")
SPEED = 0.1


def drive_plan(vid: str, y: float, t0: float) -> VehiclePlan:
    """A 100 m straight drive at 0.1 m/s: the executor drives for the whole run."""
    m = VehicleModel()
    model = PlanModel(**{f: getattr(m, f) for f in m.__struct_fields__})
    steps = [PlanStep(node="a", t=0.0, pos=(0.0, y, 0.0), kind="land"),
             PlanStep(node="b", t=100.0 / SPEED, pos=(100.0, y, 0.0), kind="land", edge="drive")]
    return VehiclePlan(vid=vid, mission="bench", map="bench", steps=steps, model=model, t0=t0)


async def measure(endpoint: str, n: int, executors: int, seconds: float) -> dict[str, float]:
    session = open_session(ZenohConfig.client(endpoint))
    env = {**os.environ, "FLEET_ZENOH_CONNECT": endpoint, "FLEET_NAME": KEYS.fleet}
    procs = [subprocess.Popen([sys.executable, "-m", "services.cli", "executor"], env={**env, "FLEET_INSTANCE": f"ex{i}"},
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for i in range(executors)]
    try:
        alive = await watch_alive(session, KEYS, "executor")
        await alive.wait_until(lambda s: len(s) >= executors, timeout=30)
        alive.close()
        vids = [f"v{i:03d}" for i in range(n)]
        pose_times: dict[str, list[float]] = defaultdict(list)
        arrivals: list[tuple[str, float, float]] = []  # vid, cmd tick time, arrival
        sub = subscribe(session, KEYS.all_vehicles("cmd"), Cmd,
                        lambda c, _k: arrivals.append((c.vid, c.t, time.time())), maxlen=100_000)
        pubs = {v: Publisher(session, KEYS.vehicle(v, "pose"), Pose) for v in vids}
        t0 = time.time() + 1.0
        for i, v in enumerate(vids):
            Publisher(session, KEYS.vehicle(v, "plan"), VehiclePlan).put(drive_plan(v, 0.5 * i, t0))
        start = time.time()
        next_tick = time.monotonic()
        seq = 0
        while time.time() - start < seconds + 1.0:
            now = time.time()
            x = max(0.0, now - t0) * SPEED
            for i, v in enumerate(vids):
                pubs[v].put(Pose(vid=v, t=now, x=x, y=0.5 * i, z=0.0, yaw=0.0, seq=seq))
                pose_times[v].append(now)
            seq += 1
            next_tick += 0.01
            await asyncio.sleep(max(0.0, next_tick - time.monotonic()))
        sub.close()
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(timeout=10)
        session.close()
    window = [(v, t, r) for v, t, r in arrivals if r - start > 1.0]  # after the warm-up second
    lat = []
    for v, t, r in window:
        times = pose_times[v]
        k = bisect.bisect_right(times, t) - 1
        if k >= 0:
            lat.append(r - times[k])
    per_vehicle = len(window) / max(1, n) / seconds
    lat_ms = 1e3 * np.array(lat)
    return {"n": n, "executors": executors, "rate_hz": per_vehicle, "p50_ms": float(np.percentile(lat_ms, 50)),
            "p99_ms": float(np.percentile(lat_ms, 99)), "max_ms": float(lat_ms.max())}


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--vehicles", default="8,32,80")
    parser.add_argument("--executors", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    rows = []
    with InProcessRouter() as router:
        for n in (int(v) for v in args.vehicles.split(",")):
            r = asyncio.run(measure(router.endpoint, n, args.executors, args.seconds))
            rows.append(r)
            print(f"{n} vehicles: {r}", flush=True)
    print(format_table(["vehicles", "executors", "cmd rate Hz/vehicle", "latency p50 ms", "p99 ms", "max ms"],
                       [[r["n"], r["executors"], f"{r['rate_hz']:.1f}", f"{r['p50_ms']:.1f}", f"{r['p99_ms']:.1f}",
                         f"{r['max_ms']:.1f}"] for r in rows]))
    fig, (ax1, ax2) = new_figure(2)
    ns = [r["n"] for r in rows]
    ax1.plot(ns, [r["rate_hz"] for r in rows], "o-")
    ax1.axhline(100, ls="--", c="0.5")
    ax1.set(xlabel="vehicles", ylabel="commands per vehicle per s", title="achieved control rate (target 100 Hz)")
    ax2.plot(ns, [r["p50_ms"] for r in rows], "o-", label="p50")
    ax2.plot(ns, [r["p99_ms"] for r in rows], "s-", label="p99")
    ax2.set(xlabel="vehicles", ylabel="ms", title="pose-to-command latency")
    ax2.legend()
    print(f"saved {save_figure(fig, args.out, 'fleet_latency')}")


if __name__ == "__main__":
    main()
