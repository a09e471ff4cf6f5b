"""The base of every fleet process: session, liveliness token, tasks, clean stop.

Subclass `Service` and override `main()` (or compose: call its helpers from your own objects)::

    class Echo(Service):
        async def main(self) -> None:
            out = self.publisher(self.keys.vehicle("v1", "state"), VehicleState)
            self.subscribe(self.keys.vehicle("v1", "pose"), Pose, lambda pose, _key: out.put(...))
            await self.stopped()

    sys.exit(asyncio.run(Echo("echo", "e1", ZenohConfig.client(endpoint)).run()))

`run()` stops on SIGINT/SIGTERM, on `stop()`, when `main()` returns, or when `main()` or a spawned
task fails (exit code 1). Stopping cancels the tasks, closes everything declared through the
helpers (newest first), drops the liveliness token and closes the session, on the event loop.
Several services may run side by side in one process (`common.bus.args.run_services`): the process
is ready once each of them serves.
"""

from __future__ import annotations

import asyncio
import logging
import signal
import threading
import time
from collections.abc import Awaitable, Callable, Coroutine, Mapping
from typing import Any, Generic, TypeVar

import zenoh

from common.bus.keys import Keys
from common.bus.liveliness import AliveSet, ChangeCallback, declare_alive, watch_alive
from common.bus.pubsub import (
    MAILBOX_SIZE,
    Counters,
    MessageHandler,
    Publisher,
    Queryable,
    Subscription,
    call_in_loop,
    serve,
    subscribe,
)
from common.bus.readiness import mark_ready
from common.bus.session import ZenohConfig, open_session

log = logging.getLogger(__name__)

T = TypeVar("T")
Req = TypeVar("Req")
Rep = TypeVar("Rep")

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

LOOP_PROBE_S = 0.05
"""s, how often the event loop's own lateness is measured (`Service._watch_loop`)."""
LOOP_STALL_S = 0.2
"""s, a probe this late means the loop did not run for that long (a handler hogging it, the process
starved of CPU, a GC pause): logged at WARNING and counted as `loop_stall`."""


_running: set[Service] = set()
"""The services running in this process (readiness waits for all of those of one event loop)."""


class Service:
    """One fleet process: `name` is its service kind, `instance` tells replicas apart."""

    def __init__(self, name: str, instance: str, zconfig: ZenohConfig, keys: Keys | None = None) -> None:
        self.keys = keys or Keys()
        self.keys.alive(name, instance)  # both must be plain key chunks
        self.name = name
        self.instance = instance
        self.zconfig = zconfig
        self.counters = Counters()
        self._session: zenoh.Session | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop = asyncio.Event()
        self._stop_requested = False
        self._failed = False
        self._serving = False
        self._tasks: set[asyncio.Task[Any]] = set()
        self._closers: list[Callable[[], None]] = []

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError(f"{self.name}/{self.instance} has no session outside run()")
        return self._session

    async def main(self) -> None:
        """The service's work; the default just waits to be stopped."""
        await self.stopped()

    async def stopped(self) -> None:
        await self._stop.wait()

    def stop(self) -> None:
        """Ask `run()` to stop (from any thread, also before `run()` has started)."""
        self._stop_requested = True
        if self._loop is not None:
            call_in_loop(self._loop, self._stop.set)

    def spawn(self, coro: Coroutine[Any, Any, T], name: str | None = None) -> asyncio.Task[T]:
        """Run `coro` as a task of this service: cancelled at stop; its failure stops the service."""
        task = asyncio.get_running_loop().create_task(coro, name=name)
        self._tasks.add(task)
        task.add_done_callback(self._task_done)
        return task

    def _task_done(self, task: asyncio.Task[Any]) -> None:
        self._tasks.discard(task)
        if not task.cancelled() and task.exception() is not None:
            log.error("%s/%s: task %s failed", self.name, self.instance, task.get_name(),
                      exc_info=task.exception())
            self._failed = True
            self._stop.set()

    def publisher(self, key: str, typ: type[T], **options: Any) -> Publisher[T]:
        pub = Publisher(self.session, key, typ, **options)
        self._closers.append(pub.close)
        return pub

    def publishers(self, key_of: Callable[[str], str], typ: type[T], **options: Any) -> KeyedPublishers[T]:
        """One publisher per vehicle (or other name), on key `key_of(name)`, declared on first use."""
        return KeyedPublishers(self, key_of, typ, options)

    def subscribe(self, key: str, typ: type[T], handler: MessageHandler[T] | None = None,
                  maxlen: int = MAILBOX_SIZE) -> Subscription[T]:
        sub = subscribe(self.session, key, typ, handler, counters=self.counters, maxlen=maxlen)
        self._closers.append(sub.close)
        return sub

    def serve(self, key: str, req_type: type[Req], rep_type: type[Rep],
              handler: Callable[[Req], Awaitable[Rep]]) -> Queryable[Req, Rep]:
        queryable = serve(self.session, key, req_type, rep_type, handler, counters=self.counters)
        self._closers.append(queryable.close)
        return queryable

    async def watch_alive(self, service: str, on_change: ChangeCallback | None = None) -> AliveSet:
        alive = await watch_alive(self.session, self.keys, service, on_change)
        self._closers.append(alive.close)
        return alive

    async def run(self) -> int:
        """Run until stopped; returns the process exit code (0 clean stop, 1 failure)."""
        self._loop = asyncio.get_running_loop()
        if self._stop_requested:
            self._stop.set()
        _running.add(self)
        signals = _install_signal_handlers(self._loop, self.stop)
        try:
            try:
                self._session = await asyncio.to_thread(open_session, self.zconfig)
            except zenoh.ZError as exc:
                log.error("%s/%s: cannot open zenoh session: %s", self.name, self.instance, exc)
                return 1
            self._closers.append(declare_alive(self.session, self.keys, self.name, self.instance).undeclare)
            log.info("%s/%s running", self.name, self.instance)
            self._serving = True
            if all(service._serving for service in _running if service._loop is self._loop):
                mark_ready()
            self.spawn(self._watch_loop(), name="loop-watch")
            main = self.spawn(self.main(), name="main")
            stop = asyncio.create_task(self._stop.wait())
            await asyncio.wait({main, stop}, return_when=asyncio.FIRST_COMPLETED)
            stop.cancel()
            return 1 if self._failed else 0
        finally:
            await self._shutdown()
            _running.discard(self)
            for sig in signals:
                self._loop.remove_signal_handler(sig)

    async def _watch_loop(self) -> None:
        """Measure how late the loop wakes a `LOOP_PROBE_S` sleep; report stalls (the fleet's
        deadlines, e.g. the gateway's 0.2 s stale command, are judged by loops like this one)."""
        loop = asyncio.get_running_loop()
        while True:
            due = loop.time() + LOOP_PROBE_S
            thread_from, process_from = time.thread_time(), time.process_time()
            await asyncio.sleep(LOOP_PROBE_S)
            late = loop.time() - due
            if late > LOOP_STALL_S:
                self.counters.inc("loop_stall")
                log.warning("%s/%s: event loop stalled for %.2f s (of its %.2f s the loop's thread ran %.2f s, "
                            "the process's threads %.2f s)", self.name, self.instance, late, LOOP_PROBE_S + late,
                            time.thread_time() - thread_from, time.process_time() - process_from)

    async def _shutdown(self) -> None:
        self._stop.set()
        tasks = list(self._tasks)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        while self._closers:
            closer = self._closers.pop()
            try:
                closer()
            except zenoh.ZError as exc:
                log.warning("%s/%s: closing: %s", self.name, self.instance, exc)
        await asyncio.sleep(0)  # cancelled query answers send their "service stopping" replies now
        if self._session is not None:
            self._session.close()
            self._session = None
        log.info("%s/%s stopped", self.name, self.instance)


class KeyedPublishers(Generic[T]):
    """A service's publishers of one message type, one per name (a vehicle id), each declared the
    first time it is used and kept until the service stops."""

    def __init__(self, service: Service, key_of: Callable[[str], str], typ: type[T], options: dict[str, Any]) -> None:
        self._service = service
        self._key_of = key_of
        self._typ = typ
        self._options = options
        self._pubs: dict[str, Publisher[T]] = {}

    def __getitem__(self, name: str) -> Publisher[T]:
        pub = self._pubs.get(name)
        if pub is None:
            pub = self._pubs[name] = self._service.publisher(self._key_of(name), self._typ, **self._options)
        return pub

    def put(self, name: str, msg: T) -> None:
        self[name].put(msg)

    def put_all(self, msgs: Mapping[str, T]) -> None:
        """Publish each message on its name's key."""
        for name, msg in msgs.items():
            self[name].put(msg)


def _install_signal_handlers(loop: asyncio.AbstractEventLoop, stop: Callable[[], None]) -> tuple[int, ...]:
    """SIGINT/SIGTERM call `stop` (only possible in the main thread); returns what was installed."""
    if threading.current_thread() is not threading.main_thread():
        return ()
    for sig in _STOP_SIGNALS:
        loop.add_signal_handler(sig, stop)
    return _STOP_SIGNALS
