"""The telemetry recorder's cost per vehicle (issue 15): the CPU `fleet telemetry` spends to draw a
mission into its rerun recording, the streams at the rates a fleet publishes them (each vehicle's
state at the executor's 20 Hz, its ground truth at the simulator's 100 Hz, its gateway's telemetry
at 5 Hz), through the recorder's own handlers (thinned to `fleet telemetry --max-hz`, 20 Hz, per
stream by the samples' times) into a recording written to a file; zenoh's delivery and decoding excluded.

Prints the recorder's CPU as a share of one core per second of mission, and how many vehicles one
core records in real time; saves a PNG. (Measured 2026-12-04: 2.5 % of a core per vehicle, almost
all of it rerun's per-call cost of `rr.log`; sending the same rows as columns every 0.5 s took
0.75 %, but the live view's test failed with it and it was not kept: docs/reliability.md.)

    python -m bench.recorder_cost [--vehicles 8] [--seconds 30]
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.bus.keys import Keys
from common.bus.messages import SimTruth, Telemetry, VehicleState
from common.bus.session import ZenohConfig
from services.telemetry.rerun_log import FleetRecording
from services.telemetry.service import TelemetryService

TRUTH_HZ, STATE_HZ, TELEMETRY_HZ = 100, 20, 5
"""The streams' rates in a fleet: the simulator's frames, the executor's `state_hz`, the gateway's `status_hz`."""


def measure(vehicles: int, seconds: float, out: Path) -> float:
    """CPU seconds the recorder spends per second of a mission of `vehicles` driving in circles."""
    keys = Keys("bench")
    svc = TelemetryService("bench", ZenohConfig.client("tcp/127.0.0.1:1"), keys, out=out)
    svc.recording = FleetRecording("bench", out / "bench.rrd")
    on_truth = svc._with_recording(FleetRecording.log_truth)
    on_telemetry = svc._with_recording(FleetRecording.log_telemetry)
    vids = [f"cf{i}" for i in range(vehicles)]
    t0 = time.time()
    start = time.process_time()
    for tick in range(round(seconds * TRUTH_HZ)):
        s = tick / TRUTH_HZ
        for k, vid in enumerate(vids):
            x, y = k + 0.3 * math.cos(s), 0.3 * math.sin(s)
            on_truth(SimTruth(vid=vid, t=t0 + s, x=x, y=y, z=0.0, yaw=s), keys.sim_truth(vid))
            if tick % (TRUTH_HZ // STATE_HZ) == 0:
                svc._on_state(VehicleState(vid=vid, t=t0 + s, owner="bench", mode="driving", x=x, y=y, z=0.0,
                                           yaw=s, mission="bench"), keys.vehicle(vid, "state"))
            if tick % (TRUTH_HZ // TELEMETRY_HZ) == 0:
                on_telemetry(Telemetry(vid=vid, t=t0 + s, gateway="r0", vbat=4.0 - 1e-4 * s, link_quality=1.0,
                                       sent=tick, dropped=0, cmd_rate_hz=100.0), keys.vehicle(vid, "telemetry"))
    svc.recording.close()
    return (time.process_time() - start) / seconds


def main() -> None:
    parser = bench_parser(__doc__)
    parser.add_argument("--vehicles", type=int, nargs="+", default=[1, 8, 32])
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    rows, shares = [], []
    for n in args.vehicles:
        with tempfile.TemporaryDirectory() as tmp:
            share = measure(n, args.seconds, Path(tmp))
        shares.append(share)
        rows.append([n, f"{100 * share:.1f}", f"{100 * share / n:.2f}", f"{n / share:.0f}"])
    print(format_table(["vehicles", "% of a core", "% per vehicle", "vehicles/core"], rows))
    print(f"cost: the recorder's handlers and rerun, {STATE_HZ} Hz states, {TRUTH_HZ} Hz truth, "
          f"{TELEMETRY_HZ} Hz telemetry per vehicle, process CPU time per mission second")
    fig, (ax,) = new_figure()
    ax.plot(args.vehicles, [100 * s for s in shares], "o-")
    ax.set_xlabel("vehicles recorded")
    ax.set_ylabel("% of one core")
    ax.set_title("telemetry recorder cost")
    print(f"figure: {save_figure(fig, args.out, 'recorder_cost')}")


if __name__ == "__main__":
    main()
