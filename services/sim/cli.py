"""`fleet sim`: everything simulated. Bare `fleet sim --config RADIOS` runs the simulated Crazyflies
of a radios file (each at its `udp://` URI, docs/radio.md); `fleet sim team` the simulated ground-air
team of paper 002; `fleet sim replay PLAN` executes a team plan file in that world, offline;
`fleet sim fault VID KIND` injects a fault into a running simulated fleet (`services/sim/fault.py`)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, get_args

from common.bus.args import add_zenoh_args, keys_from_args, lazy_handler, run_service, zconfig_from_args
from common.bus.messages import SimFaultKind
from common.bus.process_priority import raise_priority
from common.domain.team_plan import parse_vec3
from common.errors import InputError

if TYPE_CHECKING:
    from services.sim.team.world import SensingNoise

# The demo room of paper 002's team (maps/collab/demo-room.yaml), as `fleet collab plan` knows it.
ROOM_MAP, ROOM_START, ROOM_UGV = "demo-room", "1.25,1.25,1", "0.75,1.25,0"
FAULT_KINDS: tuple[str, ...] = get_args(SimFaultKind)


def register(subparsers: argparse._SubParsersAction) -> None:
    sim = subparsers.add_parser("sim", help="simulated Crazyflies (--config RADIOS), the simulated team, replays")
    sim.add_argument("--config", help="radios file (YAML, docs/radio.md): simulate its udp:// vehicles")
    sim.add_argument("--radio", action="append", help="simulate only this radio's vehicles (repeatable)")
    sim.add_argument("--truth-hz", type=float, default=100.0, help="ground-truth rate on sim/truth/<vid> (Hz)")
    sim.add_argument("--thrust-spread", type=float, default=0.0, metavar="FRACTION",
                     help="units' thrust differs from the model by up to this fraction, fixed by each id (default 0)")
    sim.add_argument("--priority", type=int, default=0, metavar="N",
                     help="raise its CPU priority by N nice levels where the system allows it (root or "
                          "CAP_SYS_NICE): the simulated world should not wait for a CPU the fleet's services "
                          "want (default 0: leave it)")
    add_zenoh_args(sim, default_instance="sim")
    sim.set_defaults(handler=_crazyflies)
    ssub = sim.add_subparsers(dest="sim_command", metavar="ACTION")

    p = ssub.add_parser("team", help="a simulated ground-air team (paper 002): runs the actions executors send")
    p.add_argument("--map", default=ROOM_MAP, help="the world (a map name or file, as for `fleet collab plan`)")
    p.add_argument("--start", default=ROOM_START, help="drone start x,y,z in metres")
    p.add_argument("--ugv", default=ROOM_UGV, help="UGV start x,y,heading_deg")
    p.add_argument("--drone-id", default="drone1", help="the drone's vehicle id")
    p.add_argument("--ugv-id", default="ugv1", help="the UGV's vehicle id")
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated seconds per real second")
    p.add_argument("--truth-rate", type=float, default=10.0, help="ground truth publication rate (Hz)")
    _noise_args(p)
    add_zenoh_args(p, default_instance="team-sim")
    p.set_defaults(handler=_team)

    _register_fault(ssub)

    p = ssub.add_parser("replay", help="execute a team plan file in the simulated world, honouring its sync points")
    p.add_argument("plan", help="team plan JSON (`fleet collab plan --out`)")
    p.add_argument("--map", help="default: the plan's map")
    _noise_args(p)
    p.set_defaults(handler=_replay)


def _noise_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--range-noise", type=float, default=0.0, help="drone range sensing error, std dev in m")
    p.add_argument("--bearing-noise", type=float, default=0.0, help="drone bearing sensing error, std dev in deg")
    p.add_argument("--noise-seed", type=int, default=0, help="seed of the sensing errors")


def _noise(args: argparse.Namespace, source: str) -> SensingNoise:
    """The drone's sensing errors the command asks for (`SensingNoise`)."""
    from services.sim.team.world import SensingNoise

    try:
        return SensingNoise(args.range_noise, args.bearing_noise)
    except ValueError as e:
        raise InputError(source, "--range-noise/--bearing-noise", str(e)) from None


def _register_fault(ssub: argparse._SubParsersAction) -> None:
    p = ssub.add_parser("fault", help="inject a fault into a running simulated fleet (operator role; "
                                      "docs/reliability.md)")
    p.add_argument("vid", metavar="VID", help="the simulated vehicle")
    p.add_argument("kind", metavar="KIND", choices=FAULT_KINDS,
                   help="mocap_dropout, radio_blackout (--duration S), battery (--charge-used AH), "
                        "power_off (--duration S, 0 or none: until power_on), power_on, "
                        "gust (--duration S --gust AX AY: wind on the body in the air, m/s^2)")
    amount = p.add_mutually_exclusive_group()
    amount.add_argument("--duration", type=float, metavar="S", help="how long the fault lasts (s)")
    amount.add_argument("--charge-used", type=float, metavar="AH", help="battery: the charge used from now on (Ah)")
    p.add_argument("--gust", type=float, nargs=2, metavar=("AX", "AY"),
                   help="gust: the wind's horizontal acceleration on the body (m/s^2, world x and y)")
    p.add_argument("--wait", type=float, default=2.0, help="how long to wait for the simulator (s)")
    add_zenoh_args(p, default_instance="operator")
    p.set_defaults(handler=lazy_handler("services.sim.fault:cmd_fault"))


def _crazyflies(args: argparse.Namespace) -> int:
    from common.deploy.radios import load_radios_for
    from services.sim.crazyflie.service import SimService

    if not args.config:
        raise InputError("fleet sim", "--config", "a radios file is needed to simulate Crazyflies")
    spec = load_radios_for(args.config, args.radio or [])
    if args.truth_hz <= 0:
        raise InputError("--truth-hz", "", "must be positive")
    if not 0.0 <= args.thrust_spread < 0.5:
        raise InputError("--thrust-spread", "", "must be at least 0 and below 0.5")
    if not 0 <= args.priority <= 19:
        raise InputError("--priority", "", "must be 0 to 19")
    raise_priority(args.priority)
    return run_service(SimService(spec, zconfig_from_args(args), instance=args.instance, keys=keys_from_args(args),
                                  radios=args.radio, truth_hz=args.truth_hz, thrust_spread=args.thrust_spread))


def _team(args: argparse.Namespace) -> int:
    from common.team.maps import load_env
    from common.team.problem import problem_in_metres
    from common.team.sensing import Sensing
    from common.team.team_model import TeamModel
    from services.sim.team.service import TeamSimService
    from services.sim.team.world import TeamWorld

    source = "fleet sim team"
    if args.time_scale <= 0 or args.truth_rate <= 0:
        raise InputError(source, "--time-scale/--truth-rate", "must be positive")
    start, ugv = parse_vec3(args.start, "--start", source), parse_vec3(args.ugv, "--ugv", source)
    sensing = Sensing(load_env(args.map), TeamModel())
    problem_in_metres(sensing, start, ugv, start, source)  # both robots may stand there
    world = TeamWorld(sensing, start, ugv, _noise(args, source), args.noise_seed)
    svc = TeamSimService(args.instance, zconfig_from_args(args), keys_from_args(args), world,
                         {"drone": args.drone_id, "ugv": args.ugv_id}, args.time_scale, args.truth_rate)
    return run_service(svc)


def _replay(args: argparse.Namespace) -> int:
    from common.domain.team_plan import read_plan
    from common.team.maps import load_env
    from common.team.sensing import Sensing
    from common.team.team_model import TeamModel
    from services.sim.team.world import TeamSim

    plan = read_plan(args.plan)
    noise = _noise(args, "fleet sim replay")
    report = TeamSim(Sensing(load_env(args.map or plan.map), TeamModel()), plan, noise, args.noise_seed).run()
    for e in report.events:
        mark = "ok " if e.ok else "ERR"
        pose = ", ".join(f"{v:.2f}" for v in e.pose)
        print(f"{mark} t={e.start_s:6.1f}-{e.end_s:6.1f}s {e.robot:5s} {e.index:3d} {e.action:16s} -> ({pose}) {e.detail}")
    status = "drone reached the goal" if report.reached_goal else f"FAILED: {report.failure or 'goal not reached'}"
    print(f"replay: {status}; makespan {report.makespan_s:.1f} s")
    return 0 if report.reached_goal else 1
