"""Command-line and environment configuration shared by every service process.

Each service command takes `--connect`, `--listen`, `--mode`, `--fleet` and `--instance`; defaults come
from FLEET_ZENOH_CONNECT (comma-separated endpoints), FLEET_NAME and FLEET_INSTANCE (set per replica by
compose and `fleet up`). Credentials come from FLEET_ZENOH_USER / FLEET_ZENOH_PASSWORD or
FLEET_ZENOH_PASSWORD_FILE (a compose secret), never from the repository; FLEET_ZENOH_TLS_ROOT_CA names
the CA certificate that a `tls/...` router endpoint must be signed by (docs/security.md).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
from collections.abc import Callable, Sequence
from importlib import import_module
from pathlib import Path

from common.bus.keys import DEFAULT_FLEET, Keys
from common.bus.service import Service
from common.bus.session import ZenohConfig
from common.errors import InputError

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def add_zenoh_args(parser: argparse.ArgumentParser, default_instance: str | None = None) -> None:
    env = os.environ
    parser.add_argument("--connect", default=env.get("FLEET_ZENOH_CONNECT", DEFAULT_ENDPOINT),
                        help="router endpoint(s), comma-separated (env FLEET_ZENOH_CONNECT)")
    parser.add_argument("--listen", default=env.get("FLEET_ZENOH_LISTEN", ""), help="endpoints to listen on")
    parser.add_argument("--mode", choices=["client", "peer"], default=env.get("FLEET_ZENOH_MODE", "client"))
    parser.add_argument("--fleet", default=env.get("FLEET_NAME", DEFAULT_FLEET), help="fleet name (key prefix)")
    parser.add_argument("--instance", default=env.get("FLEET_INSTANCE", default_instance or socket.gethostname()),
                        help="this replica's name (env FLEET_INSTANCE)")


def _split(value: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in value.split(",") if v.strip())


def credentials() -> tuple[str | None, str | None]:
    """User and password from the environment (the password may come from a file); both or neither."""
    user = os.environ.get("FLEET_ZENOH_USER") or None
    password = os.environ.get("FLEET_ZENOH_PASSWORD") or None
    password_file = os.environ.get("FLEET_ZENOH_PASSWORD_FILE")
    if password_file:
        try:
            password = Path(password_file).read_text().strip()
        except OSError as exc:
            raise InputError(password_file, "FLEET_ZENOH_PASSWORD_FILE", f"cannot read ({exc.strerror})") from None
    if (user is None) != (password is None):
        raise InputError("environment", "FLEET_ZENOH_USER" if user is None else "FLEET_ZENOH_PASSWORD(_FILE)",
                         "user and password go together")
    return user, password


def tls_from_env() -> dict[str, str]:
    """`ZenohConfig.tls` options: the router's CA certificate from FLEET_ZENOH_TLS_ROOT_CA, if set."""
    root_ca = os.environ.get("FLEET_ZENOH_TLS_ROOT_CA")
    return {"root_ca_certificate": root_ca} if root_ca else {}


def zconfig_from_args(args: argparse.Namespace) -> ZenohConfig:
    user, password = credentials()
    return ZenohConfig(mode=args.mode, connect=_split(args.connect), listen=_split(args.listen),
                       user=user, password=password, tls=tls_from_env())


def keys_from_args(args: argparse.Namespace) -> Keys:
    try:
        return Keys(args.fleet)
    except ValueError as exc:
        raise InputError("--fleet", "", str(exc)) from None


def lazy_handler(target: str) -> Callable[[argparse.Namespace], int]:
    """The command handler ``module:function``, imported only when its command runs. Every `fleet`
    process builds the whole parser; importing each service's dependencies for it (filterpy and
    scipy, rerun, networkx) took 3 s of CPU per process, 0.3 s without."""
    module, _, function = target.partition(":")

    def handler(args: argparse.Namespace) -> int:
        return getattr(import_module(module), function)(args)

    return handler


def run_service(service: Service) -> int:
    """Run a service to its end in this process; its exit code."""
    return asyncio.run(service.run())


def run_services(services: Sequence[Service]) -> int:
    """Run services side by side in this process's event loop (several radios' gateways in one
    process); when one ends, the others are stopped, so that the process ends and its supervisor
    restarts all of them. The worst exit code."""
    async def main() -> int:
        runs = [asyncio.create_task(service.run()) for service in services]
        await asyncio.wait(runs, return_when=asyncio.FIRST_COMPLETED)
        for service in services:
            service.stop()
        return max(await asyncio.gather(*runs))

    return asyncio.run(main())
