"""A ground-air team mission (paper 002): plan the drone's path with the UGV's help (PAD), then run
it through the executors against the simulated team, and print the summary.

    python examples/team_mission.py [--map demo-room] [--goal 5.75,3.75,2]
"""

from __future__ import annotations

import argparse
import sys

from services.api import Fleet, TeamTask


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="demo-room")
    parser.add_argument("--goal", default="5.75,3.75,2", help="the drone's goal x,y,z (m)")
    args = parser.parse_args()
    team = TeamTask(drone="drone1", ugv="ugv1", drone_start=(1.25, 1.25, 1.0), ugv_start=(0.75, 1.25, 0.0),
                    goal=tuple(float(c) for c in args.goal.split(",")))

    # the planner, the executors and the simulated team (10 simulated seconds a second), or FLEET_ZENOH_CONNECT's
    with Fleet.open(profiles=["team"], only=["planner", "executor", "team-sim"], fleet="team",
                    overrides={"FLEET_TEAM_MAP": args.map, "FLEET_TEAM_TIME_SCALE": "10"}) as fleet:
        plan = fleet.plan_team(args.map, team)
        print(f"team plan: {len(plan.drone)} drone steps, {len(plan.ugv)} UGV steps, cost {plan.cost:.1f}")
        result = fleet.run_team_mission(args.map, team, check=False)
    print(result.summary)
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
