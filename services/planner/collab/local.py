"""`fleet collab mission --local`: a ground-air team's services on this machine (paper 002 run end
to end): an in-process zenoh router, and the planner, the executors and the collab simulator as
processes of this Python, up and alive; stopped on exit.

The router runs without access control: the role table (`common/deploy/acl.py`) has no rows for the team
keys (`vehicle/<vid>/{team_plan,action,action_status}`) yet.
"""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from common.bus.keys import Keys
from common.bus.messages import TeamTask
from common.bus.session import InProcessRouter, ZenohConfig
from common.deploy.compose import Process
from common.deploy.launcher import start, stop
from services.mission.demo import wait_for_services


def _xyz(v: tuple[float, float, float]) -> str:
    return ",".join(f"{x:g}" for x in v)


def team_processes(map_name: str, team: TeamTask, executors: int, time_scale: float) -> list[Process]:
    """The planner, `executors` executors and the simulated team (robots at the task's starts)."""
    cli = [sys.executable, "-m", "services.cli"]
    procs = [Process("planner", "planner", [*cli, "planner"])]
    procs += [Process("executor", f"executor-{i + 1}", [*cli, "executor"], {"FLEET_INSTANCE": f"executor-{i + 1}"})
              for i in range(executors)]
    procs.append(Process("collab-sim", "collab-sim", [
        *cli, "collab", "sim", "--map", map_name, "--drone-id", team.drone, "--ugv-id", team.ugv,
        "--start", _xyz(team.drone_start), "--ugv", _xyz(team.ugv_start), "--time-scale", f"{time_scale:g}"]))
    return procs


@contextmanager
def local_team(map_name: str, team: TeamTask, run_dir: Path, executors: int = 2, time_scale: float = 10.0,
               fleet: str = "collab") -> Iterator[tuple[ZenohConfig, Keys]]:
    """Everything a team mission needs, running; yields the client configuration and the keys."""
    run_dir.mkdir(parents=True, exist_ok=True)
    keys = Keys(fleet)
    with InProcessRouter() as router:
        procs = team_processes(map_name, team, executors, time_scale)
        for p in procs:
            p.env.update({"FLEET_ZENOH_CONNECT": router.endpoint, "FLEET_NAME": keys.fleet})
        print(f"collab: router on {router.endpoint}; starting {len(procs)} processes (logs in {run_dir / 'logs'})")
        start(procs, run_dir, settle_s=0.1)
        try:
            counts = {"planner": 1, "executor": executors, "collab-sim": 1}
            missing = asyncio.run(wait_for_services(router.client_config(), keys, counts, 60.0))
            if missing:
                raise RuntimeError(f"services not up within 60 s: {', '.join(missing)} (see {run_dir / 'logs'})")
            yield router.client_config(), keys
        finally:
            stop(run_dir, grace_s=5.0)
