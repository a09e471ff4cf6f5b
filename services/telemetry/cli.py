"""`fleet telemetry`: the command line of the telemetry recorder (`services/telemetry/service.py`)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from common.bus.args import add_zenoh_args, lazy_handler


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("telemetry", help="record the fleet to rerun (.rrd per mission, live viewer optional)")
    p.add_argument("--out", type=Path, default=Path("out/recordings"), help="directory for .rrd files")
    p.add_argument("--viewer", action="store_true", help="spawn the rerun viewer")
    p.add_argument("--web", action="store_true", help="serve the rerun web viewer (the recording is still written)")
    p.add_argument("--web-port", type=int, default=int(os.environ.get("FLEET_WEB_PORT", 9090)),
                   help="the web viewer's HTTP port (env FLEET_WEB_PORT)")
    p.add_argument("--grpc-port", type=int, default=int(os.environ.get("FLEET_GRPC_PORT", 9876)),
                   help="the port the web viewer reads the live recording from (env FLEET_GRPC_PORT)")
    p.add_argument("--max-hz", type=float, default=20.0, help="most samples drawn per second per vehicle and stream")
    p.add_argument("--nice", type=int, default=10,
                   help="lower the recorder's CPU priority by this much (it must not delay the control loops)")
    add_zenoh_args(p, default_instance="telemetry")
    p.set_defaults(handler=lazy_handler("services.telemetry.service:cmd_telemetry"))
