"""The simulator's cost per vehicle (issue 15): what one `fleet sim` process spends to advance each
simulated Crazyflie (physics sub-steps, the firmware's 100 Hz tasks: estimator, supervisor,
commander, wheel app, battery, log blocks) and read its ground truth, per 10 ms frame, as its
publishing loop does (`services/sim/crazyflie/service.py`), radio and bus excluded.

Three fleets: parked (on the ground, motors and wheels stopped: most vehicles between missions and
while they wait), driving (each receives a wheel command every frame on its app channel, as the
gateway sends them) and flying (each receives an attitude setpoint and its external position every
frame, as in offboard flight: climbing at 1.05 times its hover thrust). Prints us per vehicle-frame
and how many vehicles one core simulates in real time at 100 Hz; saves a PNG.

    python -m bench.sim_cost [--vehicles 32] [--seconds 10]
"""

from __future__ import annotations

import time

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.bus.messages import FlightSetpoint
from common.crazyflie import crtp
from common.crazyflie.thrust import hover_command
from common.deploy.radios import LinkModel
from services.sim.crazyflie.endpoint import SimCrazyflie
from services.sim.crazyflie.physics import SimFlyingCar
from services.sim.crazyflie.radio import SimRadio

FRAME_S = 0.01
BOOT_S = 3.0
"""Simulated seconds run before timing: the firmware boots and arms."""


def fleet(n: int) -> list[SimCrazyflie]:
    radio = SimRadio("r", LinkModel(loss=0.0))
    return [SimCrazyflie(SimFlyingCar(f"cf{i}", pos=(float(i), 0.0, 0.0), t=0.0), radio) for i in range(n)]


MODES = ("parked", "driving", "flying")


def measure(n: int, seconds: float, mode: str) -> dict[str, float]:
    """CPU time (this thread) per vehicle-frame, us, over `seconds` simulated seconds."""
    cfs = fleet(n)
    wheels = crtp.encode_wheels(0.1, -0.1)
    unlock = crtp.encode_setpoint(FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=0))
    climb = crtp.encode_setpoint(FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0,
                                                thrust=round(1.05 * hover_command(cfs[0].car.mass))))
    t = 0.0
    cpu = 0.0
    frames = round((BOOT_S + seconds) / FRAME_S)
    for _ in range(frames):
        t += FRAME_S
        timed = t > BOOT_S
        start = time.thread_time()
        for cf in cfs:
            car = cf.car
            if mode == "driving":
                cf.firmware.receive(wheels, car.t)
            elif mode == "flying":  # the supervisor unlocks on a zero thrust, then the climb
                cf.firmware.receive(climb if t > BOOT_S else unlock, car.t)
                cf.firmware.receive(crtp.encode_ext_pose(car.x, car.y, car.z, 0.0), car.t)
            cf.advance(t)
            car.truth()
        if timed:
            cpu += time.thread_time() - start
    moving = sum(abs(cf.car.wheel_left) > 0.05 or cf.car.airborne for cf in cfs)
    per_frame_us = 1e6 * cpu / (n * round(seconds / FRAME_S))
    return {"us": per_frame_us, "per_core": 1e6 * FRAME_S / per_frame_us, "moving": moving}


def main() -> None:
    parser = bench_parser(__doc__)
    parser.add_argument("--vehicles", type=int, default=32)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    rows, labels, costs = [], [], []
    for mode in MODES:
        r = measure(args.vehicles, args.seconds, mode)
        rows.append([mode, args.vehicles, int(r["moving"]), f"{r['us']:.0f}", f"{r['per_core']:.0f}"])
        labels.append(mode)
        costs.append(r["us"])
    print(format_table(["fleet", "vehicles", "moving", "us/vehicle-frame", "vehicles/core @100 Hz"], rows))
    print("cost: physics sub-steps + firmware tasks (+ decoding the commands) + ground truth per vehicle per 10 ms "
          "frame, thread CPU time; radio and bus excluded")
    fig, (ax,) = new_figure()
    ax.bar(labels, costs)
    ax.set(ylabel="us per vehicle-frame", title=f"simulator cost, {args.vehicles} vehicles")
    save_figure(fig, args.out, "sim_cost.png")


if __name__ == "__main__":
    main()
