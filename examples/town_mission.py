"""Fly the town mission (paper 000 §VII-C: eight flying cars, six of them over the gap between the
two road regions) and print the mission runner's summary; the mission's events as they happen.

    python examples/town_mission.py [--scenario maps/scenarios/town_8.yaml] [--only cf1,cf4] [--planner ilp]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from services.api import Fleet, MissionEvent


def show(event: MissionEvent) -> None:
    """Print what matters as it happens (progress events are left out)."""
    if event.kind in ("started", "arrived", "vehicle_event", "aborted", "ended"):
        print(f"  {event.kind:<13} {event.vid:<5} {event.detail}", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="maps/scenarios/town_8.yaml")
    parser.add_argument("--only", help="fly only these vehicles of the scenario (comma-separated)")
    parser.add_argument("--planner", default="sipp", choices=["sipp", "ilp"])
    args = parser.parse_args()
    scenario = yaml.safe_load(Path(args.scenario).read_text())
    tasks = {vid: (t["start"], t["goal"]) for vid, t in scenario["tasks"].items()
             if not args.only or vid in args.only.split(",")}

    with Fleet.open() as fleet:
        result = fleet.run_mission(scenario["map"], tasks, planner=args.planner, on_event=show, check=False)
    print(result.summary)
    for vid, v in result.vehicles.items():
        print(f"{vid}: {'arrived' if v.arrived else 'did not arrive'}, {v.energy_j:.1f} J")
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
