"""`fleet gateway`: one Crazyradio's gateway over a radios file (common/deploy/radios.py, docs/radio.md)."""

from __future__ import annotations

import argparse
import os

from common.bus.args import add_zenoh_args, keys_from_args, run_service, zconfig_from_args
from common.deploy.radios import load_radios_for


def register(subparsers: argparse._SubParsersAction) -> None:
    gw = subparsers.add_parser("gateway", help="serve one Crazyradio's vehicles (real or simulated)")
    gw.add_argument("--config", required=True, help="radios file (YAML, docs/radio.md)")
    gw.add_argument("--radio", required=True, help="the radio of the file this process serves")
    gw.add_argument("--subscribe-each", action="store_true",
                    help="subscribe to each own vehicle's cmd key instead of vehicle/*/cmd (large fleets)")
    add_zenoh_args(gw)
    gw.set_defaults(handler=_gateway, instance=os.environ.get("FLEET_INSTANCE"))  # default: the radio's name


def _gateway(args: argparse.Namespace) -> int:
    from services.radio_gateway.gateway import RadioGateway

    spec = load_radios_for(args.config, [args.radio])
    return run_service(RadioGateway(args.radio, spec, zconfig_from_args(args), instance=args.instance,
                                    keys=keys_from_args(args), subscribe_each=args.subscribe_each))
