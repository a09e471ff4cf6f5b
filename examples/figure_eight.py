"""One vehicle traces a figure eight across the town, leg by leg: each leg is a single-vehicle
command (the planner's one-vehicle plan, flown through the executors with the fleet's safety checks;
refused while a mission owns the vehicle). From WP9 the default legs cross the gap twice, in the air:
WP9 -> WP10 -> EP7 -> EP4 -> WP9.

    python examples/figure_eight.py [--vehicle cf7] [--spots WP10,EP7,EP4,WP9] [--legs N]
"""

from __future__ import annotations

import argparse
import time

from services.api import Fleet


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicle", default="cf7")
    parser.add_argument("--spots", default="WP10,EP7,EP4,WP9", help="the spots of the eight, in order")
    parser.add_argument("--legs", type=int, help="fly only the first N legs")
    args = parser.parse_args()
    spots = args.spots.split(",")[:args.legs]

    with Fleet.open() as fleet:
        start = fleet.vehicles([args.vehicle])[args.vehicle]
        print(f"{args.vehicle} at ({start.x:.2f}, {start.y:.2f}), {start.mode}, battery {start.battery_v} V")
        for spot in spots:
            t, modes = time.monotonic(), set()
            # raises VehicleBusy, CommandRefused or MissionFailed, naming the vehicle and the reason
            result = fleet.go_to(args.vehicle, spot, on_event=lambda e, seen=modes: seen.add(e.mode))
            v = fleet.vehicle(args.vehicle)
            print(f"-> {spot}: {'flew' if 'flying' in modes else 'drove'} in {time.monotonic() - t:.1f} s, "
                  f"{result.vehicles[args.vehicle].energy_j:.1f} J, now at ({v.x:.2f}, {v.y:.2f}, {v.z:.2f})", flush=True)


if __name__ == "__main__":
    main()
