"""Cost of one control tick (pose fusion + state machine + controller) of `VehicleController`.

Flies the town-like reference path (tests/support/closed_loop.py) once in the simulator with
noisy 100 Hz mocap, timing `on_pose` + `tick` of every tick in thread CPU time (the simulator is not
timed), and prints per mode class the mean / median / 99th-percentile cost and how many vehicles
one core runs at 100 Hz (1 s / (100 x mean cost)); also the mission's tracking figures. Saves a PNG.

One vehicle alone: its pose is fused by itself, so it pays the Kalman bank's numpy step (tens of
us) that an executor shares among every vehicle of a frame (`fuse_poses`). What an executor costs
per vehicle, whole process, is `bench.fleet_latency`'s figure (issue 15's target: 200 a core).

    .venv/bin/python bench/control_tick.py [--out out/] [--repeat 3]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from common.bus.messages import Pose  # noqa: E402
from common.domain.vehicle_model import VehicleModel  # noqa: E402
from common.flight.modes import AIRBORNE, Mode  # noqa: E402
from services.executor.vehicle_controller import VehicleController  # noqa: E402
from services.sim.crazyflie.physics import SimFlyingCar  # noqa: E402
from tests.support.closed_loop import Mocap, MocapNoise, plan_for, reference_steps  # noqa: E402

RATE_HZ = 100.0


def mode_class(mode: Mode) -> str:
    if mode == Mode.DRIVING:
        return "driving"
    return "flying" if mode in AIRBORNE else "parked/done"


def fly_once(seed: int) -> tuple[list[tuple[float, str, float]], list[float], list[float]]:
    """One mission: (t, mode class, tick cost in s) per tick, and ground / air tracking errors (m)."""
    model = VehicleModel()
    steps = reference_steps(model)
    sim = SimFlyingCar("cf1", model, pos=steps[0].pos)
    ctrl = VehicleController("cf1", model)
    ctrl.on_pose(Pose(vid="cf1", t=0.0, x=sim.x, y=sim.y, z=sim.z, yaw=sim.yaw))
    ctrl.load(plan_for("cf1", steps, model, t0=0.5))
    mocap = Mocap(MocapNoise(), seed=seed)
    costs: list[tuple[float, str, float]] = []
    ground: list[float] = []
    air: list[float] = []
    while sim.t < 0.5 + steps[-1].t + 1.0:
        now = sim.t
        pose = mocap.observe(sim.truth())
        start = time.thread_time_ns()
        if pose is not None:
            ctrl.on_pose(pose)
        cmd = ctrl.tick(now)
        cost = (time.thread_time_ns() - start) * 1e-9
        costs.append((now, mode_class(ctrl.mode), cost))
        ref = ctrl.reference(now)
        if ref is not None and ctrl.mode == Mode.DRIVING:
            ground.append(math.hypot(sim.x - ref.x, sim.y - ref.y))
        elif ref is not None and ctrl.mode in AIRBORNE:
            air.append(math.dist((sim.x, sim.y, sim.z), (ref.x, ref.y, ref.z)))
        sim.apply(cmd.setpoint, now)
        sim.step(1.0 / RATE_HZ)
    return costs, ground, air


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("out"), help="directory for the PNG (default out/)")
    parser.add_argument("--repeat", type=int, default=3, help="missions to fly (default 3)")
    args = parser.parse_args()
    costs: list[tuple[float, str, float]] = []
    ground: list[float] = []
    air: list[float] = []
    for seed in range(args.repeat):
        c, g, a = fly_once(seed)
        costs += c
        ground += g
        air += a
    print(f"control tick cost (on_pose + tick), thread CPU time, {args.repeat} missions, {len(costs)} ticks")
    print(f"{'mode':<12} {'ticks':>6} {'mean us':>8} {'p50 us':>8} {'p99 us':>8} {'vehicles/core @100 Hz':>22}")
    classes = ("driving", "flying", "parked/done")
    means = {}
    for name in classes:
        values = sorted(cost for _, cls, cost in costs if cls == name)
        mean = statistics.fmean(values)
        means[name] = mean
        p99 = values[min(len(values) - 1, int(0.99 * len(values)))]
        print(f"{name:<12} {len(values):>6} {mean * 1e6:>8.1f} {statistics.median(values) * 1e6:>8.1f} "
              f"{p99 * 1e6:>8.1f} {1.0 / (RATE_HZ * mean):>22.0f}")
    worst = max(means["driving"], means["flying"])
    print(f"worst moving mode: {worst * 1e6:.1f} us per tick -> {1.0 / (RATE_HZ * worst):.0f} vehicles per core "
          "at 100 Hz, each fusing its poses alone (an executor's cost per vehicle: bench.fleet_latency)")
    rms = lambda v: math.sqrt(sum(x * x for x in v) / len(v))  # noqa: E731
    print(f"tracking RMS: ground {rms(ground) * 100:.2f} cm, air {rms(air) * 100:.2f} cm "
          f"(max {max(ground) * 100:.1f} / {max(air) * 100:.1f} cm)")

    args.out.mkdir(parents=True, exist_ok=True)
    fig, (ax_t, ax_h) = plt.subplots(1, 2, figsize=(11, 4))
    colours = {"driving": "tab:green", "flying": "tab:blue", "parked/done": "tab:gray"}
    first = [(t, cls, cost) for t, cls, cost in costs[: len(costs) // args.repeat]]
    for name in classes:
        pts = [(t, cost * 1e6) for t, cls, cost in first if cls == name]
        ax_t.scatter([p[0] for p in pts], [p[1] for p in pts], s=2, color=colours[name], label=name)
        ax_h.hist([cost * 1e6 for _, cls, cost in costs if cls == name], bins=60, alpha=0.6,
                  color=colours[name], label=f"{name}: {means[name] * 1e6:.0f} us")
    ax_t.set(xlabel="mission time (s)", ylabel="tick cost (us)", title="cost along one mission")
    ax_h.axvline(1e6 / (RATE_HZ * 80), color="tab:red", linestyle="--", label="80 vehicles/core @100 Hz")
    ax_h.set(xlabel="tick cost (us)", ylabel="ticks", title="distribution")
    ax_h.set_xlim(0, 1e6 / (RATE_HZ * 80) * 1.5)
    ax_t.legend(markerscale=5)
    ax_h.legend()
    fig.tight_layout()
    path = args.out / "control_tick.png"
    fig.savefig(path, dpi=120)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
