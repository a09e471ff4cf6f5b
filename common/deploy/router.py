"""`fleet router`: a zenoh session in router mode (zenohd is not installable here), and `fleet
credentials`: role credentials for a secured router and its services (docs/security.md)."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from pathlib import Path

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("router", help="run a zenoh router (stands in for zenohd)")
    p.add_argument("--listen", help=f"endpoints, comma-separated (default: the config's, else {DEFAULT_LISTEN})")
    p.add_argument("--config", help="a zenoh JSON5 config to start from, e.g. deploy/router.json5 (access control)")
    p.add_argument("--users", default=os.environ.get("FLEET_ZENOH_USERS_FILE"),
                   help="user-password dictionary, 'user:password' lines (env FLEET_ZENOH_USERS_FILE); "
                        "overrides the config's dictionary_file")
    p.set_defaults(handler=cmd_router)
    p = sub.add_parser("credentials", help="make random role credentials (zenoh-users + zenoh-<role>) in a directory")
    p.add_argument("dir", type=Path, help="where to write them (created, owner-only files)")
    p.set_defaults(handler=cmd_credentials)


def cmd_router(args: argparse.Namespace) -> int:
    import zenoh

    from common.bus.args import credentials
    from common.bus.readiness import mark_ready
    from common.bus.session import ZenohConfig, open_session

    user, password = credentials()  # only used towards other routers
    listen = args.listen or ("" if args.config else DEFAULT_LISTEN)
    config = ZenohConfig.router(*(e.strip() for e in listen.split(",") if e.strip()), user=user, password=password,
                                config_file=args.config, users_file=args.users)
    try:
        session = open_session(config)
    except zenoh.ZError as exc:  # a bad config, a missing dictionary file, a taken port
        print(f"fleet router: cannot start: {exc}", file=sys.stderr)
        return 1
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    where = listen or f"the endpoints of {args.config}"
    print(f"router {session.zid()} listening on {where}" + (f", config {args.config}" if args.config else ""), flush=True)
    mark_ready()
    done.wait()
    session.close()
    return 0


def cmd_credentials(args: argparse.Namespace) -> int:
    from common.deploy.credentials import make_credentials

    creds = make_credentials(args.dir)
    print(f"wrote {creds.users_file} and a zenoh-<role> password file per role in {creds.dir}")
    return 0
