"""Paper 000 Table II in the simulator: flight and driving endurance and power, measured.

One simulated flying car (`services/sim/crazyflie/physics.py`: its battery, power per mode and
physics) is flown by the executor's control stack (`VehicleController`: pure pursuit on the ground,
LQR in the air, noisy 100 Hz motion capture) without zenoh, faster than real time, as
`tests/support/closed_loop.py` does, from a full battery round a circuit at the paper's speeds
(0.3 m/s flying at 0.5 m, 0.1 m/s driving) until the executor's low-battery rule fires with no
reserve kept (`FaultMonitor.low_battery`: the voltage under load below 3.3 V for 1 s, or the charge
the executor has counted reaching the capacity). Measured per run: run time, distance flown or
driven (ground truth), average electrical power (the simulator's charge drawn x nominal voltage /
time, eq. 4-5), its speed and cost of transport P / (m g v) (§VII-A), and which rule ended it.

    python -m bench.endurance [--mode fly|drive|both] [--out out/endurance.json]

`make results` (`bench.results`) runs it and writes the Table II section of docs/results.md;
`python -m bench.results --only table2` reruns just that section.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import msgspec

from common.bus.messages import PlanStep, Pose, Telemetry
from common.domain.mapfile import load_map
from common.domain.vehicle_model import EdgeKind, NodeKind, VehicleModel
from common.flight.modes import AIRBORNE
from services.executor.vehicle_controller import VehicleController
from services.sim.crazyflie.physics import PhysicsParams, SimFlyingCar
from tests.support.closed_loop import Mocap, MocapNoise, plan_for

Run = Literal["fly", "drive"]
DT = 0.01
"""Control period (s): the executor's 100 Hz."""
ALTITUDE = 0.5
RADIUS = {"fly": 1.0, "drive": 0.5}
"""Circuit radius (m): a 24-gon, flown at 0.5 m or driven on the floor."""
SIDES = 24
START = 0.5
"""Mission start on the simulator's clock (s; a plan's t0 of 0 means not started)."""
BUDGET_S = {"fly": 9 * 60.0, "drive": 90 * 60.0}
"""Laps planned (s): longer than any battery lasts, so the battery ends every run."""


def circuit_plan(model: VehicleModel, run: Run, budget_s: float) -> list[PlanStep]:
    """Park at the circuit's first corner, wait 1 s; then (flying) take off to 0.5 m and fly laps of
    a 24-gon at the fly speed, or (driving) drive laps at the drive speed, for `budget_s`."""
    r = RADIUS[run]
    corners = [(r * math.cos(2 * math.pi * k / SIDES), r * math.sin(2 * math.pi * k / SIDES)) for k in range(SIDES)]
    z = ALTITUDE if run == "fly" else 0.0
    edge: EdgeKind = "fly" if run == "fly" else "drive"
    kind: NodeKind = "air" if run == "fly" else "waypoint"
    x0, y0 = corners[0]
    steps = [PlanStep(node="p0", t=0.0, pos=(x0, y0, 0.0), kind="land"),
             PlanStep(node="p0", t=1.0, pos=(x0, y0, 0.0), kind="land")]
    if run == "fly":
        steps.append(PlanStep(node="a0", t=1.0 + ALTITUDE / model.speed.takeoff, pos=(x0, y0, z), kind="air",
                              edge="takeoff"))
    k = 0
    while steps[-1].t < budget_s:
        k += 1
        x, y = corners[k % SIDES]
        prev = steps[-1].pos
        t = steps[-1].t + math.dist(prev, (x, y, z)) / model.edge_speed(edge)
        steps.append(PlanStep(node=f"c{k % SIDES}", t=round(t, 6), pos=(x, y, z), kind=kind, edge=edge))
    return steps


def measure(run: Run, model: VehicleModel | None = None, seed: int = 0,
            log: Callable[[str], None] | None = None) -> dict:
    """Fly or drive one battery empty in the simulator (see the module doc); the measured row."""
    base = model or VehicleModel()
    # no reserve: the run measures the battery, not the fleet's planning margin (paper 000 §V-C C_low)
    model = msgspec.structs.replace(base, reserve_ah=0.0, margin=0.0)
    steps = circuit_plan(model, run, BUDGET_S[run])
    sim = SimFlyingCar("cf1", model, PhysicsParams(), pos=steps[0].pos)
    ctrl = VehicleController("cf1", model)
    mocap = Mocap(MocapNoise(), seed=seed)
    ctrl.on_pose(Pose(vid="cf1", t=0.0, x=sim.x, y=sim.y, z=sim.z, yaw=sim.yaw))
    ctrl.load(plan_for("cf1", steps, model, t0=START))
    distance = cruise_t = cruise_charge = 0.0
    vmin = math.inf
    ended = ""
    k = 0
    wall = time.perf_counter()
    while sim.t < BUDGET_S[run]:
        now = sim.t
        truth = sim.truth()
        pose = mocap.observe(truth)
        if pose is not None:
            ctrl.on_pose(pose)
        battery = sim.battery
        if k % 10 == 0:  # telemetry at 10 Hz, as the gateway reads the firmware's log block
            ctrl.on_telemetry(Telemetry(vid="cf1", t=now, gateway="sim", vbat=battery.vbat, link_quality=1.0,
                                        sent=k, dropped=0, cmd_rate_hz=1.0 / DT), now)
        if ctrl.faults.low_battery(ctrl.charge_used_ah, now):
            ended = "voltage" if battery.vbat < ctrl.params.faults.vbat_low else "charge counted"
            break
        cmd = ctrl.tick(now)
        sim.apply(cmd.setpoint, now)
        before, x, y, z = sim.charge_used_ah, sim.x, sim.y, sim.z
        sim.step(DT)
        moved = math.dist((x, y, z), (sim.x, sim.y, sim.z))
        distance += moved
        cruising = ctrl.mode in AIRBORNE if run == "fly" else moved > 0.0
        if cruising:
            cruise_t += DT
            cruise_charge += sim.charge_used_ah - before
        vmin = min(vmin, sim.battery.vbat)
        k += 1
        if log and k % 30000 == 0:
            log(f"  {run}: {sim.t / 60:.1f} min simulated, {sim.battery.soc:.0%} left, {sim.battery.vbat:.2f} V")
    t = sim.t
    energy = sim.charge_used_ah * model.voltage * 3600.0
    power = energy / t
    speed = distance / t
    return {
        "run": run, "run_min": t / 60.0, "distance_m": distance, "speed": speed, "power_w": power,
        "cot": model.cost_of_transport(power, speed),
        "cruise_power_w": cruise_charge * model.voltage * 3600.0 / cruise_t if cruise_t else math.nan,
        "energy_j": energy, "soc_left": sim.battery.soc, "vbat_min": vmin, "ended": ended or "budget",
        "wall_s": time.perf_counter() - wall,
    }


def measure_all(model: VehicleModel, log: Callable[[str], None] | None = None) -> dict:
    """Both runs with `model` (the shipped maps' vehicle), and the battery's parameters."""
    p = PhysicsParams()
    return {"model": msgspec.to_builtins(model), "r_internal": p.r_internal,
            "vbat_low": VehicleController("cf1", model).params.faults.vbat_low,
            "fly": measure("fly", model, log=log), "drive": measure("drive", model, log=log)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench.endurance", description=__doc__.splitlines()[0])
    parser.add_argument("--mode", choices=["fly", "drive", "both"], default="both")
    parser.add_argument("--out", default="out/endurance.json")
    args = parser.parse_args(argv)

    def log(s: str) -> None:
        print(s, file=sys.stderr, flush=True)

    runs: list[Run] = ["fly", "drive"] if args.mode == "both" else [args.mode]
    model = load_map("fig6").vehicle
    out = {run: measure(run, model, log=log) for run in runs}
    print("| run | run time min | distance m | speed m/s | ave power W | cruise power W | COT | ended by | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for run, r in out.items():
        print(f"| {run} | {r['run_min']:.2f} | {r['distance_m']:.0f} | {r['speed']:.3f} | {r['power_w']:.2f} | "
              f"{r['cruise_power_w']:.2f} | {r['cot']:.1f} | {r['ended']} | {r['wall_s']:.0f} |")
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
