"""How often a lossy link that is up gets judged lost, by the gateway's rule (docs/radio.md, "When a
link is lost"): silence alone for `link_timeout_s` (the rule before), against silence with
`lost_after_requests` unanswered requests and 20 Hz probing of a silent vehicle (the rule now).

The gateway's real `Scheduler` and `VehicleChannel`s run on a simulated clock (no I/O): three
hovering vehicles on one radio, every status request and its reply each lost with probability
`loss`, replies after 4 ms. Counts the `link_lost` events (every one false: the link never goes
down) and the status requests sent per vehicle per second. Prints the table; saves
out/link_judgement.png.

    .venv/bin/python -m bench.link_judgement [--seconds 3000] [--out out/]
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from pathlib import Path

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.crazyflie import crtp
from common.deploy.radios import GatewayParams
from services.radio_gateway.scheduler import Scheduler
from services.radio_gateway.vehicle import VehicleChannel

RULES = {"silence only (before)": GatewayParams(probe_hz=1e-6, lost_after_requests=1),
         "probes + 10 unanswered (now)": GatewayParams()}
LOSSES = (0.05, 0.10, 0.20, 0.30)
VEHICLES = 3
TICK_S = 0.01
REPLY_S = 0.004


@dataclass(frozen=True)
class Row:
    rule: str
    loss: float
    false_lost: int
    vehicle_s: float
    requests_hz: float


def measure(rule: str, loss: float, seconds: float, seed: int = 1) -> Row:
    rng = random.Random(seed)
    params = RULES[rule]
    chans = [VehicleChannel(f"v{i}", params, 0.0) for i in range(VEHICLES)]
    by_vid = {ch.vid: ch for ch in chans}
    sched = Scheduler(chans, 500.0, params, 0.0)
    in_flight: list[tuple[float, VehicleChannel, crtp.Status]] = []
    lost = requests = 0
    now = 0.0
    while now < seconds:
        now += TICK_S
        arrived = [r for r in in_flight if r[0] <= now]
        in_flight = [r for r in in_flight if r[0] > now]
        for at, ch, status in arrived:
            ch.on_status(status, at)
        lost += sum(kind == "link_lost" for ch in chans for kind, _ in ch.supervise(now))
        batch, _ = sched.tick(now)
        for vid, raw in batch:
            packet = crtp.decode_uplink(raw)
            if not isinstance(packet, crtp.StatusRequest):
                continue
            requests += 1
            if rng.random() >= loss and rng.random() >= loss:  # the request, then its reply
                in_flight.append((now + REPLY_S, by_vid[vid], crtp.Status(
                    echo_sent=packet.sent, received=packet.sent, setpoints=0, vbat_mv=3900,
                    wheel_left_mm_s=0, wheel_right_mm_s=0, flags=0)))
    return Row(rule, loss, lost, VEHICLES * seconds, requests / seconds / VEHICLES)


def plot(rows: list[Row], out: Path) -> Path:
    fig, (ax,) = new_figure()
    for rule in RULES:
        mine = [r for r in rows if r.rule == rule]
        ax.plot([100 * r.loss for r in mine], [3600 * r.false_lost / r.vehicle_s for r in mine], "o-", label=rule)
    ax.set_xlabel("loss each way (%)")
    ax.set_ylabel("false link_lost per vehicle-hour")
    ax.set_title("Link judged lost while up")
    ax.legend()
    return save_figure(fig, out, "link_judgement")


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3000.0, help="simulated seconds per rule and loss")
    args = parser.parse_args()
    rows = [measure(rule, loss, args.seconds) for rule in RULES for loss in LOSSES]
    print(format_table(
        ["rule", "loss", "false link_lost", "vehicle-s", "per vehicle-hour", "requests/s/vehicle"],
        [(r.rule, f"{r.loss:.2f}", r.false_lost, f"{r.vehicle_s:.0f}", f"{3600 * r.false_lost / r.vehicle_s:.1f}",
          f"{r.requests_hz:.2f}") for r in rows]))
    print(f"figure: {plot(rows, Path(args.out))}")


if __name__ == "__main__":
    main()
