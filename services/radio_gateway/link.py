"""The radio side of the gateway: cflib link drivers, one per vehicle, and one sender thread per radio.

`cflib.crtp.get_link_driver(uri)` picks the driver from the URI, so ``radio://0/80/2M/E7E7E7E7E7``
(a Crazyradio: cflib's `RadioDriver`, several links sharing one dongle through its radio thread) and
``udp://127.0.0.1:19850`` (a simulated Crazyflie: cflib's `UdpDriver`) go through exactly this code.
A Crazyradio send blocks while the dongle is busy (`RadioDriver.send_packet` waits for its one-packet
queue), so sends never run on the event loop: each tick's batch goes to the `RadioSender` thread,
which sends it in order. Received packets are read by one thread per link and handed to
`on_packet(vid, raw)` on that thread; the gateway moves them to its event loop.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Sequence

import cflib.crtp
from cflib.crtp.crtpstack import CRTPPacket

from common.bus.pubsub import Counters

log = logging.getLogger(__name__)

PacketCallback = Callable[[str, bytes], None]
"""``on_packet(vid, raw)`` on a link thread: raw = header byte + payload."""
ErrorCallback = Callable[[str, str], None]
"""``on_error(vid, message)`` on a link or sender thread."""

REOPEN_S = 1.0
"""Seconds between attempts to open a link that failed to open (no dongle, bad URI)."""
_RECEIVE_WAIT_S = 0.2
_LINK_PORT = 0x0F
_init_lock = threading.Lock()


def init_drivers() -> None:
    """`cflib.crtp.init_drivers()` once per process (each call would register the drivers again)."""
    with _init_lock:
        if not cflib.crtp.CLASSES:
            cflib.crtp.init_drivers()


class CrtpLink:
    """One vehicle's link. `send` is for the sender thread only; opening happens there too."""

    def __init__(self, vid: str, uri: str, on_packet: PacketCallback, on_error: ErrorCallback) -> None:
        self.vid = vid
        self.uri = uri
        self._on_packet = on_packet
        self._on_error = on_error
        self._driver = None
        self._next_open = 0.0
        self._closed = threading.Event()
        self._reader: threading.Thread | None = None

    def _open(self) -> bool:
        now = time.monotonic()
        if now < self._next_open or self._closed.is_set():
            return False
        self._next_open = now + REOPEN_S
        init_drivers()
        try:
            driver = cflib.crtp.get_link_driver(self.uri, None, self._driver_error)
        except Exception as exc:  # cflib raises plain Exceptions (no dongle, link already open, ...)
            self._on_error(self.vid, f"cannot open {self.uri}: {exc}")
            return False
        if driver is None:
            self._on_error(self.vid, f"no cflib driver for {self.uri}")
            return False
        self._driver = driver
        self._reader = threading.Thread(target=self._read, name=f"crtp-rx {self.vid}", daemon=True)
        self._reader.start()
        log.info("%s: link %s open (%s)", self.vid, self.uri, driver.get_name())
        return True

    def _driver_error(self, message: str) -> None:
        self._on_error(self.vid, message.splitlines()[0] if message else "link error")

    def send(self, raw: bytes) -> bool:
        """Send one packet (header byte + payload); False if the link is not open or still busy.

        cflib's `RadioDriver` keeps one packet per link in `out_queue` and retries it until the
        vehicle acknowledges; its `send_packet` would block up to 2 s on a full queue, stalling
        every vehicle of the radio behind one that went silent. A busy link skips this packet."""
        if self._driver is None and not self._open():
            return False
        pending = getattr(self._driver, "out_queue", None)
        if pending is not None and pending.full():
            return False
        self._driver.send_packet(CRTPPacket(raw[0], raw[1:]))
        return True

    def _read(self) -> None:
        driver = self._driver
        while not self._closed.is_set():
            try:
                pk = driver.receive_packet(_RECEIVE_WAIT_S)
            except Exception as exc:  # a driver failing mid-read: report and keep reading
                self._on_error(self.vid, f"receive failed: {exc}")
                self._closed.wait(_RECEIVE_WAIT_S)
                continue
            # the radio's empty acknowledgements come back as link-control packets: not worth a hand-over
            if pk is not None and pk.header >> 4 != _LINK_PORT:
                self._on_packet(self.vid, bytes((pk.header,)) + bytes(pk.data))

    def close(self) -> None:
        self._closed.set()
        if self._reader is not None:
            self._reader.join(timeout=2 * _RECEIVE_WAIT_S + 1.0)
        if self._driver is not None:
            try:
                self._driver.close()
            except Exception as exc:
                log.warning("%s: closing %s: %s", self.vid, self.uri, exc)
            self._driver = None


Batch = Sequence[tuple[CrtpLink, bytes]]


class RadioSender:
    """Sends each tick's batch in order on its own thread. If the radio falls behind by more than
    `max_pending` batches, the oldest waiting batch is dropped (counted as ``radio_behind`` in
    `counters`): a late setpoint is worth less than the next one."""

    def __init__(self, name: str, on_error: ErrorCallback, counters: Counters, max_pending: int = 2) -> None:
        self._queue: queue.Queue[Batch | None] = queue.Queue()
        self._max_pending = max_pending
        self._on_error = on_error
        self._counters = counters
        self._thread = threading.Thread(target=self._run, name=f"radio-tx {name}", daemon=True)
        self._thread.start()

    def submit(self, batch: Batch) -> None:
        while self._queue.qsize() >= self._max_pending:
            try:
                self._queue.get_nowait()
                self._counters.inc("radio_behind")
            except queue.Empty:
                break
        self._queue.put(batch)

    def _run(self) -> None:
        while (batch := self._queue.get()) is not None:
            for link, raw in batch:
                try:
                    link.send(raw)
                except Exception as exc:  # one bad link must not stop the radio
                    self._on_error(link.vid, f"send failed: {exc}")

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=3.0)
