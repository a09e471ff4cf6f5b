"""Shared fixtures: an in-process zenoh router and client sessions connected to it; a failed flight is flown again."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest
import zenoh

from common.bus.session import InProcessRouter, ZenohConfig, open_session

FLIGHT_RERUNS = 2
"""A test marked `flight` flies the fleet's processes (router, planner, executors, gateways, motion
capture, the simulated world: up to 12 processes) in real time on the machine that runs the suite.
On a shared 2-core machine a stall of a few hundred milliseconds makes the fleet do what it must do
when the world stalls: hold a vehicle past its margin, land one whose poses or commands went stale.
Such a flight is flown up to twice more (pytest-rerunfailures: `R` in the progress line, "N rerun" in
the summary); a behaviour that is wrong fails all three. (Once more was not enough on the CI machine's
slow hour of 2026-12-04: the examples' flights and `fleet up`'s 8-vehicle mission failed twice each.)"""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("flight") is not None:
            item.add_marker(pytest.mark.flaky(reruns=FLIGHT_RERUNS, reruns_delay=1))


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
