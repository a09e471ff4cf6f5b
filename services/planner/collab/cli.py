"""`fleet collab ...`: plan, simulate and benchmark ground-air team plans (paper 002), run the
simulated team as a service, and run team missions through the executors."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from common.bus.args import add_zenoh_args
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
    p.add_argument("--out", help="write the plan as JSON here")
    p.add_argument("--json", action="store_true", help="print JSON instead of the listing")
    p.add_argument("--simulate", action="store_true", help="also execute the plan in simulation")
    p.set_defaults(handler=cmd_plan)

    p = csub.add_parser("simulate", help="execute a team plan file in simulation, honouring its sync points")
    p.add_argument("plan", help="team plan JSON")
    p.add_argument("--map", help="default: the plan's map")
    p.set_defaults(handler=cmd_simulate)

    p = csub.add_parser("sim", help="run a simulated ground-air team: executes the actions executors send")
    p.add_argument("--map", default=ROOM_MAP, help="the world (a map name or file, as for plan)")
    p.add_argument("--start", default=ROOM_START, help="drone start x,y,z in metres")
    p.add_argument("--ugv", default=ROOM_UGV, help="UGV start x,y,heading_deg")
    _team_ids(p)
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated seconds per real second")
    p.add_argument("--truth-rate", type=float, default=10.0, help="ground truth publication rate (Hz)")
    add_zenoh_args(p, default_instance="collab-sim")
    p.set_defaults(handler=cmd_sim)

    p = csub.add_parser("mission", help="plan a team mission, run it through the executors, print a summary")
    p.add_argument("--map", default=ROOM_MAP)
    p.add_argument("--start", default=ROOM_START, help="drone start x,y,z in metres")
    p.add_argument("--ugv", default=ROOM_UGV, help="UGV start x,y,heading_deg")
    p.add_argument("--goal", default=ROOM_GOAL, help="drone goal x,y,z")
    _team_ids(p)
    p.add_argument("--planner", choices=["pad", "arastar"], default="pad")
    p.add_argument("--time-limit", type=float, default=30.0, help="seconds to the first solution")
    p.add_argument("--improve", type=float, default=1.0, help="seconds to improve after it")
    p.add_argument("--id", help="mission id (default: random)")
    p.add_argument("--local", action="store_true",
                   help="bring up a router, the planner, executors and the simulated team here first")
    p.add_argument("--executors", type=int, default=2, help="with --local: how many executors")
    p.add_argument("--time-scale", type=float, default=10.0, help="with --local: simulated seconds per real second")
    p.add_argument("--run-dir", default="out/collab-mission", help="with --local: process state and logs")
    add_zenoh_args(p, default_instance="mission")
    p.set_defaults(handler=cmd_mission)

    p = csub.add_parser("bench", help="PAD vs full-dimensional ARA* on the two office maps (002 Tables I-II)")
    p.add_argument("--instances", type=int, default=50)
    p.add_argument("--time-limit", type=float, default=10.0)
    p.add_argument("--improve", type=float, default=1.0)
    p.add_argument("--out", default="out/collab_experiment.png")
    p.add_argument("--json", default="out/collab_experiment.json", help="per-run results ('' for none)")
    p.set_defaults(handler=cmd_bench)


def _team_ids(p: argparse.ArgumentParser) -> None:
    p.add_argument("--drone-id", default="drone1", help="the drone's vehicle id")
    p.add_argument("--ugv-id", default="ugv1", help="the UGV's vehicle id")


def floats(text: str, what: str, source: str = "fleet collab plan") -> tuple[float, float, float]:
    """'x,y,z' -> three floats; an InputError naming the option otherwise."""
    try:
        x, y, z = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(source, what, f"expected three comma-separated numbers, got {text!r}") from None
    return x, y, z


def _problem(args: argparse.Namespace, planner):
    from services.planner.collab.instances import sample_problem

    given = [args.start, args.ugv, args.goal]
    if not any(given):
        return sample_problem(planner, args.seed)
    if not all(given):
        raise InputError("fleet collab plan", "--start/--ugv/--goal", "give all three or none")
    return planner.problem_at(floats(args.start, "--start"), floats(args.ugv, "--ugv"), floats(args.goal, "--goal"),
                              "fleet collab plan")


def format_plan(plan) -> str:
    """A readable listing of a team plan: one line per step, sync points as 'after <robot> <n>'."""
    from common.domain import team_plan as tp
    lines = [f"team plan on {plan.map} ({plan.planner}): cost {plan.cost:.2f} (within {plan.epsilon:.2f} x optimal), "
             f"{plan.planning_time_s:.2f} s, {plan.expansions} expansions",
             f"drone start {plan.drone_start}, UGV start {plan.ugv_start}, goal {plan.goal}"]
    for robot, steps in (("drone", plan.drone), ("ugv", plan.ugv)):
        lines.append(f"{robot}:")
        other = tp.PlanProgress.other(robot)
        for i, step in enumerate(steps):
            fields = " ".join(f"{k}={_short(v)}" for k, v in _fields(step.action).items())
            sync = f"  [after {other} {step.wait_for}]" if step.wait_for else ""
            end = ", ".join(f"{v:.2f}" for v in step.end)
            lines.append(f"  {i:3d} {tp.action_name(step):18s} {fields} -> ({end}){sync}")
    return "\n".join(lines)


def _fields(struct) -> dict:
    return {f: getattr(struct, f) for f in struct.__struct_fields__}


def _short(v):
    if isinstance(v, float):
        return f"{v:.2f}"
    if isinstance(v, tuple):
        return "(" + ", ".join(_short(x) for x in v) + ")"
    return v


def cmd_plan(args: argparse.Namespace) -> int:
    from common.domain.team_plan import encode_json
    from common.team.maps import load_env
    from services.planner.collab.planner import TeamPlanner

    planner = TeamPlanner(load_env(args.map))
    problem = _problem(args, planner)
    out = planner.plan(problem, args.planner, args.time_limit, args.improve)
    if out.plan is None:
        why = "time limit reached" if out.timed_out else "no team plan exists"
        print(f"fleet collab plan: no plan ({why}, {out.expansions} expansions)", file=sys.stderr)
        return 1
    if args.out:
        Path(args.out).write_bytes(encode_json(out.plan))
    print(encode_json(out.plan).decode() if args.json else format_plan(out.plan))
    if args.simulate:
        return _simulate(planner.sensing, out.plan)
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from common.domain.team_plan import read_plan
    from common.team.maps import load_env
    from common.team.sensing import Sensing
    from common.team.team_model import TeamModel

    plan = read_plan(args.plan)
    return _simulate(Sensing(load_env(args.map or plan.map), TeamModel()), plan)


def _simulate(sensing, plan) -> int:
    from services.sim.team.world import TeamSim

    report = TeamSim(sensing, plan).run()
    for e in report.events:
        mark = "ok " if e.ok else "ERR"
        pose = ", ".join(f"{v:.2f}" for v in e.pose)
        print(f"{mark} t={e.start_s:6.1f}-{e.end_s:6.1f}s {e.robot:5s} {e.index:3d} {e.action:16s} -> ({pose}) {e.detail}")
    status = "drone reached the goal" if report.reached_goal else f"FAILED: {report.failure or 'goal not reached'}"
    print(f"simulation: {status}; makespan {report.makespan_s:.1f} s")
    return 0 if report.reached_goal else 1


def cmd_sim(args: argparse.Namespace) -> int:
    from common.bus.args import keys_from_args, run_service, zconfig_from_args
    from common.team.maps import load_env
    from services.planner.collab.planner import TeamPlanner
    from services.sim.team.service import CollabSimService
    from services.sim.team.world import TeamWorld

    if args.time_scale <= 0 or args.truth_rate <= 0:
        raise InputError("fleet collab sim", "--time-scale/--truth-rate", "must be positive")
    start, ugv = floats(args.start, "--start", "fleet collab sim"), floats(args.ugv, "--ugv", "fleet collab sim")
    planner = TeamPlanner(load_env(args.map))
    planner.problem_at(start, ugv, start, "fleet collab sim")  # checks that both robots may stand there
    world = TeamWorld(planner.sensing, start, ugv)
    svc = CollabSimService(args.instance, zconfig_from_args(args), keys_from_args(args), world,
                           {"drone": args.drone_id, "ugv": args.ugv_id}, args.time_scale, args.truth_rate)
    return run_service(svc)


def cmd_mission(args: argparse.Namespace) -> int:
    import asyncio

    from common.bus.args import keys_from_args, zconfig_from_args
    from common.bus.messages import TeamTask
    from services.mission.team import TeamMission, TeamMissionSpec
    from services.planner.collab.local import local_team

    source = "fleet collab mission"
    if args.executors < 1 or args.time_scale <= 0:
        raise InputError(source, "--executors/--time-scale", "must be positive")
    team = TeamTask(drone=args.drone_id, ugv=args.ugv_id, drone_start=floats(args.start, "--start", source),
                    ugv_start=floats(args.ugv, "--ugv", source), goal=floats(args.goal, "--goal", source),
                    method=args.planner, improve_s=args.improve)
    spec = TeamMissionSpec(map=args.map, team=team, time_limit=args.time_limit, **({"mission": args.id} if args.id else {}))

    def run(zconfig, keys) -> TeamMission:
        mission = TeamMission(spec, zconfig, keys)
        asyncio.run(mission.run())
        return mission

    if args.local:
        try:
            with local_team(args.map, team, Path(args.run_dir), args.executors, args.time_scale) as (zconfig, keys):
                mission = run(zconfig, keys)
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


def cmd_bench(args: argparse.Namespace) -> int:
    from services.planner.collab.experiment import run

    if args.instances < 1 or args.time_limit <= 0 or args.improve < 0:
        raise InputError("fleet collab bench", "--instances/--time-limit/--improve", "must be positive")
    print(run(args.instances, args.time_limit, args.improve, Path(args.out), Path(args.json) if args.json else None))
    print(f"\nfigure: {args.out}")
    return 0
