"""`fleet demo`: the whole fleet on one machine with no setup (paper 000 §VII-C: 8 flying cars in
the miniature town, two per Crazyradio). An in-process zenoh router; the planner, executors, radio
gateways, simulated Crazyflies, simulated motion capture and the telemetry recorder as separate
processes (the services of compose.yaml); the mission run from here; a summary at the end.
Exit 0 only if every vehicle arrived and no two bodies came into contact."""

from __future__ import annotations

import argparse
import asyncio
import math
import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from common.bus.keys import Keys
from common.bus.liveliness import watch_alive
from common.bus.session import InProcessRouter, ZenohConfig, open_session
from common.deploy.compose import Process
from common.deploy.credentials import Credentials, make_credentials
from common.deploy.launcher import start, stop
from common.deploy.radios import LinkModel, RadiosFile, RadioSpec, VehicleLink, dump_radios
from common.domain.mapfile import MAPS_DIR, decode_yaml, read_text
from common.domain.planfile import Task
from services.mission.runner import MissionRunner, MissionSpec
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.maps.loading import load_graph
from services.planner.maps.scenario import ScenarioFile, check_tasks

DEMO_SCENARIO = MAPS_DIR / "scenarios" / "town_8.yaml"


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def demo_radios(graph: FleetGraph, tasks: dict[str, Task], per_radio: int = 2,
                link: LinkModel | None = None) -> RadiosFile:
    """Simulated Crazyflies on their start spots, `per_radio` to a radio (the paper found 2 reliable)."""
    radios: dict[str, dict[str, VehicleLink]] = {}
    for i, (vid, task) in enumerate(tasks.items()):
        x, y, z = (float(v) for v in graph.pos[graph.index[task.start]])
        radios.setdefault(f"radio{i // per_radio}", {})[vid] = VehicleLink(
            uri=f"udp://127.0.0.1:{free_udp_port()}", start=(x, y, z), yaw=parked_yaw(graph, task.start))
    return RadiosFile(radios={name: RadioSpec(vehicles=v, link=link or LinkModel()) for name, v in radios.items()})


def parked_yaw(graph: FleetGraph, spot: str) -> float:
    """A parked car faces the road it leaves by (its spot's access edge)."""
    i = graph.index[spot]
    out = graph.out_edges[i]
    if not len(out):
        return 0.0
    dx, dy, _ = graph.pos[graph.edges[out[0], 1]] - graph.pos[i]
    return float(math.atan2(dy, dx))


def fleet_processes(radios_path: Path, radios: RadiosFile, executors: int, rrd_dir: Path,
                    viewer: bool = False, web: bool = False) -> list[Process]:
    """The services of one fleet, as local processes of this Python."""
    cli = [sys.executable, "-m", "services.cli"]
    cfg = ["--config", str(radios_path)]
    procs = [Process("planner", "planner", [*cli, "planner"])]
    procs += [Process("executor", f"executor-{i + 1}", [*cli, "executor"], {"FLEET_INSTANCE": f"executor-{i + 1}"})
              for i in range(executors)]
    procs.append(Process("sim", "sim", [*cli, "sim", *cfg]))
    procs += [Process("gateway", name, [*cli, "gateway", *cfg, "--radio", name], {"FLEET_INSTANCE": name})
              for name in radios.radios]
    procs.append(Process("mocap", "mocap", [*cli, "mocap"]))
    telemetry = [*cli, "telemetry", "--out", str(rrd_dir)] + (["--viewer"] if viewer else []) + (["--web"] if web else [])
    procs.append(Process("telemetry", "telemetry", telemetry))
    return procs


async def wait_for_services(config: ZenohConfig, keys: Keys, counts: dict[str, int], timeout: float) -> list[str]:
    """Wait until each service has its count of live instances; the ones still missing."""
    session = open_session(config)
    try:
        watches = {svc: await watch_alive(session, keys, svc) for svc in counts}
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            missing = [s for s, n in counts.items() if len(watches[s].instances) < n]
            if not missing:
                break
            await asyncio.sleep(0.2)
        for w in watches.values():
            w.close()
        return [s for s, n in counts.items() if len(watches[s].instances) < n]
    finally:
        session.close()


@dataclass
class LocalFleet:
    router: InProcessRouter
    keys: Keys
    run_dir: Path
    radios: RadiosFile
    credentials: Credentials

    def client_config(self) -> ZenohConfig:
        """A session of the operator role (`mission`): runs missions, watches, injects simulator faults."""
        return self.router.client_config(**self.credentials.options("mission"))


@contextmanager
def local_fleet(graph: FleetGraph, tasks: dict[str, Task], run_dir: Path, executors: int = 2, per_radio: int = 2,
                fleet: str = "demo", viewer: bool = False, web: bool = False,
                link: LinkModel | None = None) -> Iterator[LocalFleet]:
    """An in-process router and every service as a process, up and alive; stopped on exit.

    Secured as compose.yaml is: the router enforces deploy/router.json5 with role credentials made
    in run_dir/secrets, and each process authenticates with its role's (docs/security.md)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    radios = demo_radios(graph, tasks, per_radio, link)
    radios_path = run_dir / "radios.yaml"
    radios_path.write_text(dump_radios(radios))
    keys = Keys(fleet)
    creds = make_credentials(run_dir / "secrets")
    with InProcessRouter(**creds.router_options()) as router:
        procs = fleet_processes(radios_path, radios, executors, run_dir.parent / "recordings", viewer, web)
        for p in procs:
            p.env.update({"FLEET_ZENOH_CONNECT": router.endpoint, "FLEET_NAME": keys.fleet, **creds.env(p.service)})
        print(f"fleet: router on {router.endpoint}; starting {len(procs)} processes (logs in {run_dir / 'logs'})")
        start(procs, run_dir, settle_s=0.1)
        try:
            counts = {"planner": 1, "executor": executors, "gateway": len(radios.radios), "sim": 1, "mocap": 1,
                      "telemetry": 1}
            local = LocalFleet(router, keys, run_dir, radios, creds)
            missing = asyncio.run(wait_for_services(local.client_config(), keys, counts, 60.0))
            if missing:
                raise RuntimeError(f"services not up within 60 s: {', '.join(missing)} (see {run_dir / 'logs'})")
            yield local
        finally:
            stop(run_dir, grace_s=5.0)


def run_demo(args: argparse.Namespace) -> int:
    path = Path(args.scenario or DEMO_SCENARIO)
    scenario: ScenarioFile = decode_yaml(read_text(path), ScenarioFile, str(path))
    map_name = scenario.map or "town"
    graph = load_graph(map_name)
    tasks = dict(scenario.tasks)
    check_tasks(tasks, graph, str(path))
    out = Path(args.out)
    spec = MissionSpec(map=map_name, tasks=tasks, planner=args.planner, mu=args.mu, time_limit=args.time_limit)
    try:
        with local_fleet(graph, tasks, out / "run", args.executors, args.per_radio, viewer=args.viewer,
                         web=args.web) as fleet:
            runner = MissionRunner(spec, fleet.client_config(), fleet.keys)
            asyncio.run(runner.run())
    except RuntimeError as exc:
        print(f"demo: {exc}")
        return 1
    result = runner.result
    if result is None:
        print("demo: the mission did not run")
        return 1
    print(result.summary())
    print(f"rerun recording: {out / 'recordings' / (spec.mission + '.rrd')} (open with `rerun FILE`)")
    return 0 if result.ok else 1


