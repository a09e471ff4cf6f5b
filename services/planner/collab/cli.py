"""`fleet collab plan`: plan a ground-air team plan (paper 002) and print or write it. Team missions
run through `fleet mission team`; the simulated team is `fleet sim team`, and `fleet sim replay`
executes a plan file in it."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from common.domain.team_plan import parse_vec3
from common.errors import InputError

# The demo room's problem (maps/collab/demo-room.yaml): the drone needs the UGV to reach the goal.
ROOM_MAP, ROOM_START, ROOM_UGV, ROOM_GOAL = "demo-room", "1.25,1.25,1", "0.75,1.25,0", "5.75,3.75,2"


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `collab` command group to the `fleet` parser's subparsers."""
    c = sub.add_parser("collab", help="ground-air team planning with collaborative localization (paper 002)")
    csub = c.add_subparsers(dest="collab_command", required=True, metavar="ACTION")
    p = csub.add_parser("plan", help="plan a team plan (PAD or full-dimensional ARA*) and print it")
    p.add_argument("--map", default="office-cubicles", help="generated map, maps/collab name, .yaml or MovingAI .map")
    p.add_argument("--seed", type=int, default=0, help="random start/goal pair (unless --start/--ugv/--goal)")
    p.add_argument("--start", help="drone start x,y,z in metres")
    p.add_argument("--ugv", help="UGV start x,y,heading_deg")
    p.add_argument("--goal", help="drone goal x,y,z")
    p.add_argument("--planner", choices=["pad", "arastar"], default="pad")
    p.add_argument("--time-limit", type=float, default=30.0, help="seconds to the first solution")
    p.add_argument("--improve", type=float, default=1.0, help="seconds to improve after it")
    p.add_argument("--out", help="write the plan as JSON here (`fleet sim replay FILE` executes it)")
    p.add_argument("--json", action="store_true", help="print JSON instead of the listing")
    p.add_argument("--slc", choices=["free", "paper"], default="free",
                   help="drone primitives: free metric steps (default) or the paper's corner groups and OBSTACLE trigger")
    p.set_defaults(handler=cmd_plan)


def _problem(args: argparse.Namespace, planner):
    from services.planner.collab.instances import sample_problem

    given = [args.start, args.ugv, args.goal]
    if not any(given):
        return sample_problem(planner, args.seed)
    if not all(given):
        raise InputError("fleet collab plan", "--start/--ugv/--goal", "give all three or none")
    source = "fleet collab plan"
    return planner.problem_at(parse_vec3(args.start, "--start", source), parse_vec3(args.ugv, "--ugv", source),
                              parse_vec3(args.goal, "--goal", source), source)


def cmd_plan(args: argparse.Namespace) -> int:
    from common.domain.team_plan import encode_json, format_team_plan
    from common.team.maps import load_env
    from services.planner.collab.lattice import SlcOptions
    from services.planner.collab.planner import TeamPlanner

    planner = TeamPlanner(load_env(args.map), options=SlcOptions.paper() if args.slc == "paper" else SlcOptions())
    problem = _problem(args, planner)
    out = planner.plan(problem, args.planner, args.time_limit, args.improve)
    if out.plan is None:
        why = "time limit reached" if out.timed_out else "no team plan exists"
        print(f"fleet collab plan: no plan ({why}, {out.expansions} expansions)", file=sys.stderr)
        return 1
    if args.out:
        Path(args.out).write_bytes(encode_json(out.plan))
    print(encode_json(out.plan).decode() if args.json else format_team_plan(out.plan))
    return 0
