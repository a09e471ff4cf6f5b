"""The executor's control cycle without the bus, in one process: what its own code costs per vehicle.

An `ExecutorService` that never opens a session is given `--vehicles` plans (`bench.fleet_latency`'s:
a 100 m drive at 0.1 m/s, or with `--fly` a take-off and a long hover) and runs its cycle on a
simulated clock, back to back: a motion-capture frame of every vehicle fused (`_fuse`, the
proximity stop's bodies settled), the proximity stop, the held vehicles' standoff, the plan
clocks, every controller's tick and the command batches and states encoded (`_cycle`; each
message encoded as a publisher does, but not put on the bus). Thread CPU time per round of
`--cycles` cycles, per vehicle-cycle; the table gives the fastest round and the median of the
rounds after a warm-up.

Why beside `bench.fleet_latency` (the whole process, the bus and its threads included, the issue's
figure): that one's run-to-run spread on this 2-core virtual machine is +-10-15 % (the host's load),
more than most changes to the cycle; this one's fastest round moves by a few per cent, so a change
of the cycle can be weighed here, old and new code run one after the other. It is a floor, not an
executor's cost: the cycles follow each other with the caches warm, where an executor sleeps
between frames (the whole process costs about twice this, docs/control.md).

    python -m bench.executor_cycle [--vehicles 8,32,80] [--fly] [--rounds 12] [--cycles 300]
"""

from __future__ import annotations

import statistics
import time
from typing import Any

from bench.fleet_latency import bench_plan, where
from bench.tables import bench_parser, format_table, new_figure, plot_series, save_figure
from common.bus.keys import Keys
from common.bus.messages import Codec, FramePose, PoseFrame
from common.bus.pubsub import encode_message
from common.bus.session import ZenohConfig
from common.domain.vehicle_model import VehicleModel
from services.executor.service import ExecutorService
from services.executor.vehicle_controller import VehicleController

RATE_HZ = 100.0
CAPTURE_AGE_S = 0.004
"""s between a frame's capture and the cycle that fuses it."""
WARMUP_ROUNDS = 2
T0 = 1000.0


class EncodingSink:
    """Stands in for a publisher or a service's keyed publishers: encodes what it is given as a
    `Publisher` does (`encode_message`), sends nothing."""

    def __init__(self) -> None:
        self._codecs: dict[type, Codec[Any]] = {}

    def put(self, *args: Any) -> None:
        msg = args[-1]
        codec = self._codecs.get(type(msg))
        if codec is None:
            codec = self._codecs[type(msg)] = Codec(type(msg))
        encode_message(codec, msg)


def executor(n: int, fly: bool) -> tuple[ExecutorService, list[str]]:
    """An executor of `n` vehicles, each with its plan, started at `T0`; never connected."""
    svc = ExecutorService("bench", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("bench"))
    for name in ("_cmd", "_batch", "_state", "_states", "_event", "_delay"):
        setattr(svc, name, EncodingSink())
    vids = [f"v{i:03d}" for i in range(n)]
    for i, vid in enumerate(vids):
        plan = bench_plan(vid, 0.5 * i, T0, fly)
        svc.plans[vid] = plan
        ctl = svc.controllers[vid] = VehicleController(vid, VehicleModel(), owner="bench", bank=svc.bank)
        ctl.load(plan)
        ctl.start(T0)
        svc.gateway_of[vid] = f"g{i % 4}"
    return svc, vids


def measure(n: int, fly: bool, rounds: int, cycles: int) -> dict[str, float]:
    """us per vehicle-cycle (thread CPU time) of each round; the fastest and the median after the warm-up."""
    svc, vids = executor(n, fly)
    now, k = T0 - 0.5, 0
    costs = []
    for _ in range(rounds):
        start = time.thread_time()
        for _ in range(cycles):
            now += 1.0 / RATE_HZ
            t = now - CAPTURE_AGE_S
            frame = PoseFrame(t=t, seq=k, poses=[FramePose(v, *where(t, T0, 0.5 * i, fly), 0.0)
                                                 for i, v in enumerate(vids)])
            svc._fuse([frame])
            svc.bodies.settle(t)
            svc._stop_short(now)
            svc._keep_apart(now)
            svc._run_clocks(now)
            svc._cycle(now, k, t, t)
            k += 1
        costs.append(1e6 * (time.thread_time() - start) / (cycles * n))
    kept = costs[WARMUP_ROUNDS:] or costs
    modes = {str(ctl.mode) for ctl in svc.controllers.values()}
    return {"n": n, "fastest": min(kept), "median": statistics.median(kept), "modes": ", ".join(sorted(modes))}


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--vehicles", default="8,32,80")
    parser.add_argument("--fly", action="store_true", help="hover instead of driving")
    parser.add_argument("--rounds", type=int, default=12, help=f"rounds ({WARMUP_ROUNDS} of warm-up)")
    parser.add_argument("--cycles", type=int, default=300, help="control cycles a round")
    args = parser.parse_args()
    rows = [measure(int(v), args.fly, args.rounds, args.cycles) for v in args.vehicles.split(",")]
    print(format_table(["vehicles", "modes", "fastest us/vehicle-cycle", "median", "vehicles/core @100 Hz (fastest)"],
                       [[r["n"], r["modes"], f"{r['fastest']:.1f}", f"{r['median']:.1f}",
                         f"{1e6 / (RATE_HZ * r['fastest']):.0f}"] for r in rows]))
    print("thread CPU time of the cycle's own code, without the bus: a floor under bench.fleet_latency's "
          "whole-process figure")
    fig, (ax,) = new_figure(1)
    plot_series(ax, [r["n"] for r in rows], {"fastest round": [r["fastest"] for r in rows],
                                              "median round": [r["median"] for r in rows]},
                xlabel="vehicles", ylabel="us per vehicle-cycle", title="executor cycle without the bus")
    print(f"saved {save_figure(fig, args.out, 'executor_cycle')}")


if __name__ == "__main__":
    main()
