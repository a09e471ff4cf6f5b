"""Shared fixtures: an in-process zenoh router and client sessions connected to it."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest
import zenoh

from common.bus.session import InProcessRouter, ZenohConfig, open_session


@pytest.fixture
def zenoh_router() -> Iterator[str]:
    """Endpoint (``tcp/127.0.0.1:<port>``) of a fresh router for this test."""
    with InProcessRouter() as router:
        yield router.endpoint


@pytest.fixture
def zsession(zenoh_router: str) -> Iterator[Callable[..., zenoh.Session]]:
    """Factory of client sessions connected to `zenoh_router`, all closed after the test."""
    sessions: list[zenoh.Session] = []

    def open_client(**options: Any) -> zenoh.Session:
        sessions.append(open_session(ZenohConfig.client(zenoh_router, **options)))
        return sessions[-1]

    yield open_client
    for session in reversed(sessions):
        session.close()
