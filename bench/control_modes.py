"""Offboard against onboard control (issue 17, DESIGN.md "Vehicles") on the town mission of `fleet
demo` (8 flying cars, 2 to a simulated radio), under three link models: the default (2 ms, 1 %
loss), 50 ms more latency, and 10 % loss.

Each run is the whole fleet as `fleet demo` runs it (`services.mission.demo.local_fleet`: planner,
executors, one gateway per radio, the simulated Crazyflies and motion capture) with every vehicle
in one control mode. This process listens to the simulator's ground truth (`sim/truth/<vid>`) and
afterwards compares it with the reference the executors track, rebuilt from the plan in force at
the end (`services.executor.trajectory.Trajectory` of each vehicle's path from the mission start;
after a replan the spliced paths, and a vehicle that left the mission is not counted): tracking
RMS and max error in the air and on the ground (truth, not the executors' estimates), the vertical
speed at each touchdown, whether every vehicle arrived and the contacts between bodies.

    python -m bench.control_modes [--modes offboard,onboard] [--links default,latency,loss] [--out out]
"""

from __future__ import annotations

import asyncio
import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.bus.messages import SimTruth
from common.bus.pubsub import subscribe
from common.bus.session import open_session
from common.bus.vehicle_plans import vehicle_plans
from common.deploy.radios import GatewayParams, LinkModel
from common.domain.scenario import read_scenario
from services.executor.trajectory import Trajectory
from services.mission.client import MissionTiming
from services.mission.demo import DEMO_SCENARIO, local_fleet
from services.mission.runner import MissionRunner, MissionSpec

LINKS = {"default": LinkModel(), "latency": LinkModel(latency_s=0.052), "loss": LinkModel(loss=0.10)}
"""The default model; 50 ms more one-way latency (2 + 50 ms); 10 % of the packets lost each way."""
GATEWAYS = {"latency": GatewayParams(connect_timeout_s=60.0)}
"""cflib's connection (TOCs, parameters, log blocks) is hundreds of round trips: over 104 ms each it
takes longer than the default 10 s connect timeout; the mission waits as long for the links."""


@dataclass
class Run:
    """One mission's figures (m, m/s)."""

    mode: str
    link: str
    ok: bool = False
    reason: str = ""
    arrived: int = 0
    vehicles: int = 0
    contacts: int = 0
    air: list[float] = field(default_factory=list)
    ground: list[float] = field(default_factory=list)
    touchdowns: list[float] = field(default_factory=list)

    @staticmethod
    def _rms(errors: list[float]) -> float:
        return math.sqrt(sum(e * e for e in errors) / len(errors)) if errors else float("nan")

    def row(self) -> list[object]:
        td = self.touchdowns or [float("nan")]
        return [self.mode, self.link, f"{self.arrived}/{self.vehicles}", self.contacts,
                f"{100 * self._rms(self.air):.1f}", f"{100 * max(self.air, default=float('nan')):.1f}",
                f"{100 * self._rms(self.ground):.1f}", f"{sum(td) / len(td):.2f}", f"{max(td):.2f}"]


HEADERS = ["control", "link", "arrived", "contacts", "air rms cm", "air max cm", "ground rms cm",
           "touchdown mean m/s", "touchdown max m/s"]


def fly(mode: str, link: str, run_dir: Path) -> Run:
    """The town mission in control mode `mode` over link model `link`; its figures."""
    scenario = read_scenario(DEMO_SCENARIO)
    tasks = dict(scenario.tasks)
    map_name = scenario.map or "town"
    truth: list[SimTruth] = []
    spec = MissionSpec(map=map_name, tasks=tasks, time_limit=20.0, timing=MissionTiming(link_wait_s=60.0))
    with local_fleet(map_name, tasks, run_dir, executors=2, fleet=f"cm{mode[:2]}{link[:2]}", link=LINKS[link],
                     control=mode, gateway=GATEWAYS.get(link)) as fleet:  # type: ignore[arg-type]
        runner = MissionRunner(spec, fleet.client_config(), fleet.keys, progress=False)

        async def listen_and_fly() -> None:
            session = open_session(fleet.client_config())
            sub = subscribe(session, fleet.keys.all_sim_truth, SimTruth, lambda t, _k: truth.append(t),
                            maxlen=1_000_000)
            try:
                await runner.run()
            finally:
                sub.close()
                session.close()

        asyncio.run(listen_and_fly())
    result = runner.result
    out = Run(mode, link, vehicles=len(tasks))
    if result is None or result.plan is None or runner.t0 is None:
        return out
    out.ok, out.reason, out.contacts = result.ok, result.reason, result.contacts
    out.arrived = sum(r.arrived for r in result.vehicles.values())
    # the plan in force at the end (after a replan: every remaining vehicle's whole spliced path); a
    # vehicle that left the mission is not in it and not counted
    final = result.final_plan or result.plan
    refs = {p.vid: Trajectory(p.steps) for p in vehicle_plans(final, spec.mission, runner.t0).values()}
    last: dict[str, SimTruth] = {}
    for s in sorted(truth, key=lambda s: s.t):
        ref = refs.get(s.vid)
        if ref is None or s.t < runner.t0:
            continue
        rel = s.t - runner.t0
        r = ref.sample(rel)
        if rel <= ref.end_time:
            error = math.dist((s.x, s.y, s.z), (r.x, r.y, r.z))
            (out.air if s.airborne else out.ground).append(error)
        before = last.get(s.vid)
        if before is not None and before.airborne and not s.airborne:
            out.touchdowns.append(-before.vz)
        last[s.vid] = s
    return out


def figure(runs: list[Run], out_dir: str) -> Path:
    fig, (ax,) = new_figure(width=7.0)
    links = list(dict.fromkeys(r.link for r in runs))
    modes = list(dict.fromkeys(r.mode for r in runs))
    width = 0.8 / max(len(modes), 1)
    for k, mode in enumerate(modes):
        rms = [next((100 * Run._rms(r.air) for r in runs if r.mode == mode and r.link == link), 0.0) for link in links]
        worst = [next((100 * max(r.air, default=0.0) for r in runs if r.mode == mode and r.link == link), 0.0)
                 for link in links]
        xs = [i + (k - (len(modes) - 1) / 2) * width for i in range(len(links))]
        ax.bar(xs, rms, width, label=f"{mode} RMS")
        ax.scatter(xs, worst, marker="v", color="k", zorder=3, label="max" if k == 0 else None)
    ax.set_xticks(range(len(links)), links)
    ax.set_ylabel("tracking error in the air, ground truth (cm)")
    ax.set_title("town mission, 8 flying cars: control modes")
    ax.legend()
    return save_figure(fig, out_dir, "control_modes")


def main() -> None:
    parser = bench_parser(__doc__.split("\n\n")[0])
    parser.add_argument("--modes", default="offboard,onboard")
    parser.add_argument("--links", default=",".join(LINKS))
    args = parser.parse_args()
    runs = []
    with tempfile.TemporaryDirectory(prefix="control-modes-") as tmp:
        for link in args.links.split(","):
            for mode in args.modes.split(","):
                run = fly(mode, link, Path(tmp) / f"{mode}-{link}" / "run")
                print(format_table(HEADERS, [run.row()]).splitlines()[-1], flush=True)
                if not run.ok:
                    print(f"{mode}/{link}: {run.reason}", flush=True)
                runs.append(run)
    print(format_table(HEADERS, [r.row() for r in runs]))
    print(f"figure: {figure(runs, args.out)}")


if __name__ == "__main__":
    main()
