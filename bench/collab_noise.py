"""Paper 002 under sensing noise: how often team plans still bring the drone to its goal.

Plans seeded problems on the office maps with PAD (the paper's primitives, as bench.collab_experiment)
and executes each plan in the simulated world (`services/sim/team/world.py`) with range and bearing
noise on the drone's sensing (`SensingNoise`, 002 §III-B), several noise draws per plan, two ways:

- `TeamSim` alone: the offline executor, which fails on the first action that ends off its planned
  end (no handling);
- the fleet's executor logic (`TeamRobot`, `services/executor/team_robots.py`, without zenoh): both
  robots' sequences with their sync points, re-trying a drone step that ended in a neighbouring
  cell (up to `RETRIES` times).

Success: every step done and the drone within 0.25 m of the goal (`fleet mission team`'s test).

    python -m bench.collab_noise [--maps office-conference office-cubicles] [--problems 10] [--draws 5]
                                 [--out out/collab_noise.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from common.bus.messages import ActionStatus, VehicleTeamPlan
from common.domain import team_plan as tp
from common.team.maps import load_env
from services.executor.team_robots import TeamRobot
from services.planner.collab.instances import sample_problem
from services.planner.collab.lattice import SlcOptions
from services.planner.collab.pad import PadConfig
from services.planner.collab.planner import TeamPlanner
from services.sim.team.world import SensingNoise, TeamSim, TeamWorld

MAPS = ("office-conference", "office-cubicles")
LEVELS: tuple[tuple[float, float], ...] = ((0.0, 0.0), (0.05, 2.0), (0.1, 5.0), (0.15, 7.5), (0.2, 10.0),
                                           (0.3, 15.0))
"""(range std m, bearing std deg) levels, from none to about 60 % of a 0.5 m cell along a wall."""
GOAL_M = 0.25
"""The mission's goal tolerance (`services/mission/team_mission.py`)."""
EPS_TRACK = 2.0


def execute(plan: tp.TeamPlan, world: TeamWorld, max_actions: int = 10_000) -> tuple[bool, int, str]:
    """Both robots' sequences through `TeamRobot` (the executor's logic, re-tries included) in
    `world`, one action at a time, sync points honoured: (success, re-tries, failure)."""
    robots = {r: TeamRobot(VehicleTeamPlan(vid=r, mission="m", robot=r, partner=tp.PlanProgress.other(r), plan=plan),
                           owner="bench") for r in tp.ROBOTS}
    for robot in robots.values():
        robot.start(0.0)
    now = 0.0
    for _ in range(max_actions):
        sent = False
        for name, robot in robots.items():
            robot.partner_progress(robots[tp.PlanProgress.other(name)].done)
            action = robot.action(now)
            if action is None:
                continue
            sent = True
            out = world.outcome(name, action.step)
            world.apply(name, out)
            robot.on_status(ActionStatus(vid=name, mission="m", index=action.index, status="done" if out.ok else "failed",
                                         pose=world.xyz(name), t=now, detail=out.detail, attempt=action.attempt))
        if any(r.failure for r in robots.values()) or all(r.finished for r in robots.values()):
            break
        if not sent:
            return False, 0, "deadlock"
        now += 1.0
    retries = sum(r.retries for r in robots.values())
    failure = next((f"{n}: {r.failure}" for n, r in robots.items() if r.failure), "")
    ok = not failure and all(r.finished for r in robots.values()) and math.dist(world.xyz("drone"), plan.goal) <= GOAL_M
    return ok, retries, failure


def run(maps: Sequence[str], problems: int, draws: int, levels: Sequence[tuple[float, float]] = LEVELS,
        time_limit: float = 10.0, log: Callable[[str], None] | None = None) -> dict:
    """Plan `problems` seeded problems per map (PAD, first solution within `time_limit`), execute each
    plan `draws` times per noise level both ways; success rates and re-tries per map and level."""
    out: dict = {"problems": problems, "draws": draws, "levels": [list(x) for x in levels], "maps": {}}
    for name in maps:
        t0 = time.perf_counter()
        planner = TeamPlanner(load_env(name), options=SlcOptions.paper())
        plans = []
        for seed in range(problems):
            res = planner.plan(sample_problem(planner, seed), "pad", time_limit, 0.0, pad_config=PadConfig(eps_track=EPS_TRACK))
            if res.plan is not None:
                plans.append(res.plan)
        rows = []
        for rng_std, bearing in levels:
            noise = SensingNoise(rng_std, bearing)
            plain = handled = retries = 0
            for i, plan in enumerate(plans):
                for d in range(draws):
                    seed = 1000 * i + d
                    plain += TeamSim(planner.sensing, plan, noise, seed).run().reached_goal
                    world = TeamWorld(planner.sensing, plan.drone_start, plan.ugv_start, noise, seed)
                    ok, n, _ = execute(plan, world)
                    handled += ok
                    retries += n
            runs = len(plans) * draws
            rows.append({"range_std": rng_std, "bearing_std_deg": bearing, "runs": runs,
                         "plain": plain / runs if runs else math.nan, "handled": handled / runs if runs else math.nan,
                         "retries_per_run": retries / runs if runs else math.nan})
            if log:
                log(f"[{name}] range {rng_std:.2f} m, bearing {bearing:.1f} deg: without re-tries "
                    f"{rows[-1]['plain']:.0%}, with {rows[-1]['handled']:.0%} ({rows[-1]['retries_per_run']:.2f} re-tries/run)")
        steps = [len(p.drone) for p in plans]
        out["maps"][name] = {"plans": len(plans), "drone_steps": sum(steps) / len(steps) if steps else 0, "rows": rows,
                             "seconds": time.perf_counter() - t0}
    return out


def table(r: dict) -> tuple[list[str], list[list[object]]]:
    headers = ["map", "range std m", "bearing std deg", "runs", "success, no re-try", "success, executor re-tries",
               "re-tries per run"]
    rows = [[name, f"{x['range_std']:.2f}", f"{x['bearing_std_deg']:.1f}", x["runs"], f"{100 * x['plain']:.0f} %",
             f"{100 * x['handled']:.0f} %", f"{x['retries_per_run']:.2f}"]
            for name, m in r["maps"].items() for x in m["rows"]]
    return headers, rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench.collab_noise", description=__doc__.splitlines()[0])
    parser.add_argument("--maps", nargs="+", default=list(MAPS))
    parser.add_argument("--problems", type=int, default=10)
    parser.add_argument("--draws", type=int, default=5)
    parser.add_argument("--out", default="out/collab_noise.json")
    args = parser.parse_args(argv)
    if args.problems < 1 or args.draws < 1:
        parser.error("--problems and --draws must be positive")
    r = run(args.maps, args.problems, args.draws, log=lambda s: print(s, file=sys.stderr, flush=True))
    headers, rows = table(r)
    print("| " + " | ".join(headers) + " |")
    print("|" + "---|" * len(headers))
    for row in rows:
        print("| " + " | ".join(str(c) for c in row) + " |")
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
