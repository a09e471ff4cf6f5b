"""`fleet up`, `fleet down`, `fleet ps`: compose.yaml's services as local processes; `fleet compose
lab`: a compose file for real vehicles (common/deploy/lab.py)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from common.deploy.launcher import DEFAULT_RUN_DIR


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("up", help="start compose.yaml's services as local processes")
    p.add_argument("compose", nargs="?", default="compose.yaml")
    p.add_argument("--run-dir", type=Path, default=DEFAULT_RUN_DIR, help="state and logs (default .fleet/)")
    p.add_argument("--set", action="append", default=[], metavar="VAR=VALUE",
                   help="override a ${VAR} of the compose file (repeatable)")
    p.add_argument("--only", help="start only these services, comma-separated")
    p.add_argument("--profile", action="append", default=[], help="activate a compose profile (repeatable)")
    p.add_argument("--wait", type=float, default=60.0, metavar="S",
                   help="seconds to wait for every service to serve (0: return once started)")
    p.set_defaults(handler=cmd_up)
    p = sub.add_parser("down", help="stop what `fleet up` started")
    p.add_argument("--run-dir", type=Path, default=DEFAULT_RUN_DIR)
    p.add_argument("--grace", type=float, default=5.0, help="seconds before SIGKILL")
    p.set_defaults(handler=cmd_down)
    p = sub.add_parser("ps", help="list what `fleet up` started")
    p.add_argument("--run-dir", type=Path, default=DEFAULT_RUN_DIR)
    p.set_defaults(handler=cmd_ps)
    p = sub.add_parser("compose", help="write compose files")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="KIND")
    lab = kinds.add_parser("lab", help="a compose file for real vehicles: one gateway per radio of a radios file, "
                                       "the Crazyradios passed through, a motion-capture system")
    lab.add_argument("--radios", required=True, help="the lab's radios file (radio://<serial>/... URIs), e.g. under deploy/")
    lab.add_argument("--mocap", required=True, help="the lab's mocap file (docs/mocap.md), e.g. deploy/mocap-vicon.yaml")
    lab.add_argument("--executors", type=int, default=2, help="executor replicas by default (FLEET_EXECUTORS)")
    lab.add_argument("--name", default="fleet-lab", help="the compose project name")
    lab.add_argument("--out", help="write here (compose paths are made relative to its directory); default: stdout")
    lab.set_defaults(handler=cmd_compose_lab)


def cmd_up(args: argparse.Namespace) -> int:
    from common.deploy.compose import load_compose
    from common.deploy.launcher import start, wait_ready
    from common.errors import InputError

    overrides = {}
    for item in args.set:
        if "=" not in item:
            raise InputError("--set", item, "expected VAR=VALUE")
        k, v = item.split("=", 1)
        overrides[k] = v
    procs = load_compose(args.compose, overrides, args.run_dir, args.profile)
    if args.only:
        wanted = set(args.only.split(","))
        procs = [p for p in procs if p.service in wanted]
    try:
        started = start(procs, args.run_dir)
    except RuntimeError as exc:
        print(f"fleet up: {exc}")
        return 1
    for p in started:
        print(f"started {p['instance']:<16} pid {p['pid']}")
    print(f"logs in {args.run_dir / 'logs'}; stop with `fleet down`")
    if args.wait <= 0:
        return 0
    t0 = time.monotonic()
    missing = wait_ready(args.run_dir, args.wait)
    for instance, why in missing.items():
        print(f"fleet up: {instance} {why} after {time.monotonic() - t0:.0f} s: see {args.run_dir / 'logs' / instance}.log")
    if missing:
        return 1
    print(f"all {len(started)} services serving after {time.monotonic() - t0:.1f} s")
    return 0


def cmd_down(args: argparse.Namespace) -> int:
    from common.deploy.launcher import stop

    outcome = stop(args.run_dir, args.grace)
    for instance, how in outcome:
        print(f"{instance:<16} {how}")
    if not outcome:
        print("nothing running")
    return 1 if any(how.startswith("killed") for _, how in outcome) else 0


def cmd_ps(args: argparse.Namespace) -> int:
    from common.deploy.launcher import status

    for p in status(args.run_dir):
        print(f"{p['instance']:<16} pid {p['pid']:<8} {'running' if p['alive'] else 'exited'}")
    return 0


def cmd_compose_lab(args: argparse.Namespace) -> int:
    from common.deploy.lab import lab_compose

    text, warnings = lab_compose(args.radios, args.mocap, args.out, args.executors, args.name)
    for warning in warnings:
        print(f"fleet compose lab: warning: {warning}", file=sys.stderr)
    if args.out:
        Path(args.out).write_text(text)
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0
