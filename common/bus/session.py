"""Zenoh sessions from a small config, and an in-process router for tests and the demo.

Every session of the fleet uses a short link lease (`LEASE_MS`) so that a hung or partitioned process
is expired by its router within a second; a killed process is seen at once (its TCP link closes).
Each side expires the other with the lease *the other side announced*, so every process must use it.
"""

from __future__ import annotations

import json
import socket
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import zenoh

Mode = Literal["router", "peer", "client"]

LEASE_MS = 800
"""Link lease announced to the other end: it expires us after this long without hearing from us."""
KEEP_ALIVE = 4
"""Keep-alive messages per lease (one every 200 ms when the link is otherwise idle)."""


@dataclass(frozen=True)
class ZenohConfig:
    """What a fleet process needs to say about its zenoh session; `extra` reaches any other option.

    `tls` maps `transport/link/tls/<option>` names (e.g. ``root_ca_certificate``) to values; `extra`
    maps full config paths (e.g. ``"scouting/delay"``) to JSON values. `config_file` is a zenoh JSON5
    file to start from (e.g. deploy/router.json5 with its access control); every field set here, and
    `listen`/`connect` when not empty, goes over it.
    """

    mode: Mode = "client"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    lease_ms: int = LEASE_MS
    keep_alive: int = KEEP_ALIVE
    connect_timeout_ms: int = 5000
    """How long opening waits for a `connect` endpoint to answer (-1: forever)."""
    multicast_scouting: bool = False
    user: str | None = None
    password: str | None = None
    tls: Mapping[str, Any] = field(default_factory=dict)
    extra: Mapping[str, Any] = field(default_factory=dict)
    config_file: str | None = None
    users_file: str | None = None
    """A router's user-password dictionary ("user:password" lines): only those sessions may connect."""

    @classmethod
    def client(cls, *connect: str, **options: Any) -> ZenohConfig:
        return cls(mode="client", connect=connect, **options)

    @classmethod
    def router(cls, *listen: str, **options: Any) -> ZenohConfig:
        return cls(mode="router", listen=listen, **options)

    def to_zenoh(self) -> zenoh.Config:
        """The `zenoh.Config` this describes (raises `zenoh.ZError` on an unknown or invalid option)."""
        values: dict[str, Any] = {
            "mode": self.mode,
            "connect/timeout_ms": self.connect_timeout_ms,
            "transport/link/tx/lease": self.lease_ms,
            "transport/link/tx/keep_alive": self.keep_alive,
            "scouting/multicast/enabled": self.multicast_scouting,
        }
        if self.listen:
            values["listen/endpoints"] = list(self.listen)
        if self.connect:
            values["connect/endpoints"] = list(self.connect)
        if not self.multicast_scouting:
            # Routers otherwise wait `scouting/delay` (500 ms) in open() for scouting answers.
            values["scouting/delay"] = 0
        if self.user is not None:
            values["transport/auth/usrpwd/user"] = self.user
        if self.password is not None:
            values["transport/auth/usrpwd/password"] = self.password
        if self.users_file is not None:
            values["transport/auth/usrpwd/dictionary_file"] = self.users_file
        values.update({f"transport/link/tls/{name}": value for name, value in self.tls.items()})
        values.update(self.extra)
        config = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
        for path, value in values.items():
            config.insert_json5(path, json.dumps(value))
        return config


def open_session(config: ZenohConfig) -> zenoh.Session:
    """Open a session (blocking: up to `connect_timeout_ms` for a client whose router is not up yet)."""
    return zenoh.open(config.to_zenoh())


def free_tcp_endpoint(host: str = "127.0.0.1") -> str:
    """A ``tcp/<host>:<port>`` endpoint on a port that was free a moment ago."""
    with socket.socket() as sock:
        sock.bind((host, 0))
        return f"tcp/{host}:{sock.getsockname()[1]}"


class InProcessRouter:
    """A router-mode session on a free local TCP port, without multicast scouting.

    Clients connect to it explicitly (`client_config()`), so tests on one machine never meet.
    `options` go to its `ZenohConfig` (e.g. `config_file` and `users_file` for access control:
    `common.deploy.credentials.Credentials.router_options()`).
    """

    def __init__(self, endpoint: str | None = None, attempts: int = 5, **options: Any) -> None:
        for attempt in range(attempts):
            self.endpoint = endpoint or free_tcp_endpoint()
            try:
                self.session = open_session(ZenohConfig.router(self.endpoint, **options))
                return
            except zenoh.ZError:  # the free port was taken in between
                if endpoint or attempt == attempts - 1:
                    raise

    def client_config(self, **options: Any) -> ZenohConfig:
        return ZenohConfig.client(self.endpoint, **options)

    def close(self) -> None:
        self.session.close()

    def __enter__(self) -> InProcessRouter:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
