"""`fleet gateway` (one radio's gateway) and `fleet sim` (the simulated Crazyflies) over a radios file
(common/deploy/radios.py, docs/radio.md)."""

from __future__ import annotations

import argparse
import os

from common.bus.args import add_zenoh_args, keys_from_args, run_service, zconfig_from_args
from common.deploy.radios import RadiosFile, load_radios
from common.errors import InputError


def register(subparsers: argparse._SubParsersAction) -> None:
    gw = subparsers.add_parser("gateway", help="serve one Crazyradio's vehicles (real or simulated)")
    gw.add_argument("--config", required=True, help="radios file (YAML, docs/radio.md)")
    gw.add_argument("--radio", required=True, help="the radio of the file this process serves")
    gw.add_argument("--subscribe-each", action="store_true",
                    help="subscribe to each own vehicle's cmd key instead of vehicle/*/cmd (large fleets)")
    add_zenoh_args(gw)
    gw.set_defaults(handler=_gateway, instance=os.environ.get("FLEET_INSTANCE"))  # default: the radio's name

    sim = subparsers.add_parser("sim", help="simulated Crazyflies for the udp:// vehicles of a radios file")
    sim.add_argument("--config", required=True, help="radios file (YAML, docs/radio.md)")
    sim.add_argument("--radio", action="append", help="simulate only this radio's vehicles (repeatable)")
    sim.add_argument("--truth-hz", type=float, default=100.0, help="ground-truth rate on sim/truth/<vid> (Hz)")
    add_zenoh_args(sim, default_instance="sim")
    sim.set_defaults(handler=_sim)


def _load(path: str, radios: list[str]) -> RadiosFile:
    spec = load_radios(path)
    for name in radios:
        if name not in spec.radios:
            raise InputError(path, "--radio", f"no radio {name!r} (the file has {', '.join(spec.radios)})")
    return spec


def _gateway(args: argparse.Namespace) -> int:
    from services.radio_gateway.gateway import RadioGateway

    spec = _load(args.config, [args.radio])
    return run_service(RadioGateway(args.radio, spec, zconfig_from_args(args), instance=args.instance,
                                    keys=keys_from_args(args), subscribe_each=args.subscribe_each))


def _sim(args: argparse.Namespace) -> int:
    from services.sim.crazyflie.service import SimService

    spec = _load(args.config, args.radio or [])
    if args.truth_hz <= 0:
        raise InputError("--truth-hz", "", "must be positive")
    return run_service(SimService(spec, zconfig_from_args(args), instance=args.instance, keys=keys_from_args(args),
                                  radios=args.radio, truth_hz=args.truth_hz))
