"""`fleet mission run SCENARIO` (flying cars, paper 000) and `fleet mission team` (a ground-air team,
paper 002): plan, hand out, start together, watch, summarise; `fleet demo` (`services/mission/demo.py`)."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from common.bus.args import add_zenoh_args, keys_from_args, lazy_handler, zconfig_from_args
from common.domain.team_plan import parse_vec3
from common.errors import InputError

# The demo room's problem (maps/collab/demo-room.yaml): the drone needs the UGV to reach the goal.
ROOM_MAP, ROOM_START, ROOM_UGV, ROOM_GOAL = "demo-room", "1.25,1.25,1", "0.75,1.25,0", "5.75,3.75,2"


def register(sub: argparse._SubParsersAction) -> None:
    m = sub.add_parser("mission", help="run missions on the live fleet")
    msub = m.add_subparsers(dest="mission_command", required=True, metavar="ACTION")
    p = msub.add_parser("run", help="plan a scenario, fly it, print a summary (exit 0 if all arrived without contact)")
    p.add_argument("scenario", help="scenario YAML (maps/scenarios/...)")
    p.add_argument("--map", help="map name or path (default: the scenario's `map`)")
    p.add_argument("--planner", choices=["sipp", "ilp"], default="sipp")
    p.add_argument("--mu", type=float, default=0.5)
    p.add_argument("--time-limit", type=float, default=30.0, help="planning time limit (s)")
    p.add_argument("--id", help="mission id (default: random)")
    p.add_argument("--keep-going", action="store_true", help="do not abort the mission on a vehicle fault")
    p.add_argument("--on-fault", choices=["replan", "abort"], default="replan",
                   help="one vehicle's fault: plan the others on around it (default), or abort the mission")
    p.add_argument("--replanner", choices=["sipp", "ilp"], default="sipp",
                   help="who plans the others on after a fault or a new task: sipp (fast), or ilp (with "
                        "--planner ilp; sipp takes over when the ILP finds no plan within the replan's time)")
    p.add_argument("--rejoins", type=int, default=None,
                   help="how often a vehicle held for another's sake, or stopped by a fault that cleared, may be "
                        "brought back into the plan (default 3; 0: it stays held)")
    p.add_argument("--lifelong", action="store_true",
                   help="keep giving every vehicle that arrives a random free parking spot for --minutes")
    p.add_argument("--minutes", type=float, default=5.0, help="with --lifelong: how long to keep adding tasks")
    p.add_argument("--seed", type=int, default=0, help="with --lifelong: the random goals' seed")
    p.add_argument("--hover", action="store_true",
                   help="goals may be air nodes: a vehicle hovers there until `fleet mission add` gives it "
                        "another goal; the mission ends once every vehicle has landed at its goal")
    add_zenoh_args(p, default_instance="mission")
    p.set_defaults(handler=cmd_mission_run)
    p = msub.add_parser("add", help="give a vehicle of a running mission a new goal (planned against the others)")
    p.add_argument("mission", help="the running mission's id (printed when it starts; `--id` of mission run)")
    p.add_argument("vid", help="the vehicle")
    p.add_argument("goal", help="its new goal node")
    p.add_argument("--timeout", type=float, default=5.0, help="s to wait for the mission's answer")
    add_zenoh_args(p, default_instance="operator")
    p.set_defaults(handler=cmd_mission_add)
    _register_team(msub)
    _register_demo(sub)
    p = sub.add_parser("estop", help="emergency stop: every gateway cuts every vehicle's motors (operator role)")
    p.add_argument("--reason", default="operator's emergency stop", help="said in every vehicle's event")
    p.add_argument("--release", action="store_true", help="accept commands again; reboot the vehicles it locked")
    add_zenoh_args(p, default_instance="operator")
    p.set_defaults(handler=lazy_handler("services.mission.estop:cmd_estop"))


def _register_team(msub: argparse._SubParsersAction) -> None:
    p = msub.add_parser("team", help="plan a ground-air team mission (paper 002), run it through the executors")
    p.add_argument("--map", default=ROOM_MAP)
    p.add_argument("--start", default=ROOM_START, help="drone start x,y,z in metres")
    p.add_argument("--ugv", default=ROOM_UGV, help="UGV start x,y,heading_deg")
    p.add_argument("--goal", default=ROOM_GOAL, help="drone goal x,y,z")
    p.add_argument("--drone-id", default="drone1", help="the drone's vehicle id")
    p.add_argument("--ugv-id", default="ugv1", help="the UGV's vehicle id")
    p.add_argument("--planner", choices=["pad", "arastar"], default="pad")
    p.add_argument("--time-limit", type=float, default=30.0, help="seconds to the first solution")
    p.add_argument("--improve", type=float, default=1.0, help="seconds to improve after it")
    p.add_argument("--id", help="mission id (default: random)")
    p.add_argument("--local", action="store_true",
                   help="bring up the planner, executors and the simulated team here first (compose.yaml, profile team)")
    p.add_argument("--executors", type=int, default=2, help="with --local: how many executors")
    p.add_argument("--time-scale", type=float, default=10.0, help="with --local: simulated seconds per real second")
    p.add_argument("--run-dir", default="out/team-mission", help="with --local: process state and logs")
    add_zenoh_args(p, default_instance="mission")
    p.set_defaults(handler=cmd_mission_team)


def _register_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="plan and fly the 8-vehicle town mission in simulation, one command")
    p.add_argument("--scenario", help="scenario YAML (default: maps/scenarios/town_8.yaml, or town_fly.yaml)")
    p.add_argument("--vehicles", choices=["fly+drive", "fly"], default="fly+drive",
                   help="flying cars (the paper's), or stock Crazyflies that only fly (no wheel app)")
    p.add_argument("--control", choices=["offboard", "onboard"], default="offboard",
                   help="offboard: the executors' LQR sends attitude setpoints (paper 000); onboard: motion "
                        "capture streamed to each vehicle's estimator, position setpoints to its own controller")
    p.add_argument("--planner", choices=["sipp", "ilp"], default="sipp")
    p.add_argument("--mu", type=float, default=0.5)
    p.add_argument("--time-limit", type=float, default=30.0)
    p.add_argument("--executors", type=int, default=2)
    p.add_argument("--per-radio", type=int, default=2, help="simulated Crazyflies per radio (paper: 2)")
    p.add_argument("--out", default="out/demo")
    p.add_argument("--viewer", action="store_true", help="spawn the rerun viewer")
    p.add_argument("--web", action="store_true", help="serve the rerun web viewer")
    p.add_argument("--lead", type=float,
                   help="s from the plans' hand-out (the live view shows the map and the plans) to the start "
                        "(default: every mission's, 2 s)")
    p.set_defaults(handler=lazy_handler("services.mission.demo:run_demo"))


def spec_from_args(args: argparse.Namespace):
    from common.domain.scenario import read_scenario
    from services.mission.client import MissionTiming
    from services.mission.runner import MissionSpec

    scen = read_scenario(args.scenario)
    map_name = args.map or scen.map
    if not map_name:
        raise InputError(args.scenario, "map", "the scenario names no map: give --map")
    extra = {"mission": args.id} if args.id else {}
    if args.lifelong and args.minutes <= 0:
        raise InputError("fleet mission run", "--minutes", f"{args.minutes:g}: must be positive")
    if args.rejoins is not None:
        if args.rejoins < 0:
            raise InputError("fleet mission run", "--rejoins", f"{args.rejoins}: must be 0 or more")
        extra["rejoins"] = args.rejoins
    if args.replanner == "ilp" and args.planner != "ilp":
        raise InputError("fleet mission run", "--replanner", "ilp replans the ILP's plans: give --planner ilp too")
    return MissionSpec(map=map_name, tasks=dict(scen.tasks), planner=args.planner, mu=args.mu,
                       time_limit=args.time_limit, timing=MissionTiming(abort_on_fault=not args.keep_going),
                       on_fault=args.on_fault, lifelong_s=60.0 * args.minutes if args.lifelong else 0.0,
                       seed=args.seed, replanner=args.replanner, hover=args.hover, **extra)


def cmd_mission_add(args: argparse.Namespace) -> int:
    """`fleet mission add MISSION VID GOAL`: the mission's answer; exit 1 if refused or unanswered."""
    from common.bus.messages import TaskAdd, TaskAddReply
    from common.bus.pubsub import QueryError, QueryTimeout, query
    from common.bus.session import open_session

    keys = keys_from_args(args)
    key = keys.mission(args.mission, "add")

    async def ask() -> TaskAddReply:
        session = open_session(zconfig_from_args(args))
        try:
            return await query(session, key, TaskAdd(vid=args.vid, goal=args.goal), TaskAddReply, timeout=args.timeout)
        finally:
            session.close()

    try:
        reply = asyncio.run(ask())
    except (QueryTimeout, QueryError) as exc:
        print(f"fleet mission add: mission {args.mission} did not answer ({exc}): is it running?", file=sys.stderr)
        return 1
    if not reply.ok:
        print(f"fleet mission add: refused: {reply.error}", file=sys.stderr)
        return 1
    print(f"{args.vid} -> {args.goal}: planned, arriving {reply.arrival_s:.1f} s into mission {args.mission}")
    return 0


def cmd_mission_run(args: argparse.Namespace) -> int:
    from services.mission.runner import MissionRunner

    spec = spec_from_args(args)
    runner = MissionRunner(spec, zconfig_from_args(args), keys_from_args(args))
    code = asyncio.run(runner.run())
    if runner.result is None:
        print("mission: could not run (no router reachable?)")
        return code or 1
    print(runner.result.summary())
    return 0 if runner.result.ok else 1


def cmd_mission_team(args: argparse.Namespace) -> int:
    from common.bus.messages import TeamTask
    from services.mission.team_mission import TeamMission, TeamMissionSpec

    source = "fleet mission team"
    if args.executors < 1 or args.time_scale <= 0:
        raise InputError(source, "--executors/--time-scale", "must be positive")
    team = TeamTask(drone=args.drone_id, ugv=args.ugv_id, drone_start=parse_vec3(args.start, "--start", source),
                    ugv_start=parse_vec3(args.ugv, "--ugv", source), goal=parse_vec3(args.goal, "--goal", source),
                    method=args.planner, improve_s=args.improve)
    spec = TeamMissionSpec(map=args.map, team=team, time_limit=args.time_limit, **({"mission": args.id} if args.id else {}))

    def run(zconfig, keys) -> TeamMission:
        mission = TeamMission(spec, zconfig, keys)
        asyncio.run(mission.run())
        return mission

    if args.local:
        from common.deploy.local import bring_up

        overrides = {"FLEET_NAME": "team", "FLEET_EXECUTORS": str(args.executors), "FLEET_TEAM_MAP": args.map,
                     "FLEET_TEAM_DRONE": args.start, "FLEET_TEAM_UGV": args.ugv, "FLEET_TEAM_DRONE_ID": args.drone_id,
                     "FLEET_TEAM_UGV_ID": args.ugv_id, "FLEET_TEAM_TIME_SCALE": f"{args.time_scale:g}"}
        try:
            with bring_up(Path(args.run_dir), overrides, profiles=["team"],
                          only=["planner", "executor", "team-sim"]) as local:
                mission = run(local.client_config(), local.keys)
        except RuntimeError as exc:
            print(f"{source}: {exc}", file=sys.stderr)
            return 1
    else:
        mission = run(zconfig_from_args(args), keys_from_args(args))
    if mission.result is None:
        print(f"{source}: could not run (no router reachable?)", file=sys.stderr)
        return 1
    print(mission.result.summary())
    return 0 if mission.result.ok else 1
