"""How many flying vehicles one simulated Crazyradio serves at 50 Hz (paper 000 §VI-C: two, reliably).

The figures come from the simulator's link model (docs/radio.md), not from a Crazyradio.

For n = 1, 2, ... flying vehicles on one radio with the default link model (docs/radio.md: 500
packets/s, 2 ms, 1 % loss), runs the real pieces in one process: an in-process zenoh router,
`fleet sim` (simulated Crazyflies over UDP), the radio's gateway and a stand-in executor commanding
every vehicle to hover at 100 Hz. After a warm-up it measures, at the vehicles, the flight setpoints
each one received per second (min and mean over the vehicles), the packets lost on the link (the
link model's own counts: lost and congested against delivered, uplink and downlink), the longest gap
between two setpoints, and commander watchdog trips. Prints the table and the capacity; saves out/radio_capacity.png.

    .venv/bin/python -m bench.radio_capacity [--max 12] [--seconds 3] [--out out/]
"""

from __future__ import annotations

import asyncio
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

from bench.tables import bench_parser, format_table, new_figure
from common.bus.keys import Keys
from common.bus.session import InProcessRouter
from common.deploy.radios import GatewayParams, LinkModel, simulated_radios
from services.radio_gateway.gateway import RadioGateway
from services.sim.crazyflie.service import SimService
from tests.support.loadgen import LoadCommander, running

TARGET_HZ = 50.0
PAPER_CAPACITY = 2


@dataclass(frozen=True)
class Row:
    n: int
    min_hz: float
    mean_hz: float
    drop_pct: float
    max_gap_ms: float
    watchdog: int


async def measure(router: InProcessRouter, n: int, seconds: float, warmup: float) -> Row:
    vids = [f"cf{i}" for i in range(n)]
    spec = simulated_radios({vid: (0.3 * i, 0.0, 0.0) for i, vid in enumerate(vids)}, per_radio=n)
    cfg, keys = router.client_config(), Keys(f"capacity{n}")
    sim = SimService(spec, cfg, keys=keys)
    gw = RadioGateway("r0", spec, cfg, keys=keys)
    cmd = LoadCommander("e1", cfg, flyers=vids, keys=keys)
    async with running(sim, gw, cmd):
        await asyncio.sleep(warmup)
        cfs = [sim.vehicles[v] for v in vids]
        for cf in cfs:
            cf.max_flight_gap = 0.0
        got0 = [cf.flight_setpoints for cf in cfs]
        radio = sim.radios["r0"]
        lost0, ok0 = radio.lost + radio.congested, radio.delivered
        t0 = time.monotonic()
        await asyncio.sleep(seconds)
        dt = time.monotonic() - t0
        rates = [(cf.flight_setpoints - g) / dt for cf, g in zip(cfs, got0, strict=True)]
        lost, ok = radio.lost + radio.congested - lost0, radio.delivered - ok0
        drop = lost / (lost + ok) if lost + ok else 0.0
        return Row(n, min(rates), statistics.fmean(rates), 100.0 * drop, 1000.0 * max(cf.max_flight_gap for cf in cfs),
                   sum(cf.watchdog_levels for cf in cfs))


def model_rate(n: int, link: LinkModel, params: GatewayParams) -> float:
    """What the schedule promises each of n flying vehicles: the budget left after the status
    requests, shared equally, at most one setpoint per tick (the gateway stops cflib's pings)."""
    return min(params.tick_hz, (link.budget_pps - n * params.status_hz) / n)


def plot(rows: list[Row], out: Path) -> Path:
    fig, (ax_rate, ax_drop) = new_figure(ncols=2)
    ns = [r.n for r in rows]
    ax_rate.plot(ns, [r.mean_hz for r in rows], "o-", label="achieved, mean")
    ax_rate.plot(ns, [r.min_hz for r in rows], "s--", label="achieved, worst vehicle")
    ax_rate.plot(ns, [model_rate(n, LinkModel(), GatewayParams()) for n in ns], ":", color="grey",
                 label="schedule: (budget - status) / n")
    ax_rate.axhline(TARGET_HZ, color="red", lw=0.8, label=f"{TARGET_HZ:.0f} Hz")
    ax_rate.axvline(PAPER_CAPACITY, color="black", lw=0.8, ls="-.", label="paper 000: 2 per radio")
    ax_rate.set_xlabel("flying vehicles on one radio")
    ax_rate.set_ylabel("flight setpoints received per vehicle (Hz)")
    ax_rate.legend(fontsize=7)
    ax_drop.plot(ns, [r.drop_pct for r in rows], "o-")
    ax_drop.set_xlabel("flying vehicles on one radio")
    ax_drop.set_ylabel("packets lost on the link (%)")
    ax_drop.set_ylim(bottom=0.0)
    fig.suptitle("One Crazyradio, default link model (500 packets/s, 1 % loss)")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / "radio_capacity.png"
    fig.savefig(path, dpi=120)
    return path


async def main_async(max_n: int, seconds: float, warmup: float) -> list[Row]:
    rows = []
    with InProcessRouter() as router:
        for n in range(1, max_n + 1):
            rows.append(await measure(router, n, seconds, warmup))
            r = rows[-1]
            print(f"  n={n}: {r.min_hz:.1f} Hz worst, {r.mean_hz:.1f} Hz mean, {r.drop_pct:.1f} % lost", flush=True)
    return rows


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--max", type=int, default=12, help="most flying vehicles tried")
    parser.add_argument("--seconds", type=float, default=3.0, help="measurement per point (s)")
    parser.add_argument("--warmup", type=float, default=1.0, help="warm-up per point (s)")
    args = parser.parse_args()
    rows = asyncio.run(main_async(args.max, args.seconds, args.warmup))
    print(format_table(
        ["flying", "worst Hz", "mean Hz", "schedule Hz", "lost %", "max gap ms", "watchdog"],
        [[r.n, f"{r.min_hz:.1f}", f"{r.mean_hz:.1f}", f"{model_rate(r.n, LinkModel(), GatewayParams()):.1f}",
          f"{r.drop_pct:.1f}", f"{r.max_gap_ms:.0f}", r.watchdog] for r in rows]))
    served = [r.n for r in rows if r.min_hz >= TARGET_HZ]
    capacity = max((n for n in served if all(m in served for m in range(1, n + 1))), default=0)
    print(f"one simulated radio serves {capacity} flying vehicles at >= {TARGET_HZ:.0f} Hz each "
          f"(paper 000 §VI-C, a real Crazyradio: {PAPER_CAPACITY})")
    print("NOTE: these figures come from the simulated radio's link model (docs/radio.md: budget, latency and "
          "loss assumed), not from a Crazyradio; a real radio's capacity must be measured on hardware.")
    print(f"figure: {plot(rows, Path(args.out))}")


if __name__ == "__main__":
    main()
