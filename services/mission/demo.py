"""`fleet demo`: the whole fleet on one machine with no setup (paper 000 §VII-C: 8 flying cars in
the miniature town, two per Crazyradio). compose.yaml's services as processes of this Python
(`common.deploy.local.bring_up`), with the demo's overrides: simulated Crazyflies on the scenario's
start spots, one gateway per simulated radio, the executor count, the recorder's viewer; the router
in this process; the mission run from here; a summary at the end. Exit 0 only if every vehicle
arrived and no two bodies came into contact."""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from functools import partial
from pathlib import Path

import msgspec

from common.bus.messages import ControlMode
from common.deploy.compose import Process
from common.deploy.local import LocalFleet, bring_up
from common.deploy.radios import GatewayParams, LinkModel, RadiosFile, dump_radios, simulated_radios
from common.domain.mapfile import MAPS_DIR, load_map, spot_pose
from common.domain.planfile import Task
from common.domain.scenario import read_scenario
from common.errors import InputError
from services.mission.client import MissionTiming
from services.mission.runner import MissionRunner, MissionSpec

DEMO_SCENARIO = MAPS_DIR / "scenarios" / "town_8.yaml"
FLY_SCENARIO = MAPS_DIR / "scenarios" / "town_fly.yaml"
"""`fleet demo --vehicles fly`: stock Crazyflies (no wheel app), flying only."""


def demo_radios(map_name: str, tasks: dict[str, Task], per_radio: int = 2, link: LinkModel | None = None,
                source: str = "", control: ControlMode = "offboard", gateway: GatewayParams | None = None) -> RadiosFile:
    """Simulated Crazyflies parked on their start spots, `per_radio` to a radio (the paper found 2
    reliable), radios named radio0, radio1, ..., flying in control mode `control`."""
    spec = load_map(map_name)
    poses = {vid: spot_pose(spec, task.start, source) for vid, task in tasks.items()}
    radios = simulated_radios({vid: p[:3] for vid, p in poses.items()}, per_radio, link, gateway,
                              yaws={vid: p[3] for vid, p in poses.items()}, prefix="radio", control=control)
    return msgspec.structs.replace(radios, radios={  # each vehicle is what its task says (wheels or not)
        name: msgspec.structs.replace(radio, vehicles={
            vid: msgspec.structs.replace(v, capabilities=tasks[vid].capabilities) for vid, v in radio.vehicles.items()})
        for name, radio in radios.radios.items()})


def gateways_for_radios(procs: list[Process], radios_path: Path, radios: RadiosFile, radios_each: int = 1
                        ) -> list[Process]:
    """compose.yaml's gateways replaced by gateway processes for the radios of `radios` (same role,
    same environment): one per radio, as compose runs them, or one per `radios_each` radios (each
    radio still its own gateway, named after it: `fleet gateway --radio a --radio b`), which spares
    a simulated fleet's machine the cost of a process per radio (docs/radio.md)."""
    gateways = [p for p in procs if p.service.startswith("gateway")]
    if not gateways:
        return procs
    if radios_each < 1:
        raise ValueError("radios_each must be at least 1")
    template = gateways[0]
    cli = template.argv[:template.argv.index("gateway")]
    names = list(radios.radios)
    made = []
    for group in (names[i:i + radios_each] for i in range(0, len(names), radios_each)):
        name = group[0] if len(group) == 1 else f"{group[0]}-{group[-1]}"
        radio_args = [arg for radio in group for arg in ("--radio", radio)]
        made.append(Process("gateway", name, [*cli, "gateway", "--config", str(radios_path), *radio_args,
                                              "--subscribe-each"], {**template.env, "FLEET_INSTANCE": name}))
    at = procs.index(template)
    rest = [p for p in procs if p not in gateways]
    return rest[:at] + made + rest[at:]


def with_args(procs: list[Process], extra: Mapping[str, list[str]]) -> list[Process]:
    """Each process of a service in `extra` with those arguments appended."""
    return [Process(p.service, p.instance, [*p.argv, *extra[p.service]], p.env) if p.service in extra else p
            for p in procs]


@contextmanager
def local_fleet(map_name: str, tasks: dict[str, Task], run_dir: Path, executors: int = 2, per_radio: int = 2,
                fleet: str = "demo", link: LinkModel | None = None, extra_args: Mapping[str, list[str]] | None = None,
                without: Iterable[str] = (), control: ControlMode = "offboard",
                gateway: GatewayParams | None = None, router_in_process: bool = False,
                radios_each: int = 1) -> Iterator[LocalFleet]:
    """compose.yaml's fleet with simulated Crazyflies for `tasks`, up and serving; stopped on exit.
    `extra_args`: more arguments per service; `without`: services not to start; `control`: every
    vehicle's control mode; `gateway`: the gateways' parameters (default: the radios file's);
    `radios_each`: radios per gateway process (`gateways_for_radios`);
    `router_in_process`: the router in this process (`LocalFleet.router`, to stop and restart it),
    not compose's router process (`bring_up`)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    radios = demo_radios(map_name, tasks, per_radio, link, control=control, gateway=gateway)
    radios_path = run_dir / "radios.yaml"
    radios_path.write_text(dump_radios(radios))
    overrides = {"FLEET_NAME": fleet, "FLEET_RADIOS": str(radios_path), "FLEET_EXECUTORS": str(executors),
                 "FLEET_RECORDINGS": str(run_dir.parent / "recordings")}
    adjust = partial(demo_processes, radios_path=radios_path, radios=radios, extra_args=extra_args or {},
                     without=set(without), radios_each=radios_each)
    with bring_up(run_dir, overrides, adjust=adjust, router_in_process=router_in_process) as local:
        yield local


def demo_processes(procs: list[Process], radios_path: Path, radios: RadiosFile,
                   extra_args: Mapping[str, list[str]], without: set[str], radios_each: int = 1) -> list[Process]:
    """compose.yaml's processes as the demo runs them: gateway processes for the simulated radios
    (one per radio, or per `radios_each`), some services left out, some with more arguments."""
    procs = [p for p in gateways_for_radios(procs, radios_path, radios, radios_each) if p.service not in without]
    return with_args(procs, extra_args)


def run_demo(args: argparse.Namespace) -> int:
    path = Path(args.scenario or (FLY_SCENARIO if args.vehicles == "fly" else DEMO_SCENARIO))
    scenario = read_scenario(path)
    map_name = scenario.map or "town"
    tasks = dict(scenario.tasks)
    out = Path(args.out)
    if args.lead is not None and not args.lead > 0:
        raise InputError("fleet demo", "--lead", f"{args.lead:g}: must be positive")
    timing = MissionTiming() if args.lead is None else MissionTiming(start_lead_s=args.lead)
    spec = MissionSpec(map=map_name, tasks=tasks, planner=args.planner, mu=args.mu, time_limit=args.time_limit,
                       timing=timing)
    try:
        demo_radios(map_name, tasks, args.per_radio, source=str(path))  # bad starts: an error before any process
        viewer = (["--viewer"] if args.viewer else []) + (["--web"] if args.web else [])
        with local_fleet(map_name, tasks, out / "run", args.executors, args.per_radio,
                         extra_args={"telemetry": viewer}, control=args.control) as fleet:
            runner = MissionRunner(spec, fleet.client_config(), fleet.keys)
            asyncio.run(runner.run())
    except RuntimeError as exc:
        print(f"demo: {exc}", file=sys.stderr)
        return 1
    result = runner.result
    if result is None:
        print("demo: the mission did not run")
        return 1
    print(result.summary())
    print(f"rerun recording: {out / 'recordings' / (spec.mission + '.rrd')} (open with `rerun FILE`)")
    return 0 if result.ok else 1
