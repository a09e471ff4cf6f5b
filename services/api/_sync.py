"""`Fleet`: the blocking flavour of the API, for scripts and notebooks. It runs an `AsyncFleet` on
an event loop of its own, in a background thread (so it works where a loop already runs, as in
Jupyter); every method waits for its asynchronous twin and has its docstring."""

from __future__ import annotations

import asyncio
import functools
import queue
import threading
from collections.abc import Awaitable, Callable, Coroutine, Iterator
from typing import Any, TypeVar

from common.bus.messages import Telemetry, VehiclePlan
from services.api._fleet import AsyncFleet
from services.api._mission import Mission
from services.api._types import MissionEvent, MissionResult, VehicleInfo

T = TypeVar("T")


class _LoopThread:
    """An event loop running in a daemon thread; `run` waits for a coroutine on it."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, name="fleet-api", daemon=True)
        self._thread.start()

    def run(self, coro: Coroutine[Any, Any, T]) -> T:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result()

    def stop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout=5.0)
        self.loop.close()


def _blocking(method: Callable[..., Awaitable[T]]) -> Callable[..., T]:
    """The blocking twin of an `AsyncFleet` coroutine method (same arguments and docstring)."""

    @functools.wraps(method)
    def call(self: Fleet, *args: Any, **kwargs: Any) -> T:
        return self._thread.run(method(self.aio, *args, **kwargs))

    return call


class SyncMission:
    """A running mission, blocking flavour: `id`, `events()`, `wait()`, `abort()` as in `Mission`."""

    def __init__(self, mission: Mission, thread: _LoopThread) -> None:
        self.aio = mission
        self.id = mission.id
        self.vehicles = mission.vehicles
        self._thread = thread

    @property
    def plans(self) -> dict[str, VehiclePlan]:
        """Each vehicle's latest plan as the mission handed it out (`VehiclePlan`)."""
        return dict(self.aio.plans)

    @property
    def done(self) -> bool:
        """Whether the mission is over."""
        return self.aio.done

    def events(self) -> Iterator[MissionEvent]:
        """Every event of the mission from its beginning, then live ones, until it has ended."""
        out: queue.Queue[MissionEvent | None] = queue.Queue()

        async def pump() -> None:
            try:
                async for event in self.aio.events():
                    out.put(event)
            finally:
                out.put(None)

        asyncio.run_coroutine_threadsafe(pump(), self._thread.loop)
        while (event := out.get()) is not None:
            yield event

    def wait(self) -> MissionResult:
        """Wait until the mission is over; its result (whether or not it succeeded)."""
        return self._thread.run(self.aio.wait())

    def abort(self, reason: str = "aborted through the API") -> MissionResult:
        """Abort: every vehicle lands at the nearest safe point or stops; returns the result."""
        return self._thread.run(self.aio.abort(reason))


class Fleet:
    """A connection to a fleet, blocking flavour: `Fleet.connect(...)`, `Fleet.start(...)` or
    `Fleet.open(...)` take the arguments of `AsyncFleet`'s; use it in a `with` block or `close()` it.
    Mission event callbacks run on the API's own thread."""

    def __init__(self, make: Callable[[], Coroutine[Any, Any, AsyncFleet]]) -> None:
        self._thread = _LoopThread()
        try:
            self.aio: AsyncFleet = self._thread.run(make())
        except BaseException:
            self._thread.stop()
            raise
        self.keys = self.aio.keys

    @classmethod
    def connect(cls, *args: Any, **kwargs: Any) -> Fleet:
        """Connect to a running fleet (see `AsyncFleet.connect`)."""
        return cls(lambda: AsyncFleet.connect(*args, **kwargs))

    @classmethod
    def start(cls, *args: Any, **kwargs: Any) -> Fleet:
        """Start a simulated fleet here and connect to it (see `AsyncFleet.start`)."""
        return cls(lambda: AsyncFleet.start(*args, **kwargs))

    @classmethod
    def open(cls, **start_options: Any) -> Fleet:
        """Connect to the fleet the environment names, else start one (see `AsyncFleet.open`)."""
        return cls(lambda: AsyncFleet.open(**start_options))

    def close(self) -> None:
        """Close the session; stop the fleet if `start` brought it up."""
        try:
            self._thread.run(self.aio.close())
        finally:
            self._thread.stop()

    def __enter__(self) -> Fleet:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    @property
    def map(self) -> str:
        """The map single-vehicle commands refer to unless told otherwise."""
        return self.aio.map

    def vehicle(self, vid: str) -> VehicleInfo:
        return self.aio.vehicle(vid)

    def telemetry(self, vid: str) -> Telemetry | None:
        return self.aio.telemetry(vid)

    vehicle.__doc__, telemetry.__doc__ = AsyncFleet.vehicle.__doc__, AsyncFleet.telemetry.__doc__

    vehicles = _blocking(AsyncFleet.vehicles)
    plan = _blocking(AsyncFleet.plan)
    plan_team = _blocking(AsyncFleet.plan_team)
    run_mission = _blocking(AsyncFleet.run_mission)
    run_team_mission = _blocking(AsyncFleet.run_team_mission)
    abort = _blocking(AsyncFleet.abort)
    add_task = _blocking(AsyncFleet.add_task)
    takeoff = _blocking(AsyncFleet.takeoff)
    go_to = _blocking(AsyncFleet.go_to)
    land = _blocking(AsyncFleet.land)
    drive_to = _blocking(AsyncFleet.drive_to)
    fly_to = _blocking(AsyncFleet.fly_to)

    def start_mission(self, *args: Any, **kwargs: Any) -> SyncMission:
        return SyncMission(self._thread.run(self.aio.start_mission(*args, **kwargs)), self._thread)

    def start_team_mission(self, *args: Any, **kwargs: Any) -> SyncMission:
        return SyncMission(self._thread.run(self.aio.start_team_mission(*args, **kwargs)), self._thread)

    start_mission.__doc__ = AsyncFleet.start_mission.__doc__
    start_team_mission.__doc__ = AsyncFleet.start_team_mission.__doc__
