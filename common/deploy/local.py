"""Bring a deployment up on this machine: a compose file's services as local processes, with
overrides, each waited for by one readiness rule (its ready file, `common.bus.readiness`).

`fleet up` does this from the command line; `fleet demo`, `fleet mission team --local`, the tests and
the benchmarks do it through `bring_up`. The router is compose's `router` service, a process of its
own, as deployed; `bring_up` may instead run it inside this process (`router_in_process`: a test
that stops and restarts it). Not by default: zenoh's runtime threads are the process's, shared by
the router's routing and this process's subscribers, which run Python and wait for its GIL; a
process that plans, judges ground truth or runs a mission holds the GIL for long stretches, and
the whole fleet's traffic waited with it (`bench.router_hop`'s busy router: p99 1 -> 5-6 ms;
80-vehicle soaks: event loops stalled 13.5 times a run in this process, 7.6 in its own:
docs/bus.md, "A router in a busy process"). The deployment is secured as
compose.yaml is: role credentials in <run dir>/secrets, access control at the router.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from common.bus.keys import Keys
from common.bus.session import InProcessRouter, ZenohConfig, free_tcp_endpoint
from common.deploy.compose import Process, load_compose
from common.deploy.credentials import Credentials, ensure_credentials
from common.deploy.launcher import start, stop, wait_ready

REPO = Path(__file__).resolve().parents[2]
COMPOSE_FILE = REPO / "compose.yaml"

Adjust = Callable[[list[Process]], list[Process]]


@dataclass
class LocalFleet:
    """A deployment running here: its router's endpoint (and the router, when in this process)."""

    endpoint: str
    keys: Keys
    run_dir: Path
    credentials: Credentials
    router: InProcessRouter | None = None

    def client_config(self, role: str = "mission") -> ZenohConfig:
        """A session of `role` (default the operator: runs missions, watches, injects simulator faults)."""
        return ZenohConfig.client(self.endpoint, **self.credentials.options(role))


@contextmanager
def bring_up(run_dir: Path, overrides: dict[str, str] | None = None, *, compose: Path = COMPOSE_FILE,
             profiles: Iterable[str] = (), only: Iterable[str] | None = None, adjust: Adjust | None = None,
             router_in_process: bool = False, timeout_s: float = 60.0) -> Iterator[LocalFleet]:
    """Start `compose`'s services (those of `only`, and the router, with `profiles` active),
    `adjust`ed, and wait until every one serves; stop them all on exit. `overrides` set the compose
    file's variables; the fleet name is FLEET_NAME (default "default"). RuntimeError names the
    processes that did not come up."""
    run_dir.mkdir(parents=True, exist_ok=True)
    creds = ensure_credentials(run_dir / "secrets")
    env = {"FLEET_SECRETS": str(creds.dir.resolve()), **(overrides or {})}
    router = None
    if router_in_process:
        router = InProcessRouter(free_tcp_endpoint(), **creds.router_options())
        env.update(ROUTER_HOST="127.0.0.1", FLEET_ROUTER_PORT=router.endpoint.rsplit(":", 1)[1])
    elif "FLEET_ROUTER_PORT" not in env:
        env["FLEET_ROUTER_PORT"] = free_tcp_endpoint().rsplit(":", 1)[1]
    try:
        procs = load_compose(compose, env, run_dir, profiles)
        wanted = set(only) if only is not None else None
        procs = [p for p in procs if (p.service == "router" and not router_in_process)
                 or (p.service != "router" and (wanted is None or p.service in wanted))]
        if adjust is not None:
            procs = adjust(procs)
        endpoint = f"tcp/127.0.0.1:{env['FLEET_ROUTER_PORT']}"
        print(f"fleet: router on {endpoint}; starting {len(procs)} processes (logs in {run_dir / 'logs'})")
        start(procs, run_dir, settle_s=0.1)
        try:
            missing = wait_ready(run_dir, timeout_s)
            if missing:
                why = ", ".join(f"{name} {what}" for name, what in missing.items())
                raise RuntimeError(f"services not up within {timeout_s:.0f} s: {why} (see {run_dir / 'logs'})")
            yield LocalFleet(endpoint, Keys(env.get("FLEET_NAME", "default")), run_dir, creds, router)
        finally:
            stop(run_dir, grace_s=5.0)
    finally:
        if router is not None:
            router.close()


@contextmanager
def router_process(run_dir: Path) -> Iterator[str]:
    """`fleet router` without access control on a free local port, a process of its own (not one
    that runs Python besides: docs/bus.md, "A router in a busy process"), up while in the context;
    its endpoint. For benchmarks that play parts of the fleet themselves."""
    endpoint = free_tcp_endpoint()
    argv = [sys.executable, "-m", "services.cli", "router", "--listen", endpoint]
    start([Process("router", "router", argv, {})], run_dir, settle_s=0.0)
    try:
        missing = wait_ready(run_dir, 10.0)
        if missing:
            raise RuntimeError(f"the router did not come up: see {run_dir / 'logs' / 'router.log'}")
        yield endpoint
    finally:
        stop(run_dir, grace_s=2.0)
