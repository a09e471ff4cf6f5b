"""`fleet gateway`: one Crazyradio's gateway over a radios file (common/deploy/radios.py, docs/radio.md)."""

from __future__ import annotations

import argparse
import os

from common.bus.args import add_zenoh_args, keys_from_args, run_services, zconfig_from_args
from common.deploy.radios import load_radios_for
from common.errors import InputError


def register(subparsers: argparse._SubParsersAction) -> None:
    gw = subparsers.add_parser("gateway", help="serve one Crazyradio's vehicles (real or simulated)")
    gw.add_argument("--config", required=True, help="radios file (YAML, docs/radio.md)")
    gw.add_argument("--radio", required=True, action="append",
                    help="a radio of the file this process serves; repeat it to serve several radios in one "
                         "process, each its own gateway named after its radio (--instance names a lone radio's)")
    gw.add_argument("--subscribe-each", action="store_true",
                    help="subscribe to each own vehicle's cmd key instead of vehicle/*/cmd (large fleets)")
    add_zenoh_args(gw)
    gw.set_defaults(handler=_gateway, instance=None)  # default: FLEET_INSTANCE, else the radio's name


def _gateway(args: argparse.Namespace) -> int:
    from services.radio_gateway.gateway import RadioGateway

    radios = list(dict.fromkeys(args.radio))
    spec = load_radios_for(args.config, radios)
    if len(radios) > 1 and args.instance is not None:
        raise InputError("fleet gateway", "--instance", "names one radio's gateway: several radios' are named "
                         "after their radios")
    instance = (args.instance or os.environ.get("FLEET_INSTANCE")) if len(radios) == 1 else None
    return run_services([RadioGateway(radio, spec, zconfig_from_args(args), instance=instance, keys=keys_from_args(args),
                                      subscribe_each=args.subscribe_each) for radio in radios])
