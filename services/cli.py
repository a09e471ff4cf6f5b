"""The `fleet` command. Each part registers its own subcommands; heavy imports happen in handlers.

Bad input (`InputError`, unreadable plan files) prints one line naming the file, the field and the
problem and exits with code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable, Sequence
from importlib import import_module

from common.domain.planfile import PlanFileError
from common.errors import InputError

# Modules that contribute subcommands: each has `register(subparsers)` and imports little (a
# service's handler is a `lazy_handler`): every service process builds this whole parser.
_COMMAND_MODULES = (
    "services.planner.cli",
    "services.planner.collab.cli",
    "services.mission.cli",
    "services.mission.doctor",
    "services.executor.cli",
    "services.radio_gateway.cli",
    "services.sim.cli",
    "services.mocap_bridge.cli",
    "services.telemetry.cli",
    "common.deploy.router",
    "common.deploy.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fleet", description="Plan and fly swarms of flying cars.")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _COMMAND_MODULES:
        import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    handler: Callable[[argparse.Namespace], int] = args.handler
    try:
        return int(handler(args) or 0)
    except (InputError, PlanFileError) as exc:
        print(f"fleet {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # output piped into `head` and the like
        return 0


if __name__ == "__main__":
    sys.exit(main())
