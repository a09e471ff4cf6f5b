"""Liveliness: every process declares `alive/<service>/<instance>`; others watch the live set.

A token disappears when its process undeclares it, closes its session, or dies: a killed process is
seen at once (its TCP link closes), a hung or cut-off one when its lease expires (`zsession.LEASE_MS`).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

import zenoh

from common.bus.keys import Keys
from common.bus.pubsub import call_in_loop

log = logging.getLogger(__name__)

ChangeCallback = Callable[[str, bool, frozenset[str]], None]
"""``on_change(instance, alive, instances)``, called on the event loop after each change."""


def declare_alive(session: zenoh.Session, keys: Keys, service: str, instance: str) -> zenoh.LivelinessToken:
    """Declare this process alive until the token is undeclared or the session ends.

    ``token = declare_alive(s, keys, "executor", "e1")``
    """
    return session.liveliness().declare_token(keys.alive(service, instance))


RECONCILE_TIMEOUT_S = 1.0
"""s a reconciling liveliness query may take."""


class AliveSet:
    """The live instances of one service, kept up to date on the event loop. Use `watch_alive`.

    After every "gone" the set is reconciled with a liveliness query: under load, a surviving
    executor was once told that its own token had gone instead of its killed peer's, and never
    took over the peer's vehicles (zenoh 1.10; the gateways got the right one). The router's
    snapshot then wins for every instance nothing newer was heard about."""

    def __init__(self, session: zenoh.Session, keys: Keys, service: str,
                 on_change: ChangeCallback | None = None) -> None:
        self.service = service
        self._session = session
        self._keys = keys
        self._on_change = on_change
        self._loop = asyncio.get_running_loop()
        self._instances: set[str] = set()
        self._heard: dict[str, int] = {}  # instance -> number of the last event about it
        self._events = 0
        self._changed = asyncio.Event()
        self._reconcile: asyncio.Task[None] | None = None
        # No history: a liveliness query right after a history subscriber on the same session gets
        # no replies (zenoh 1.10, 38 of 40 tries), so `sync` would be no barrier; the query is the snapshot.
        self._subscriber = session.liveliness().declare_subscriber(keys.all_alive(service), self._on_sample)

    @property
    def instances(self) -> frozenset[str]:
        return frozenset(self._instances)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """zenoh thread: hand the change over to the loop, in order."""
        call_in_loop(self._loop, self._apply, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

    def _apply(self, key: str, alive: bool) -> None:
        parsed = self._keys.parse_alive(key)
        if parsed is None:
            return
        self._events += 1
        self._heard[parsed[1]] = self._events
        self._set(parsed[1], alive)
        if not alive and (self._reconcile is None or self._reconcile.done()):
            self._reconcile = self._loop.create_task(self._reconcile_with_router())

    def _set(self, instance: str, alive: bool) -> None:
        if alive == (instance in self._instances):
            return
        (self._instances.add if alive else self._instances.discard)(instance)
        # a service gone is worth a warning (the fleet's processes log at WARNING): take-overs hang on it
        log.log(logging.INFO if alive else logging.WARNING, "%s %s %s", self.service, instance,
                "alive" if alive else "gone")
        changed, self._changed = self._changed, asyncio.Event()
        changed.set()
        if self._on_change is not None:
            self._on_change(instance, alive, self.instances)

    async def _query(self, timeout: float) -> set[str]:
        """The instances whose tokens the router knows now."""
        done = asyncio.Event()
        replies: list[str] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                replies.append(str(reply.ok.key_expr))

        self._session.liveliness().get(
            self._keys.all_alive(self.service),
            zenoh.handlers.Callback(on_reply, lambda: call_in_loop(self._loop, done.set)), timeout=timeout)
        await done.wait()
        return {parsed[1] for key in replies if (parsed := self._keys.parse_alive(key)) is not None}

    async def sync(self, timeout: float) -> None:
        """Fold in a liveliness query's snapshot, so `instances` is complete when this returns."""
        mark = self._events
        for instance in await self._query(timeout):
            if self._heard.get(instance, 0) <= mark:  # else the subscriber said something newer
                self._set(instance, True)

    async def _reconcile_with_router(self) -> None:
        mark = self._events
        try:
            snapshot = await self._query(RECONCILE_TIMEOUT_S)
        except zenoh.ZError as exc:  # the session is closing
            log.info("%s: no liveliness snapshot: %s", self.service, exc)
            return
        if not snapshot:  # no evidence: a query can come back empty (see __init__)
            return
        for instance in (snapshot ^ self._instances):
            if self._heard.get(instance, 0) <= mark:
                log.warning("%s %s: the router's snapshot says %s, the events said otherwise", self.service,
                            instance, "alive" if instance in snapshot else "gone")
                self._set(instance, instance in snapshot)

    async def wait_until(self, predicate: Callable[[frozenset[str]], bool], timeout: float) -> frozenset[str]:
        """Wait until `predicate(instances)` holds (TimeoutError after `timeout` s)."""
        async with asyncio.timeout(timeout):
            while not predicate(self.instances):
                await self._changed.wait()
        return self.instances

    def close(self) -> None:
        if self._reconcile is not None:
            self._reconcile.cancel()
        self._subscriber.undeclare()


async def watch_alive(session: zenoh.Session, keys: Keys, service: str,
                      on_change: ChangeCallback | None = None, *, timeout: float = 2.0) -> AliveSet:
    """Watch the live instances of `service`; returns once the current set is known.

    ``executors = await watch_alive(s, keys, "executor", on_change=self.reassign)``
    """
    alive = AliveSet(session, keys, service, on_change)
    await alive.sync(timeout)
    return alive
