"""`fleet mission run SCENARIO`: plan, hand out, start together, watch, summarise; `fleet demo`
(`services/mission/demo.py`)."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from common.bus.args import add_zenoh_args, keys_from_args, lazy_handler, zconfig_from_args
from common.domain.mapfile import decode_yaml, read_text
from common.errors import InputError


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
    add_zenoh_args(p, default_instance="mission")
    p.set_defaults(handler=cmd_mission_run)
    _register_demo(sub)


def _register_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="plan and fly the 8-vehicle town mission in simulation, one command")
    p.add_argument("--scenario", help="scenario YAML (default: maps/scenarios/town_8.yaml)")
    p.add_argument("--planner", choices=["sipp", "ilp"], default="sipp")
    p.add_argument("--mu", type=float, default=0.5)
    p.add_argument("--time-limit", type=float, default=30.0)
    p.add_argument("--executors", type=int, default=2)
    p.add_argument("--per-radio", type=int, default=2, help="simulated Crazyflies per radio (paper: 2)")
    p.add_argument("--out", default="out/demo")
    p.add_argument("--viewer", action="store_true", help="spawn the rerun viewer")
    p.add_argument("--web", action="store_true", help="serve the rerun web viewer")
    p.set_defaults(handler=lazy_handler("services.mission.demo:run_demo"))


def spec_from_args(args: argparse.Namespace):
    from services.mission.runner import MissionSpec
    from services.planner.maps.scenario import ScenarioFile

    scen: ScenarioFile = decode_yaml(read_text(Path(args.scenario)), ScenarioFile, args.scenario)
    map_name = args.map or scen.map
    if not map_name:
        raise InputError(args.scenario, "map", "the scenario names no map: give --map")
    extra = {"mission": args.id} if args.id else {}
    return MissionSpec(map=map_name, tasks=dict(scen.tasks), planner=args.planner, mu=args.mu,
                       time_limit=args.time_limit, abort_on_fault=not args.keep_going, **extra)


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
