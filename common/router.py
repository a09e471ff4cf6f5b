"""`fleet router`: a zenoh session in router mode (zenohd is not installable here)."""

from __future__ import annotations

import argparse
import signal
import threading

from common.svcargs import credentials
from common.zsession import ZenohConfig, open_session


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("router", help="run a zenoh router (stands in for zenohd)")
    p.add_argument("--listen", default="tcp/0.0.0.0:7447", help="endpoints, comma-separated")
    p.add_argument("--config", help="a zenoh JSON5 config file (access control, TLS); overrides --listen")
    p.set_defaults(handler=cmd_router)


def cmd_router(args: argparse.Namespace) -> int:
    import zenoh

    if args.config:
        session = zenoh.open(zenoh.Config.from_file(args.config))
    else:
        user, password = credentials()
        listen = tuple(e.strip() for e in args.listen.split(",") if e.strip())
        session = open_session(ZenohConfig.router(*listen, user=user, password=password))
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    print(f"router {session.zid()} listening on {args.listen}", flush=True)
    done.wait()
    session.close()
    return 0
