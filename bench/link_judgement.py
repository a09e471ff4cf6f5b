"""How often a lossy link that is up gets judged lost by the gateway's rule (docs/radio.md, "When a
link is lost"): no log block for `link_timeout_s` (1 s). The firmware streams the gateway's log block
every `log_period_s`; each block is lost with probability `loss` (the radio's downlink, after its
retries). The gateway's real `LinkHealth` runs on a simulated clock (no I/O) for each loss and block
period; every `link_lost` it reports is false (the link never goes down). Also the packets per second
the rule costs the radio: the log blocks ride in the acknowledgements of what the gateway sends
anyway, so none on the uplink. Prints the table; saves out/link_judgement.png.

    .venv/bin/python -m bench.link_judgement [--seconds 3000] [--out out/]
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from pathlib import Path

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.deploy.radios import GatewayParams
from services.radio_gateway.health import LinkHealth

PERIODS = (0.1, 0.2)
"""Log block periods (s): the default 10 Hz, and 5 Hz."""
LOSSES = (0.05, 0.10, 0.20, 0.30)
VEHICLES = 3
TICK_S = 0.01


@dataclass(frozen=True)
class Row:
    period: float
    loss: float
    false_lost: int
    vehicle_s: float


def measure(period: float, loss: float, seconds: float, seed: int = 1) -> Row:
    rng = random.Random(seed)
    timeout = GatewayParams().link_timeout_s
    links = [LinkHealth(0.0, timeout, period) for _ in range(VEHICLES)]
    lost = 0
    now = 0.0
    next_block = [rng.uniform(0.0, period) for _ in range(VEHICLES)]
    while now < seconds:
        now += TICK_S
        for i, health in enumerate(links):
            if now >= next_block[i]:
                next_block[i] += period
                if rng.random() >= loss:
                    health.on_log({"pm.vbatMV": 3900, "supervisor.info": 0x020E}, now)
            events = health.check(now)
            lost += sum(kind == "link_lost" for kind, _ in events)  # the next block brings it back
    return Row(period, loss, lost, VEHICLES * seconds)


def plot(rows: list[Row], out: Path) -> Path:
    fig, (ax,) = new_figure()
    for period in PERIODS:
        mine = [r for r in rows if r.period == period]
        ax.plot([100 * r.loss for r in mine], [3600 * r.false_lost / r.vehicle_s for r in mine], "o-",
                label=f"log block every {period:g} s")
    ax.set_xlabel("log blocks lost (%)")
    ax.set_ylabel("false link_lost per vehicle-hour")
    ax.set_title("Link judged lost while up (1 s without a log block)")
    ax.legend()
    return save_figure(fig, out, "link_judgement")


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3000.0, help="simulated seconds per period and loss")
    args = parser.parse_args()
    rows = [measure(period, loss, args.seconds) for period in PERIODS for loss in LOSSES]
    print(format_table(
        ["log block period s", "loss", "false link_lost", "vehicle-s", "per vehicle-hour"],
        [(f"{r.period:g}", f"{r.loss:.2f}", r.false_lost, f"{r.vehicle_s:.0f}",
          f"{3600 * r.false_lost / r.vehicle_s:.2f}") for r in rows]))
    print(f"figure: {plot(rows, Path(args.out))}")


if __name__ == "__main__":
    main()
