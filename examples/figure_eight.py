"""One vehicle flies a figure eight in the air, crazyswarm-style: take off, go to each point of the
eight, land where it took off. Each call goes through the fleet's planner and executors with the
missions' safety checks (a point is flown to the air node nearest it); refused while a mission owns
the vehicle. The default eight lies in the town's flight corridor over the gap.

    python examples/figure_eight.py [--vehicle cf7] [--center 1.8,1.05] [--size 0.25] [--legs N]
"""

from __future__ import annotations

import argparse
import time

from services.api import Fleet


def eight(cx: float, cy: float, d: float, z: float) -> list[tuple[float, float, float]]:
    """The points of a figure eight around (cx, cy): the right loop, the centre, the left loop, the centre."""
    offsets = [(0, 0), (d, d), (2 * d, 0), (d, -d), (0, 0), (-d, d), (-2 * d, 0), (-d, -d), (0, 0)]
    return [(cx + dx, cy + dy, z) for dx, dy in offsets]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicle", default="cf7")
    parser.add_argument("--center", default="1.8,1.05", help="x,y of the eight's centre (m)")
    parser.add_argument("--size", type=float, default=0.25, help="half the height of a loop (m)")
    parser.add_argument("--height", type=float, default=0.4)
    parser.add_argument("--legs", type=int, help="fly only the first N points, then land")
    args = parser.parse_args()
    cx, cy = (float(c) for c in args.center.split(","))
    vid = args.vehicle

    with Fleet.open() as fleet:
        start = fleet.vehicles([vid])[vid]
        print(f"{vid} at ({start.x:.2f}, {start.y:.2f}), {start.mode}, battery {start.battery_v} V", flush=True)
        t = time.monotonic()
        # raise VehicleBusy, CommandRefused or MissionFailed, naming the vehicle and the reason
        node = fleet.takeoff(vid)
        print(f"took off: hovering at {node} in {time.monotonic() - t:.1f} s", flush=True)
        for point in eight(cx, cy, args.size, args.height)[:args.legs]:
            t = time.monotonic()
            fleet.go_to(vid, point)
            v = fleet.vehicle(vid)
            print(f"-> ({point[0]:.2f}, {point[1]:.2f}): at ({v.x:.2f}, {v.y:.2f}, {v.z:.2f}) "
                  f"in {time.monotonic() - t:.1f} s", flush=True)
        t = time.monotonic()
        result = fleet.land(vid)
        v = fleet.vehicle(vid)
        print(f"landed at ({v.x:.2f}, {v.y:.2f}) in {time.monotonic() - t:.1f} s, "
              f"{result.vehicles[vid].energy_j:.1f} J in all", flush=True)


if __name__ == "__main__":
    main()
