"""Shared fixtures: an in-process zenoh router and client sessions connected to it; flights rerun
once; under pytest-xdist (`make test`) the flights in one lane and the rest beside them at the
lowest CPU priority."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import zenoh

from common.bus.process_priority import lower_priority
from common.bus.session import InProcessRouter, ZenohConfig, open_session

FLIGHT_RERUNS = 1
"""A test marked `flight` flies the fleet's processes (router, planner, executors, gateways, motion
capture, the simulated world: up to 12 processes) in real time on the machine that runs the suite.
On a shared 2-core machine a stall of a few hundred milliseconds makes the fleet do what it must do
when the world stalls: hold a vehicle past its margin, land one whose poses or commands went stale.
Such a flight is flown once more (pytest-rerunfailures: `R` in the progress line, "N rerun" in the
summary); a behaviour that is wrong fails both flights."""


FLIGHT_LANE, OTHER_LANE = "flights", "others"
"""`make test` runs two pytest-xdist workers with `--dist loadgroup`, one per lane: the flights one
after another (two at once would starve each other's control loops on 2 cores), and beside them
every other test, in a session of its own at the lowest CPU priority (nice 19, its autogroup's
too), so that it takes only the CPU the flights leave idle: a flight mostly waits on real time."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        flight = item.get_closest_marker("flight") is not None
        if flight:
            item.add_marker(pytest.mark.flaky(reruns=FLIGHT_RERUNS, reruns_delay=1))
        item.add_marker(pytest.mark.xdist_group(FLIGHT_LANE if flight else OTHER_LANE))


_lowered = False


def pytest_runtest_setup(item: pytest.Item) -> None:
    """In an xdist worker, the first test of the other lane lowers the worker's priority for good
    (an unprivileged process cannot raise it again; the lanes never share a worker)."""
    global _lowered
    if _lowered or "PYTEST_XDIST_WORKER" not in os.environ or item.get_closest_marker("flight") is not None:
        return
    _lowered = True
    if os.getsid(0) != os.getpid():
        with contextlib.suppress(PermissionError):  # unless it leads a process group
            os.setsid()  # a session, so an autogroup, of its own: the flights' keep theirs
    lower_priority(19 - os.nice(0))


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
