"""`fleet executor`: the command line of the executor service (`services/executor/service.py`)."""

from __future__ import annotations

import argparse

from common.bus.args import add_zenoh_args, lazy_handler


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("executor", help="run an executor: control loops for the vehicles it owns")
    p.add_argument("--rate", type=float, default=100.0, help="control rate (Hz)")
    p.add_argument("--state-rate", type=float, default=20.0, help="state publication rate (Hz)")
    p.add_argument("--no-tracking-guard", dest="tracking_guard", action="store_false",
                   help="do not hold vehicles whose tracking leaves the plan's margin (rehearsals and tests only: "
                        "without the guard a slow control loop can bring bodies into contact)")
    p.add_argument("--no-tracking-pause", dest="tracking_pause", action="store_false",
                   help="hold a flyer whose tracking leaves the plan's margin at once, instead of pausing its "
                        "mission while it gets back onto its plan (tests of the guard's hold)")
    p.add_argument("--no-plan-clock", dest="plan_clock", action="store_false",
                   help="run plans on the wall clock: the plan's clock does not wait for vehicles behind their "
                        "plans (comparisons only: a late vehicle then meets the others on time)")
    add_zenoh_args(p, default_instance="executor")
    p.set_defaults(handler=lazy_handler("services.executor.service:cmd_executor"))
