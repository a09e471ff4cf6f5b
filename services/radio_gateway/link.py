"""The radio side of the gateway: one cflib `Crazyflie` per vehicle, and one sender thread per radio.

`cflib.crtp.get_link_driver(uri)` picks the driver from the URI, so ``radio://0/80/2M/E7E7E7E7E7``
(a Crazyradio: cflib's `RadioDriver`, several links sharing one dongle) and ``udp://127.0.0.1:19850``
(a simulated Crazyflie, `fleet sim`) go through exactly this code. The standard services do the
slow work: cflib connects (protocol version, log and parameter tables; cached by CRC), the radios
file's parameters are written, and one log block streams `pm.vbatMV`, `pm.state`,
`supervisor.info` and `radio.rssi` (`LOG_VARIABLES`): battery, supervisor and link health come from
the firmware as it is, with or without our wheel app. The firmware and device versions are asked
once per connection (platform port, channel 1).

The gateway's own traffic (setpoints, stops, notify-setpoint-stop, supervisor requests, wheel
packets) goes out as raw packets through `Crazyflie.send_packet`: a Crazyradio send blocks while
the dongle is busy, so sends never run on the event loop; each tick's batch goes to the
`RadioSender` thread. A packet is skipped (and counted where it happens, `skipped:<why>:<vid>`)
when the vehicle is not connected or its link still holds an unsent packet: cflib's `RadioDriver`
keeps one packet per link and retries it until acknowledged, and its `send_packet` would block up
to 2 s, stalling every vehicle of the radio behind one that went silent.

Opening, closing and rebooting block (threads join, a power command waits for its answer): the
gateway runs them off its loop. cflib's callbacks arrive on cflib's threads and are handed to the
gateway's loop by the callbacks given here.
"""

from __future__ import annotations

import logging
import queue
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import cflib.crtp
from cflib.crazyflie import Crazyflie
from cflib.crazyflie.log import LogConfig
from cflib.crtp.crtpstack import CRTPPacket
from cflib.utils.power_switch import PowerSwitch

from common.bus.pubsub import Counters
from common.crazyflie import crtp

log = logging.getLogger(__name__)

LogCallback = Callable[[str, float, dict[str, float]], None]
"""``on_log(vid, arrival time, {variable: value})`` on a cflib thread."""
PacketCallback = Callable[[str, bytes], None]
"""``on_app(vid, raw)``: an app-channel packet (header byte + payload) on a cflib thread."""
StateCallback = Callable[[str, str, str], None]
"""``on_state(vid, state, detail)``: "connected", "failed", "lost", "closed", "info" on a cflib or worker thread."""
ErrorCallback = Callable[[str, str], None]
"""``on_error(vid, message)`` on the sender thread."""

LOG_VARIABLES: tuple[tuple[str, str], ...] = (
    ("pm.vbatMV", "uint16_t"), ("pm.state", "int8_t"), ("supervisor.info", "uint16_t"), ("radio.rssi", "uint8_t"))
"""The gateway's log block: battery (mV, power manager state), supervisor state bits, link RSSI."""
TOC_CACHE = Path(tempfile.gettempdir()) / "fleet-toc-cache"
"""Log and parameter tables by CRC, shared by every gateway of this machine (cflib's cache)."""
CLOSE_WAIT_S = 3.0
"""s `VehicleLink.close` waits at most for cflib to close a link (the driver's thread joined: a
Crazyradio's waits for its last packet)."""
_init_lock = threading.Lock()


def init_drivers() -> None:
    """`cflib.crtp.init_drivers()` once per process (each call would register the drivers again).
    cflib's own warning on a link error (with the driver's traceback) is silenced: the gateway
    reports every link that fails or is lost as an event with the reason."""
    with _init_lock:
        if not cflib.crtp.CLASSES:
            cflib.crtp.init_drivers()
            logging.getLogger("cflib.crazyflie").setLevel(logging.ERROR)


class VehicleLink:
    """One vehicle's connection (module docstring). `params`: written once connected."""

    def __init__(self, vid: str, uri: str, params: Mapping[str, float], log_period_ms: int, on_log: LogCallback,
                 on_app: PacketCallback, on_state: StateCallback) -> None:
        self.vid = vid
        self.uri = uri
        self.params = dict(params)
        self.log_period_ms = log_period_ms
        self._on_log, self._on_app, self._on_state = on_log, on_app, on_state
        self._cf: Crazyflie | None = None
        self._log_config: LogConfig | None = None
        self._ready = threading.Event()
        self._lock = threading.Lock()
        self.firmware = ""
        self.device = ""

    @property
    def ready(self) -> bool:
        """Connected, tables fetched, parameters written, log block started."""
        return self._ready.is_set()

    # ---- lifecycle (blocking: run off the event loop) --------------------------------------------
    def open(self) -> None:
        """Start connecting; "connected" (or "failed") is reported through `on_state`."""
        init_drivers()
        TOC_CACHE.mkdir(parents=True, exist_ok=True)
        cf = Crazyflie(rw_cache=str(TOC_CACHE))
        # cflib pings every connected link 10 times a second for its link statistics
        # (`link_statistics.py`, started on `connected`), airtime outside the gateway's schedule and a
        # percentile over the last 100 round trips per answer; the gateway judges a link by its log
        # block, so the pings stop as soon as they start
        cf.connected.add_callback(lambda _uri: cf.link_statistics.stop())
        cf.fully_connected.add_callback(lambda _uri: self._connected(cf))
        cf.connection_failed.add_callback(lambda _uri, msg: self._ended(cf, "failed", msg))
        cf.connection_lost.add_callback(lambda _uri, msg: self._ended(cf, "lost", msg))
        cf.appchannel.packet_received.add_callback(self._while_current(
            cf, lambda data: self._on_app(self.vid, bytes((crtp.PORT_PLATFORM << 4 | crtp.APP_CHANNEL,)) + bytes(data))))
        cf.add_port_callback(crtp.PORT_PLATFORM, self._while_current(cf, self._on_platform))
        with self._lock:
            self._cf = cf
        try:
            cf.open_link(self.uri)
        except Exception as exc:  # cflib raises plain Exceptions (no dongle, link already open, ...)
            self._ended(cf, "failed", f"cannot open {self.uri}: {exc}")

    def close(self) -> None:
        """Close the link (cflib sends one zero setpoint first, as `close_link` always does);
        returns once the link is closed, or after `CLOSE_WAIT_S` with a warning."""
        with self._lock:
            cf, self._cf = self._cf, None
        self._ready.clear()
        if cf is None:
            return
        # `close_link` closes the link, then waits up to 1 s for its packet thread, blocked on the
        # link's queue for as long (`incoming.join(timeout=1)`): that wait goes on without us
        closing = threading.Thread(target=self._close_link, args=(cf,), name=f"close {self.vid}", daemon=True)
        closing.start()
        deadline = time.monotonic() + CLOSE_WAIT_S
        while cf.link is not None and closing.is_alive():
            if time.monotonic() > deadline:
                log.warning("%s: %s not closed within %.0f s; going on", self.vid, self.uri, CLOSE_WAIT_S)
                return
            time.sleep(0.005)

    def _while_current(self, cf: Crazyflie, fn: Callable[..., object]) -> Callable[..., None]:
        """`fn` as a callback of `cf` that does nothing once `cf` is not this link's connection (a
        closed link's packet thread may hand on one more packet after `close` returned)."""
        def callback(*args: object) -> None:
            if cf is self._cf:
                fn(*args)
        return callback

    def _close_link(self, cf: Crazyflie) -> None:
        """cflib's `close_link` (on a thread of its own: `close`)."""
        try:
            cf.close_link()
        except Exception as exc:
            log.warning("%s: closing %s: %s", self.vid, self.uri, exc)

    def reboot(self) -> None:
        """Close, then reboot the vehicle through its radio chip (cflib `PowerSwitch`)."""
        self.close()
        init_drivers()
        switch = PowerSwitch(self.uri)
        try:
            switch.reboot_to_fw()
        finally:
            switch.close()

    # ---- cflib callbacks (cflib's threads) -----------------------------------------------------------
    def _connected(self, cf: Crazyflie) -> None:
        if cf is not self._cf:
            return
        for name, value in self.params.items():
            try:
                cf.param.set_value(name, value)
            except (KeyError, AttributeError, ValueError) as exc:
                self._on_state(self.vid, "info", f"parameter {name} not set: {exc}")
        missing = [name for name, _kind in LOG_VARIABLES if cf.log.toc.get_element_by_complete_name(name) is None]
        self._log_config = None  # a new connection: the firmware has no block of ours
        self._start_log(cf)
        for cmd in (1, 2):  # firmware version, device type
            cf.send_packet(CRTPPacket(crtp.header(crtp.PORT_PLATFORM, 1), bytes((cmd,))))
        self._ready.set()
        detail = f"connected to {self.uri}" + (f"; no {', '.join(missing)} in its log table" if missing else "")
        self._on_state(self.vid, "connected", detail)

    def _start_log(self, cf: Crazyflie) -> None:
        config = LogConfig("fleet", self.log_period_ms)
        for name, kind in LOG_VARIABLES:
            if cf.log.toc.get_element_by_complete_name(name) is not None:
                config.add_variable(name, kind)
        config.data_received_cb.add_callback(
            self._while_current(cf, lambda _ts, data, _conf: self._on_log(self.vid, time.time(), data)))
        old, self._log_config = self._log_config, None
        if old is not None:  # first: its id is free again, and no start of it can come after the delete
            old.delete()
        try:
            cf.log.add_config(config)
            config.start()
        except (KeyError, AttributeError) as exc:
            self._on_state(self.vid, "info", f"log block refused: {exc}")
            return
        self._log_config = config

    def refresh_log(self) -> None:
        """Create the log block again: the firmware drops every block when its radio heard nothing for
        a second (`log.c: logRunBlock()`, `radiolinkIsConnected()`), so after a blackout the old one
        is gone. Also the probe of a silent link: the block streams again once the vehicle hears us."""
        cf = self._cf
        if cf is not None and self._ready.is_set():
            self._start_log(cf)

    def _ended(self, cf: Crazyflie, state: str, message: str) -> None:
        if cf is self._cf:
            self._ready.clear()
            self._on_state(self.vid, state, message.splitlines()[0] if message else state)

    def _on_platform(self, pk: CRTPPacket) -> None:
        if pk.channel != 1 or not pk.data:
            return
        text = bytes(pk.data[1:]).decode(errors="replace").strip("\0")
        if pk.data[0] == 1:
            self.firmware = text
        elif pk.data[0] == 2:
            self.device = text
        else:
            return
        self._on_state(self.vid, "info", f"{'firmware' if pk.data[0] == 1 else 'device'} {text}")

    # ---- sending (the sender thread) ------------------------------------------------------------------
    def send(self, raw: bytes) -> str | None:
        """Send one packet (header byte + payload); why it was skipped, or None if it went out."""
        cf = self._cf
        if cf is None or not self._ready.is_set() or cf.link is None:
            return "not_connected"
        pending = getattr(cf.link, "out_queue", None)
        if pending is not None and pending.full():
            return "busy"
        cf.send_packet(CRTPPacket(raw[0], raw[1:]))
        return None


Batch = Sequence[tuple[VehicleLink, bytes]]


class RadioSender:
    """Sends each tick's batch in order on its own thread. If the radio falls behind by more than
    `max_pending` batches, the oldest waiting batch is dropped (counted as ``radio_behind`` in
    `counters`): a late setpoint is worth less than the next one. Skipped packets are counted as
    ``skipped:<why>:<vid>``."""

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
                    skipped = link.send(raw)
                except Exception as exc:  # one bad link must not stop the radio
                    self._on_error(link.vid, f"send failed: {exc}")
                    continue
                if skipped is not None:
                    self._counters.inc(f"skipped:{skipped}:{link.vid}")

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=3.0)
