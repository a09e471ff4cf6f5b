"""A simulated Crazyflie at a `udp://` URI: cflib's UDP driver's datagrams (one CRTP packet each) in
and out, the firmware model (`firmware/system.py`) behind them, `SimFlyingCar` physics under it.

Any cflib client connects to it as to a real vehicle (`Crazyflie`, `SyncCrazyflie`, `LogConfig`,
parameters, the high-level commander, `PowerSwitch`). Replies go to the address a request came
from; what the vehicle sends on its own (log data, console) goes to the last address that sent it a
packet. Every packet crosses the radio's link model (`SimRadio`) both ways. Over a Crazyradio cflib
resends a packet until the vehicle acknowledges it; over UDP it never resends, and one lost reply
in its connect sequence or a parameter update waits forever. So the request/reply traffic (ports
2, 4, 5 TOC and control, 8, 9, 13 channels 0-1, 15 channels 1 and 3) is delayed but never lost; the
streams (setpoints, external positions, log data, pings, the app channel) are lost at the link's
rate. A 1-byte 0xFF (cflib's scan) is answered with 0xFF. A vehicle switched off (`switch_off`,
fault injection) answers nothing at all until it is switched on again.

The physics advances in steps of `PhysicsParams.max_substep` (2 ms) up to the wall clock whenever the
simulator publishes truth, and up to a packet's delivery time when one is delivered, running the
firmware's periodic work at each 10 ms boundary; a setpoint takes effect at the step it arrives in.
Packets wait in time order for their delivery time, and an advance past it delivers them on the
way, each at its own time: a simulator whose loop was starved advances every vehicle to the wall
clock as soon as it runs again, before the deliveries it scheduled get their turn, and a setpoint
used to take effect only then, late by the stall (looked for after a loaded 32-vehicle soak in which
a driver rolled on 0.35 s, 6 cm, after its proximity stop, into the vehicle it had stopped 4 cm
short of: how much of that this was, the soak cannot tell).

Every datagram waiting at the vehicle's socket is read as soon as the event loop looks, each with the
time the kernel received it (Linux `SO_TIMESTAMPNS`), which the link model and the physics use. (The
endpoint used to be an asyncio datagram protocol, whose transport reads one datagram per socket per
loop iteration: a busy simulator of 32 vehicles let the kernel queue up to 177 kB, one to two seconds
of setpoints, which the vehicles then obeyed that late; a take-off's thrust held for five seconds sent
nine of them 25 m up. No Crazyradio delays a packet so: cflib's radio driver sends one at a time and
waits for its acknowledgement.)
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import logging
import math
import socket
import struct
import sys
import time
from collections.abc import Callable

from common.crazyflie import crtp
from services.sim.crazyflie.firmware.system import CF21, TICK_S, CrazyflieFirmware, Platform
from services.sim.crazyflie.physics import SimFlyingCar
from services.sim.crazyflie.radio import SimRadio

log = logging.getLogger(__name__)

EventCallback = Callable[[str, str, str], None]
"""``on_event(vid, kind, detail)``: something the firmware would notice (supervisor changes)."""

Address = tuple[str, int]

_SO_TIMESTAMPNS = 35
"""Linux `SO_TIMESTAMPNS` (include/uapi/asm-generic/socket.h; Python's socket module does not name
it): each datagram comes with the kernel's receive time (CLOCK_REALTIME) as a `struct timespec`."""
_TIMESPEC = struct.Struct("@qq")
_MAX_DATAGRAM = 64
"""Bytes: a CRTP packet is at most 32 (cflib's UDP driver sends header + payload)."""

_RELIABLE_PORTS = {crtp.PORT_PARAM, crtp.PORT_MEM, crtp.PORT_HIGH_LEVEL, crtp.PORT_SUPERVISOR}


def reliable(raw: bytes) -> bool:
    """A request or reply cflib waits for (module docstring): never lost in the link model."""
    port, ch = raw[0] >> 4, raw[0] & 0x03
    return (port in _RELIABLE_PORTS or (port == crtp.PORT_LOG and ch in (0, 1))
            or (port == crtp.PORT_PLATFORM and ch in (0, 1)) or (port == crtp.PORT_LINK and ch in (1, 3)))


class SimCrazyflie:
    """One simulated vehicle behind `radio`, at the UDP address given to `listen`. `clock` is wall
    time (epoch s): the car's clock too. `wheels`: the wheel app is fitted (a flying car; False for
    a stock Crazyflie)."""

    def __init__(self, car: SimFlyingCar, radio: SimRadio, on_event: EventCallback | None = None,
                 clock: Callable[[], float] = time.time, platform: Platform = CF21, wheels: bool = True) -> None:
        self.car = car
        self.vid = car.vid
        self.radio = radio
        self.on_event = on_event
        self.clock = clock
        self.step_s = car.params.max_substep
        self.firmware = CrazyflieFirmware(car, platform, wheels, on_event=self._event)
        self.hardest_touchdown = 0.0
        """Fastest touchdown so far (m/s, `SimFlyingCar.last_impact_speed`): above ~1 m/s a crash."""
        self.blacked_out = 0
        """Packets (both ways) lost to an injected radio blackout (`blackout`)."""
        self.flight_setpoints = 0
        self.last_flight_at: float | None = None
        self.max_flight_gap = 0.0
        """Longest gap (s) between two flight setpoints while the motors ran."""
        self.watchdog_levels = 0
        """Times the supervisor levelled the vehicle out for want of setpoints (WarningLevelOut), all boots."""
        self.watchdog_cuts = 0
        """Times it cut the motors in the air (ExceptFreeFall: watchdog timeout or emergency stop), all boots."""
        self._blackout_until = -math.inf
        self._switch_on_at: float | None = None
        self._next_tick = car.t + TICK_S
        self._peer: Address | None = None
        self._pending: list[tuple[float, int, bytes, Address]] = []
        """Packets on their way to the firmware: (delivery time, arrival order, packet, from), a heap."""
        self._order = itertools.count()
        self._sock: socket.socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.unsent = 0
        """Replies the socket could not take (its send buffer full): lost, as on a congested link."""

    # ---- what tests and the service read ----------------------------------------------------------
    @property
    def wheel_watchdogs(self) -> int:
        app = self.firmware.app
        return app.watchdog_trips if app is not None else 0

    @property
    def received(self) -> int:
        return self.firmware.received

    # ---- transport ------------------------------------------------------------------------
    def listen(self, addr: Address) -> None:
        """Take cflib's datagrams at `addr` (module docstring), on the running event loop."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setblocking(False)
        if sys.platform == "linux":
            sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        sock.bind(addr)
        self._sock, self._loop = sock, asyncio.get_running_loop()
        self._loop.add_reader(sock.fileno(), self._read)

    def _read(self) -> None:
        """Every datagram waiting, in order, each at the time the kernel received it."""
        assert self._sock is not None
        while True:
            try:
                data, ancillary, _flags, addr = self._sock.recvmsg(_MAX_DATAGRAM, socket.CMSG_SPACE(_TIMESPEC.size))
            except (BlockingIOError, InterruptedError):
                return
            now = self.clock()
            at = now
            for level, kind, value in ancillary:
                if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(value) >= _TIMESPEC.size:
                    sec, nsec = _TIMESPEC.unpack_from(value)
                    at = min(sec + nsec * 1e-9, now)
            self.datagram_received(data, addr, at)

    def blackout(self, until: float) -> None:
        """Fault injection (docs/reliability.md): the vehicle is out of the radio's range until `until`
        (this clock): every stream packet to or from it is lost, and the requests and replies cflib
        waits for arrive when the blackout ends (over a Crazyradio cflib resends them until then)."""
        self._blackout_until = until

    def switch_off(self, until: float | None = None) -> None:
        """Fault injection (docs/reliability.md): the vehicle's power switch off now (this clock), on
        again at `until` (None: until `switch_on`). Off, nothing answers on the radio and the motors
        stop; switched on, it boots as from a fresh power-on (`Platform.boot_s`)."""
        now = self.clock()
        self.advance(now)
        if self.firmware.powered:
            self.firmware.switch_off(self.car.t)
        self._switch_on_at = until

    def switch_on(self) -> None:
        """The power switch on now (nothing happens if it is on)."""
        self.advance(self.clock())
        self._switch_on_at = None
        if not self.firmware.powered:
            self.firmware.switch_on(self.car.t)

    @property
    def powered(self) -> bool:
        return self.firmware.powered

    def datagram_received(self, data: bytes, addr: Address, at: float | None = None) -> None:
        """A datagram from `addr` that reached the vehicle's radio at `at` (default: now)."""
        if not data or not self.firmware.powered:  # switched off: not even the radio chip answers
            return
        now = self.clock() if at is None else at
        if now < self._blackout_until:
            self.blacked_out += 1
            if reliable(data):  # cflib resends it until acknowledged: it arrives once the blackout ends
                asyncio.get_running_loop().call_later(self._blackout_until - now, self.datagram_received, data, addr)
            return
        if data == crtp.NULL_PACKET:  # cflib's scan, or a radio's poll: the link answers
            self.firmware.heard(now)
            self._reply(crtp.NULL_PACKET, addr)
            return
        due = self.radio.uplink(now, reliable(data))
        if due is not None:
            heapq.heappush(self._pending, (due, next(self._order), data, addr))
            asyncio.get_running_loop().call_later(max(due - self.clock(), 0.0), self.advance, due)

    def close(self) -> None:
        if self._sock is not None and self._loop is not None:
            if not self._loop.is_closed():
                self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None

    def _send(self, raw: bytes, addr: Address) -> None:
        if self._sock is None:
            return
        try:
            self._sock.sendto(raw, addr)
        except (BlockingIOError, InterruptedError):
            self.unsent += 1

    def _reply(self, raw: bytes, addr: Address) -> None:
        now = self.clock()
        if now < self._blackout_until:
            self.blacked_out += 1
            if reliable(raw):
                asyncio.get_running_loop().call_later(self._blackout_until - now, self._reply, raw, addr)
            return
        at = self.radio.downlink(now, reliable(raw))
        if at is not None:
            asyncio.get_running_loop().call_later(max(at - now, 0.0), self._send, raw, addr)

    # ---- time and packets -----------------------------------------------------------------
    def advance(self, now: float) -> None:
        """Step the physics in whole steps up to `now`, the firmware's periodic work at each tick,
        and every packet due by then delivered at its time (module docstring)."""
        while True:
            due = self._pending[0][0] if self._pending else math.inf
            if min(due, self._next_tick) > now:
                break
            if due < self._next_tick:
                _, _, data, addr = heapq.heappop(self._pending)
                self._step_to(due)
                self._deliver(data, addr)
                continue
            self._step_to(self._next_tick)
            if self._switch_on_at is not None and self._next_tick >= self._switch_on_at:
                self._switch_on_at = None
                self.firmware.switch_on(self._next_tick)
            for raw in self.firmware.tick(self._next_tick):
                if self._peer is not None:
                    self._reply(raw, self._peer)
            self._next_tick += TICK_S
        self._step_to(now)

    def _step_to(self, t: float) -> None:
        steps = int((t - self.car.t) / self.step_s + 1e-6)
        if steps > 0:
            self.car.step(steps * self.step_s)
            self.hardest_touchdown = max(self.hardest_touchdown, self.car.last_impact_speed)

    def _deliver(self, data: bytes, addr: Address) -> None:
        """The packet reaches the firmware now (the physics' clock: `advance` stepped it to the
        packet's delivery time)."""
        port = data[0] >> 4
        if port != crtp.PORT_LINK or data[0] & 0x03 != 3:
            self._peer = addr
        if port == crtp.PORT_COMMANDER:
            self._count_flight_setpoint(self.car.t)
        for raw in self.firmware.receive(data, self.car.t):
            self._reply(raw, addr)

    def _count_flight_setpoint(self, t: float) -> None:
        if self.last_flight_at is not None and self.car.thrust > 0.0:
            self.max_flight_gap = max(self.max_flight_gap, t - self.last_flight_at)
        self.flight_setpoints += 1
        self.last_flight_at = t

    def _event(self, kind: str, detail: str) -> None:
        if kind == "sim_watchdog_level":
            self.watchdog_levels += 1
        elif kind == "sim_watchdog_cut":
            self.watchdog_cuts += 1
        log.warning("%s: %s (%s)", self.vid, kind, detail)
        if self.on_event is not None:
            self.on_event(self.vid, kind, detail)
