"""A lifelong loop of random tasks: the vehicles fly to their first goals, and for --minutes every one
that arrives gets a random free parking spot as its next goal (drawn by the fleet's mission runner,
planned against the others' paths while they move). Once, the first vehicle is sent home by hand
when it reaches its first goal (`add_task`: it replaces the random goal it may have got). Prints each
task done and the tasks done per minute.

    python examples/lifelong.py [--vehicles cf1,cf2] [--goals WP2,WP6] [--minutes 2] [--seed 0] [--radios FILE]

A new goal given to a car while it drives may need it to turn round on its road, which the executors
do not do (the tracking guard holds it): redirect vehicles at rest or in the air.
"""

from __future__ import annotations

import argparse
import threading
import time

from services.api import CommandRefused, Fleet, MissionEvent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", default="cf1,cf2")
    parser.add_argument("--goals", default="WP2,WP6", help="each vehicle's first goal")
    parser.add_argument("--minutes", type=float, default=2.0, help="how long to keep giving new tasks")
    parser.add_argument("--seed", type=int, default=0, help="the random goals' seed")
    parser.add_argument("--radios", help="when no fleet is running here: start one with these vehicles")
    args = parser.parse_args()
    vehicles = args.vehicles.split(",")

    with Fleet.open(**({"radios": args.radios} if args.radios else {})) as fleet:
        here = fleet.vehicles(vehicles, timeout=30.0)  # a fleet just started: its vehicles come up
        print(", ".join(f"{v} at ({here[v].x:.2f}, {here[v].y:.2f})" for v in vehicles), flush=True)
        done: list[float] = []
        first = vehicles[0]
        first_arrived = threading.Event()
        t0 = time.monotonic()

        def on_event(e: MissionEvent) -> None:  # on the API's thread: no blocking calls here
            if e.kind == "arrived":
                done.append(time.monotonic())
                print(f"{time.monotonic() - t0:6.1f} s  task {len(done)} done: {e.vid} arrived", flush=True)
                if e.vid == first:
                    first_arrived.set()

        # a goal alone: from the spot the vehicle stands on
        mission = fleet.start_mission("town", dict(zip(vehicles, args.goals.split(","), strict=True)),
                                      lifelong_minutes=args.minutes, seed=args.seed,
                                      on_event=on_event)
        if first_arrived.wait(60.0 * args.minutes + 60.0):
            home = mission.plans[first].steps[0].node  # where its first plan started
            try:
                arrival = fleet.add_task(mission.id, first, home)
                print(f"sent {first} home to {home}: arriving {arrival:.1f} s into the mission", flush=True)
            except CommandRefused as refused:  # names the vehicle and why (home taken, ...)
                print(f"redirect refused: {refused}", flush=True)
        result = mission.wait()

    minutes = max((time.monotonic() - t0) / 60.0, 1e-9)
    for m in range(int(minutes) + 1):
        print(f"minute {m + 1}: {sum(1 for t in done if m <= (t - t0) / 60.0 < m + 1)} tasks done")
    print(f"{len(done)} tasks done in {minutes:.1f} min: {len(done) / minutes:.1f} per minute")
    print(result.summary)


if __name__ == "__main__":
    main()
