"""Liveliness: every process declares `alive/<service>/<instance>`; others watch the live set.

A token disappears when its process undeclares it, closes its session, or dies: a killed process is
seen at once (its TCP link closes), a hung or cut-off one when its lease expires (`zsession.LEASE_MS`).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

import zenoh

from common.bus import call_in_loop
from common.keys import Keys

log = logging.getLogger(__name__)

ChangeCallback = Callable[[str, bool, frozenset[str]], None]
"""``on_change(instance, alive, instances)``, called on the event loop after each change."""


def declare_alive(session: zenoh.Session, keys: Keys, service: str, instance: str) -> zenoh.LivelinessToken:
    """Declare this process alive until the token is undeclared or the session ends.

    ``token = declare_alive(s, keys, "executor", "e1")``
    """
    return session.liveliness().declare_token(keys.alive(service, instance))


class AliveSet:
    """The live instances of one service, kept up to date on the event loop. Use `watch_alive`."""

    def __init__(self, session: zenoh.Session, keys: Keys, service: str,
                 on_change: ChangeCallback | None = None) -> None:
        self.service = service
        self._session = session
        self._keys = keys
        self._on_change = on_change
        self._loop = asyncio.get_running_loop()
        self._instances: set[str] = set()
        self._heard: set[str] = set()
        self._changed = asyncio.Event()
        # No history: a liveliness query right after a history subscriber on the same session gets
        # no replies (zenoh 1.10, 38 of 40 tries), so `sync` would be no barrier; the query is the snapshot.
        self._subscriber = session.liveliness().declare_subscriber(keys.all_alive(service), self._on_sample)

    @property
    def instances(self) -> frozenset[str]:
        return frozenset(self._instances)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """zenoh thread: hand the change over to the loop, in order."""
        call_in_loop(self._loop, self._apply, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

    def _apply(self, key: str, alive: bool, from_snapshot: bool = False) -> None:
        parsed = self._keys.parse_alive(key)
        if parsed is None:
            return
        instance = parsed[1]
        if from_snapshot and instance in self._heard:
            return  # the subscriber already said something newer about it
        self._heard.add(instance)
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

    async def sync(self, timeout: float) -> None:
        """Fold in a liveliness query's snapshot, so `instances` is complete when this returns."""
        done = asyncio.Event()
        replies: list[str] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                replies.append(str(reply.ok.key_expr))

        self._session.liveliness().get(
            self._keys.all_alive(self.service),
            zenoh.handlers.Callback(on_reply, lambda: call_in_loop(self._loop, done.set)), timeout=timeout)
        await done.wait()
        for key in replies:
            self._apply(key, True, from_snapshot=True)

    async def wait_until(self, predicate: Callable[[frozenset[str]], bool], timeout: float) -> frozenset[str]:
        """Wait until `predicate(instances)` holds (TimeoutError after `timeout` s)."""
        async with asyncio.timeout(timeout):
            while not predicate(self.instances):
                await self._changed.wait()
        return self.instances

    def close(self) -> None:
        self._subscriber.undeclare()


async def watch_alive(session: zenoh.Session, keys: Keys, service: str,
                      on_change: ChangeCallback | None = None, *, timeout: float = 2.0) -> AliveSet:
    """Watch the live instances of `service`; returns once the current set is known.

    ``executors = await watch_alive(s, keys, "executor", on_change=self.reassign)``
    """
    alive = AliveSet(session, keys, service, on_change)
    await alive.sync(timeout)
    return alive
