"""`fleet mocap`: the motion-capture bridge (docs/mocap.md)."""

from __future__ import annotations

import argparse

from common.bus.args import add_zenoh_args, keys_from_args, run_service, zconfig_from_args


def register(subparsers: argparse._SubParsersAction) -> None:
    mocap = subparsers.add_parser("mocap", help="motion capture (or simulated) -> vehicle poses")
    mocap.add_argument("--config", help="mocap file (YAML, docs/mocap.md; examples deploy/mocap-*.yaml); default: simulated, 100 Hz")
    add_zenoh_args(mocap, default_instance="mocap")
    mocap.set_defaults(handler=_mocap)


def _mocap(args: argparse.Namespace) -> int:
    from services.mocap_bridge.bridge import MocapBridge
    from services.mocap_bridge.config import MocapConfig, load_mocap

    config = load_mocap(args.config) if args.config else MocapConfig()
    return run_service(MocapBridge(config, zconfig_from_args(args), instance=args.instance,
                                   keys=keys_from_args(args)))
