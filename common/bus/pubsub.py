"""Typed pub/sub and request/reply over zenoh, delivered into asyncio.

Bridge rule: zenoh runs our callbacks on its own threads. A callback only decodes and hands over to
the event loop (`loop.call_soon_threadsafe`); it never blocks, never awaits, never closes a session.

Drop policy: a payload above `MAX_MESSAGE_BYTES` or that does not decode strictly as the expected
type is dropped and counted under `drop_name(reason, type, key)` ("oversized", "malformed"); a slow
consumer loses the oldest messages of its bounded mailbox ("overflow"); a handler that raises is
counted ("handler"). Each counter name is logged once, at its first drop. Nothing raises into zenoh.
"""

from __future__ import annotations

import asyncio
import inspect
import logging
import threading
from collections import deque
from collections.abc import Awaitable, Callable, Iterator, Mapping
from typing import Any, Generic, TypeVar

import msgspec
import zenoh

from common.bus.messages import MAX_MESSAGE_BYTES, Codec

log = logging.getLogger(__name__)

T = TypeVar("T")
Req = TypeVar("Req")
Rep = TypeVar("Rep")

MessageHandler = Callable[[T, str], Awaitable[None] | None]
"""Called on the event loop with each decoded message and its concrete key (may be a coroutine)."""

MAILBOX_SIZE = 256
"""Default bound of a subscription's mailbox (about 2.5 s of one 100 Hz topic)."""

_QUERY_TIMEOUT_MARGIN_S = 1.0
"""zenoh's own query timeout is set this much later than ours, so ours always decides."""


def drop_name(reason: str, typ: type, key: str) -> str:
    """Counter name of messages of `typ` dropped on `key` for `reason`."""
    return f"drop:{reason}:{typ.__name__}:{key}"


class Counters(Mapping[str, int]):
    """Named counters, incremented from any thread, read as a mapping by the service and by tests."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}

    def inc(self, name: str, n: int = 1) -> int:
        with self._lock:
            value = self._counts[name] = self._counts.get(name, 0) + n
        return value

    def drop(self, reason: str, typ: type, key: str, detail: str, exc: BaseException | None = None) -> None:
        """Count one dropped message; log it (with `exc`'s traceback) if it is the first under its name."""
        name = drop_name(reason, typ, key)
        if self.inc(name) == 1:
            log.warning("dropped %s %s on %s: %s (further drops only counted as %r)",
                        reason, typ.__name__, key, detail, name, exc_info=exc)

    def total(self, prefix: str = "drop:") -> int:
        with self._lock:
            return sum(v for k, v in self._counts.items() if k.startswith(prefix))

    def __getitem__(self, name: str) -> int:
        with self._lock:
            return self._counts[name]

    def __iter__(self) -> Iterator[str]:
        with self._lock:
            return iter(list(self._counts))

    def __len__(self) -> int:
        with self._lock:
            return len(self._counts)


class BadPayload(Exception):
    """A payload that is not a valid message of the expected type (`reason`: oversized, malformed)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def decode_payload(codec: Codec[T], payload: zenoh.ZBytes | None) -> T:
    """Decode strictly, checking the size before copying the payload out of zenoh."""
    size = len(payload) if payload is not None else 0
    if size > MAX_MESSAGE_BYTES:
        raise BadPayload("oversized", f"{size} bytes > {MAX_MESSAGE_BYTES}")
    try:
        return codec.decode(payload.to_bytes() if payload is not None else b"")
    except msgspec.DecodeError as exc:
        raise BadPayload("malformed", str(exc)) from None


def encode_message(codec: Codec[T], msg: T) -> bytes:
    """Encode `msg`, refusing another type (TypeError) or an oversized result (ValueError)."""
    if not isinstance(msg, codec.type):
        raise TypeError(f"expected {codec.type.__name__}, got {type(msg).__name__}")
    data = codec.encode(msg)
    if len(data) > MAX_MESSAGE_BYTES:
        raise ValueError(f"{codec.type.__name__} of {len(data)} bytes exceeds {MAX_MESSAGE_BYTES}")
    return data


def call_in_loop(loop: asyncio.AbstractEventLoop, fn: Callable[..., object], *args: Any) -> bool:
    """From a zenoh thread: run `fn(*args)` on `loop` soon; False if the loop is already closed."""
    try:
        loop.call_soon_threadsafe(fn, *args)
    except RuntimeError:  # loop closed: the process is shutting down
        return False
    return True


class Mailbox(Generic[T]):
    """Bounded hand-over from zenoh threads to one asyncio consumer; when full, the oldest goes.

    The bound holds even while the event loop is busy: items wait here, not in the loop's queue, and
    the loop is woken at most once per batch. The consumer waits on one future of its own, with a
    timer for a timeout: `asyncio.wait_for` would make a task and a cancellation per wait, which was a
    quarter of a radio gateway's Python time (its loop waits for each executor's command batch).
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, maxlen: int, on_overflow: Callable[[], None]) -> None:
        if maxlen < 1:
            raise ValueError("mailbox needs room for at least one item")
        self._loop = loop
        self._maxlen = maxlen
        self._on_overflow = on_overflow
        self._items: deque[T] = deque()
        self._lock = threading.Lock()
        self._waiter: asyncio.Future[bool] | None = None
        self._wake_pending = False

    def put_threadsafe(self, item: T) -> None:
        """Never blocks (any thread)."""
        with self._lock:
            overflow = len(self._items) >= self._maxlen
            if overflow:
                self._items.popleft()
            self._items.append(item)
            wake = not self._wake_pending
            self._wake_pending = True
        if overflow:
            self._on_overflow()
        if wake:
            call_in_loop(self._loop, self._wake)

    def _wake(self) -> None:
        if self._items:  # a wake-up scheduled before the consumer drained is stale
            _settle(self._waiter, True)

    def drain(self) -> list[T]:
        """Every waiting item, oldest first, without waiting (event loop only)."""
        with self._lock:
            items = list(self._items)
            self._items.clear()
        return items

    async def get(self) -> T:
        """The oldest item, waiting for one (event loop only)."""
        while True:
            with self._lock:
                if self._items:
                    return self._items.popleft()
            await self.wait(None)

    async def wait(self, timeout: float | None) -> bool:
        """Until an item is waiting or `timeout` s have passed (None: for ever); whether one is
        (event loop only). It always yields to the loop once: a control loop whose input arrives
        during every cycle (an overloaded one) would otherwise never give its loop back."""
        with self._lock:
            ready = bool(self._items)
            if not ready:
                self._wake_pending = False
        if ready:
            await asyncio.sleep(0)
            return True
        waiter = self._waiter = self._loop.create_future()
        timer = None if timeout is None else self._loop.call_later(max(timeout, 0.0), _settle, waiter, False)
        try:
            return await waiter
        finally:
            self._waiter = None
            if timer is not None:
                timer.cancel()


def _settle(waiter: asyncio.Future[bool] | None, arrived: bool) -> None:
    """End a mailbox's wait (event loop only): an item `arrived`, or its time ran out."""
    if waiter is not None and not waiter.done():
        waiter.set_result(arrived)


class Publisher(Generic[T]):
    """A zenoh publisher of one message type; `options` go to `Session.declare_publisher`."""

    def __init__(self, session: zenoh.Session, key: str, typ: type[T], **options: Any) -> None:
        self.key = key
        self._codec = Codec(typ)
        self._publisher = session.declare_publisher(key, **options)

    @property
    def matched(self) -> bool:
        """Whether any subscriber currently matches (declarations take a moment to propagate)."""
        return self._publisher.matching_status.matching

    def put(self, msg: T) -> None:
        self._publisher.put(encode_message(self._codec, msg))

    def close(self) -> None:
        self._publisher.undeclare()


class Subscription(Generic[T]):
    """Messages of one type on a key expression, decoded strictly, to a handler task or `recv()`.

    Create it with `subscribe` from inside the running event loop.
    """

    def __init__(self, session: zenoh.Session, key: str, typ: type[T], handler: MessageHandler[T] | None,
                 counters: Counters, maxlen: int) -> None:
        self.key = key
        self.type = typ
        self.counters = counters
        self._codec = Codec(typ)
        self._closed = False
        loop = asyncio.get_running_loop()
        self._mailbox: Mailbox[tuple[T, str]] = Mailbox(loop, maxlen, self._count_overflow)
        self._subscriber = session.declare_subscriber(key, self._on_sample)
        self._task = loop.create_task(self._pump(handler), name=f"subscription {key}") if handler else None

    def _count_overflow(self) -> None:
        self.counters.drop("overflow", self.type, self.key, "consumer slower than the publisher")

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """zenoh thread: decode and hand over, or count and drop."""
        if self._closed or sample.kind != zenoh.SampleKind.PUT:
            return
        key = str(sample.key_expr)
        try:
            msg = decode_payload(self._codec, sample.payload)
        except BadPayload as bad:
            self.counters.drop(bad.reason, self.type, key, bad.detail)
            return
        self._mailbox.put_threadsafe((msg, key))

    async def recv(self) -> tuple[T, str]:
        """The next message and its key (only without a handler)."""
        return await self._mailbox.get()

    async def wait(self, timeout: float) -> bool:
        """Until a message is waiting or `timeout` s have passed; whether one is (only without a
        handler; take it with `drain`). A control loop waits this way for its next input or its tick."""
        return await self._mailbox.wait(timeout)

    def drain(self) -> list[tuple[T, str]]:
        """Every message waiting, oldest first, without waiting (only without a handler): a control
        loop pulls its inputs right before it uses them."""
        return self._mailbox.drain()

    async def _pump(self, handler: MessageHandler[T]) -> None:
        """Hand each message to `handler`, yielding to the loop after each one: `recv` does not
        suspend while the mailbox holds items, so a stream arriving as fast as it is handled (or a
        backlog after a stall) would otherwise keep the control loops from running (measured: pose
        handlers ran for up to 0.96 s in one step, the executor's commands went stale)."""
        while True:
            await asyncio.sleep(0)
            msg, key = await self.recv()
            try:
                result = handler(msg, key)
                if inspect.isawaitable(result):
                    await result
            except Exception as exc:
                self.counters.drop("handler", self.type, key, f"{type(exc).__name__}: {exc}", exc)

    def close_and_drain(self) -> list[tuple[T, str]]:
        """Stop receiving and return every message that arrived but was not handled yet, oldest
        first (a recorder's last samples when it stops: under load its handler lags the stream)."""
        self.close()
        return self._mailbox.drain()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._subscriber.undeclare()
        if self._task is not None:
            self._task.cancel()


def subscribe(session: zenoh.Session, key: str, typ: type[T], handler: MessageHandler[T] | None = None, *,
              counters: Counters | None = None, maxlen: int = MAILBOX_SIZE) -> Subscription[T]:
    """Subscribe to `key` for messages of `typ` (call from the event loop).

    ``subscribe(s, keys.all_vehicles("pose"), Pose, on_pose, counters=svc.counters)``
    """
    return Subscription(session, key, typ, handler, counters if counters is not None else Counters(), maxlen)


class Queryable(Generic[Req, Rep]):
    """Answers queries on one concrete key: decodes the request, awaits `handler(request)` on the
    event loop and replies with its result; a bad request, a handler exception or a stop while
    answering becomes an error reply. Create it with `serve` from inside the running event loop."""

    def __init__(self, session: zenoh.Session, key: str, req_type: type[Req], rep_type: type[Rep],
                 handler: Callable[[Req], Awaitable[Rep]], counters: Counters) -> None:
        if "*" in key or "$" in key:
            raise ValueError(f"a queryable replies on its own key, which must be concrete: {key!r}")
        self.key = key
        self.counters = counters
        self._req_codec = Codec(req_type)
        self._rep_codec = Codec(rep_type)
        self._handler = handler
        self._loop = asyncio.get_running_loop()
        self._tasks: set[asyncio.Task[None]] = set()
        self._queryable = session.declare_queryable(key, self._on_query)

    def _on_query(self, query: zenoh.Query) -> None:
        """zenoh thread: decode the request and hand it over, or reply with an error at once."""
        try:
            request = decode_payload(self._req_codec, query.payload)
        except BadPayload as bad:
            self.counters.drop(bad.reason, self._req_codec.type, self.key, bad.detail)
            _reply_error(query, f"{bad.reason} {self._req_codec.type.__name__} request: {bad.detail}")
            return
        if not call_in_loop(self._loop, self._start, query, request):
            _reply_error(query, "service stopping")

    def _start(self, query: zenoh.Query, request: Req) -> None:
        task = self._loop.create_task(self._answer(query, request), name=f"query {self.key}")
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _answer(self, query: zenoh.Query, request: Req) -> None:
        try:
            reply = encode_message(self._rep_codec, await self._handler(request))
        except asyncio.CancelledError:
            _reply_error(query, "service stopping")
            raise
        except Exception as exc:
            self.counters.inc(f"query_error:{self.key}")
            log.warning("query on %s failed: %s: %s", self.key, type(exc).__name__, exc, exc_info=True)
            _reply_error(query, f"{type(exc).__name__}: {exc}")
            return
        with query:
            query.reply(self.key, reply)

    def close(self) -> None:
        self._queryable.undeclare()
        for task in self._tasks:
            task.cancel()


def _reply_error(query: zenoh.Query, message: str) -> None:
    """Send an error reply and finalise the query (its querier stops waiting)."""
    try:
        with query:
            query.reply_err(message)
    except zenoh.ZError as exc:  # the query was finalised already
        log.debug("cannot reply %r: %s", message, exc)


def serve(session: zenoh.Session, key: str, req_type: type[Req], rep_type: type[Rep],
          handler: Callable[[Req], Awaitable[Rep]], *, counters: Counters | None = None) -> Queryable[Req, Rep]:
    """Answer queries on `key` (call from the event loop).

    ``serve(s, keys.planner_plan, PlanRequest, PlanReply, plan_service.handle)``
    """
    return Queryable(session, key, req_type, rep_type, handler, counters if counters is not None else Counters())


class QueryError(Exception):
    """A query got an error reply, a malformed reply, or no answer at all."""


class QueryTimeout(QueryError):
    """No reply arrived within the timeout."""


SERVICE_START_S = 5.0
"""How long a client waits for the queryable of a service it just saw come alive (`query`'s find_s)."""


async def find_queryable(session: zenoh.Session, key: str, timeout: float) -> bool:
    """Whether a queryable on `key` is declared, waiting up to `timeout` s for one to appear (a
    service that is alive may not have declared it yet: its token comes first)."""
    querier = session.declare_querier(key)
    try:
        async with asyncio.timeout(timeout):
            while not querier.matching_status.matching:
                await asyncio.sleep(0.02)
        return True
    except TimeoutError:
        return False
    finally:
        querier.undeclare()


async def query(session: zenoh.Session, key: str, request: Any, rep_type: type[Rep], *, timeout: float,
                find_s: float = 0.0) -> Rep:
    """Send `request` to the queryable on `key` and return its decoded reply, without blocking the loop.

    ``reply = await query(s, keys.planner_plan, PlanRequest(...), PlanReply, timeout=60, find_s=5)``
    `find_s`: first wait up to this long for the queryable to be declared (`find_queryable`: a
    client that saw a service come alive and asks it at once). Raises `QueryTimeout`, or
    `QueryError` for an error reply, a malformed reply or no queryable.
    """
    if find_s > 0.0:
        await find_queryable(session, key, find_s)
    loop = asyncio.get_running_loop()
    first: asyncio.Future[zenoh.Reply | None] = loop.create_future()

    def settle(reply: zenoh.Reply | None) -> None:
        if not first.done():
            first.set_result(reply)

    payload = encode_message(Codec(type(request)), request)
    cancel = zenoh.CancellationToken()
    session.get(key, zenoh.handlers.Callback(lambda reply: call_in_loop(loop, settle, reply),
                                             lambda: call_in_loop(loop, settle, None)),
                payload=payload, timeout=timeout + _QUERY_TIMEOUT_MARGIN_S, cancellation_token=cancel)
    try:
        reply = await asyncio.wait_for(first, timeout)
    except TimeoutError:
        raise QueryTimeout(f"no reply on {key} within {timeout} s") from None
    finally:
        cancel.cancel()
    if reply is None:
        raise QueryError(f"no queryable answered on {key}")
    if reply.err is not None:
        raise QueryError(f"error reply on {key}: {reply.err.payload.to_string()}")
    try:
        return decode_payload(Codec(rep_type), reply.ok.payload)
    except BadPayload as bad:
        raise QueryError(f"{bad.reason} reply on {key}: {bad.detail}") from None
