"""The commanders (crazyflie-firmware `src/modules/src/commander.c`, `crtp_commander.c`,
`crtp_commander_rpyt.c`, `crtp_commander_generic.c`, `crtp_commander_high_level.c`, `planner.c`).

One setpoint is in force at a time, with a priority: 0 DISABLE (boot only), 1 HIGHLEVEL, 2 CRTP
(every radio setpoint, ports 3 and 7). A setpoint is accepted only at or above the active priority;
a CRTP one also stops the high-level commander (`commanderSetSetpoint()`), whose setpoints are then
refused until a notify-setpoint-stop relaxes the priority (`commanderRelaxPriority()`). The
setpoint's timestamp is what the supervisor's watchdog ages (`supervisor.py`).

RPYT (port 3): `'<fffH'` roll, pitch (negated on the wire by cflib), yaw rate, thrust; the thrust is
locked at 0 after boot until one RPYT packet with thrust exactly 0 arrives, and a thrust below 1000
means motors off. Generic (port 7 channel 0): stop, position, velocity (world), z-distance, hover
(body velocities), full state, manual. Meta (port 7 channel 1): notify-setpoint-stop.

High level (port 8): take-off, land, go-to, stop, group mask. The planner is IDLE (it pushes a null
setpoint every 10 ms at priority 1, keeping the watchdog fed when nothing else commands), FLYING
(follows its trajectory, then holds the end) or LANDING (then IDLE). Take-off only from IDLE; a
go-to on the ground takes off. Trajectories are rest-to-rest 7th-order polynomials with zero
velocity, acceleration and jerk at both ends (`pptraj.c: poly7_nojerk`), or constant velocity
(`linear`). Every packet is answered `[cmd, d1, d2, ret]`: 0 ok, 1 refused by the planner, EBUSY
when the supervisor says the vehicle cannot fly.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

PORT_RPYT, PORT_GENERIC, PORT_HIGH_LEVEL = 3, 7, 8
PRIO_DISABLE, PRIO_HIGHLEVEL, PRIO_CRTP = 0, 1, 2
MIN_THRUST, MAX_THRUST = 1000, 60000
EBUSY, ENOEXEC = 16, 8
HL_PERIOD_S = 0.01
"""RATE_HL_COMMANDER: 100 Hz."""

Vec3 = tuple[float, float, float]
ZERO: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class Setpoint:
    """What the stabilizer acts on, reduced to what the simulated controller uses.

    kind: "null" (motors off), "attitude" (roll/pitch deg in cflib's `send_setpoint` sense, yaw rate
    deg/s clockwise-positive as cflib sends it, raw thrust), "position" (pos, vel, acc feed-forward,
    absolute yaw rad CCW), "velocity" (world vel, yaw rate rad/s CCW), "hover" (body vx, vy, yaw rate,
    absolute z), "zdistance" (roll, pitch deg, yaw rate, absolute z)."""

    kind: str
    roll: float = 0.0
    pitch: float = 0.0
    yaw_rate: float = 0.0
    thrust: int = 0
    pos: Vec3 = ZERO
    vel: Vec3 = ZERO
    acc: Vec3 = ZERO
    yaw: float | None = None


NULL = Setpoint("null")


class Commander:
    """The setpoint in force and its priority; `thrust_locked` is the RPYT lock."""

    def __init__(self, now: float) -> None:
        self.reboot(now)

    def reboot(self, now: float) -> None:
        self.priority = PRIO_DISABLE
        self.setpoint = NULL
        self.timestamp = now
        self.thrust_locked = True
        self.last_crtp_at: float | None = None

    def set(self, sp: Setpoint, priority: int, now: float, hl: HighLevel) -> bool:
        if priority < self.priority:
            return False
        self.setpoint, self.timestamp, self.priority = sp, now, priority
        if priority > PRIO_HIGHLEVEL:
            self.last_crtp_at = now
            hl.stop(now)
        return True

    def relax(self) -> None:
        self.priority = PRIO_HIGHLEVEL

    def age(self, now: float) -> float:
        return now - self.timestamp

    # ---- decoding ---------------------------------------------------------------------------
    def rpyt(self, payload: bytes) -> Setpoint | None:
        """`crtpCommanderRpytDecodeSetpoint()`; None if malformed."""
        if len(payload) < 14:
            return None
        roll, wire_pitch, yaw_rate, raw = struct.unpack("<fffH", payload[:14])
        if self.priority == PRIO_DISABLE:
            self.thrust_locked = True
        if raw == 0:
            self.thrust_locked = False
        thrust = 0 if self.thrust_locked or raw < MIN_THRUST else min(raw, MAX_THRUST)
        return Setpoint("attitude", roll=roll, pitch=-wire_pitch, yaw_rate=yaw_rate, thrust=thrust)


def generic(payload: bytes) -> Setpoint | None:
    """`crtpCommanderGenericDecodeSetpoint()`: a setpoint, None if malformed; unknown types stop."""
    if not payload:
        return None
    kind, body = payload[0], payload[1:]

    def floats(n: int) -> tuple[float, ...] | None:
        return struct.unpack(f"<{n}f", body[:4 * n]) if len(body) >= 4 * n else None

    if kind == 0:
        return NULL
    if kind == 7:  # position: x, y, z m, yaw deg
        v = floats(4)
        return None if v is None else Setpoint("position", pos=v[:3], yaw=math.radians(v[3]))
    if kind == 8:  # velocity world: vx, vy, vz, yaw rate deg/s
        v = floats(4)
        return None if v is None else Setpoint("velocity", vel=v[:3], yaw_rate=math.radians(v[3]))
    if kind == 9:  # z distance: roll, pitch deg, yaw rate deg/s, z
        v = floats(4)
        return None if v is None else Setpoint("zdistance", roll=v[0], pitch=v[1], yaw_rate=math.radians(v[2]),
                                               pos=(0.0, 0.0, v[3]))
    if kind == 10:  # hover: vx, vy body, yaw rate deg/s, z
        v = floats(4)
        return None if v is None else Setpoint("hover", vel=(v[0], v[1], 0.0), yaw_rate=math.radians(v[2]),
                                               pos=(0.0, 0.0, v[3]))
    if kind == 6 and len(body) >= 28:  # full state: pos, vel, acc (mm, mm/s, mm/s^2), compressed quat, rates
        vals = struct.unpack("<hhhhhhhhhI", body[:22])
        pos = tuple(v / 1000.0 for v in vals[0:3])
        vel = tuple(v / 1000.0 for v in vals[3:6])
        acc = tuple(v / 1000.0 for v in vals[6:9])
        return Setpoint("position", pos=pos, vel=vel, acc=acc, yaw=_yaw_of_compressed(vals[9]))  # type: ignore[arg-type]
    if kind == 11 and len(body) >= 15:  # manual: roll, pitch, yaw rate, thrust u16, rate mode
        roll, wire_pitch, yaw_rate, thrust = struct.unpack("<fffH", body[:14])
        return Setpoint("attitude", roll=roll, pitch=-wire_pitch, yaw_rate=yaw_rate, thrust=thrust)
    if kind in (1, 2, 3, 4, 5):
        return None  # legacy and RC-emulation types: not simulated
    return NULL


def _yaw_of_compressed(q: int) -> float:
    """Yaw (rad) of a `quatcompress` quaternion (the 'smallest three' encoding)."""
    i_largest = q >> 30
    sum_squares = 0.0
    comps = [0.0] * 4
    mask = (1 << 9) - 1
    for i in (3, 2, 1, 0):
        if i != i_largest:
            mag, negbit = q & mask, (q >> 9) & 1
            q >>= 10
            comps[i] = (mag / mask) / math.sqrt(2.0) * (-1.0 if negbit else 1.0)
            sum_squares += comps[i] ** 2
    comps[i_largest] = math.sqrt(max(0.0, 1.0 - sum_squares))
    x, y, z, w = comps
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


# ---- the high-level commander -------------------------------------------------------------------
IDLE, FLYING, LANDING = 0, 1, 3


def _poly7(tau: float) -> tuple[float, float, float]:
    """Rest-to-rest 7th-order blend s(tau), s', s'' (zero vel, acc and jerk at both ends)."""
    tau = min(max(tau, 0.0), 1.0)
    s = tau**4 * (35 - 84 * tau + 70 * tau**2 - 20 * tau**3)
    ds = tau**3 * (140 - 420 * tau + 420 * tau**2 - 140 * tau**3)
    dds = tau**2 * (420 - 1680 * tau + 2100 * tau**2 - 840 * tau**3)
    return s, ds, dds


@dataclass
class _Trajectory:
    t0: float
    duration: float
    start: Vec3
    end: Vec3
    yaw0: float
    yaw1: float
    linear: bool = False

    def sample(self, t: float) -> tuple[Vec3, Vec3, Vec3, float]:
        d = max(self.duration, 1e-6)
        tau = (t - self.t0) / d
        if self.linear:
            s, ds, dds = min(max(tau, 0.0), 1.0), (1.0 if 0.0 <= tau <= 1.0 else 0.0), 0.0
        else:
            s, ds, dds = _poly7(tau)
        delta = tuple(b - a for a, b in zip(self.start, self.end, strict=True))
        pos = tuple(a + s * dlt for a, dlt in zip(self.start, delta, strict=True))
        vel = tuple(ds / d * dlt for dlt in delta)
        acc = tuple(dds / d**2 * dlt for dlt in delta)
        return pos, vel, acc, self.yaw0 + s * (self.yaw1 - self.yaw0)  # type: ignore[return-value]

    def finished(self, t: float) -> bool:
        return t - self.t0 >= self.duration


class HighLevel:
    """The planner of port 8 (module docstring)."""

    def __init__(self) -> None:
        self.reboot()

    def reboot(self) -> None:
        self.state = IDLE
        self.traj: _Trajectory | None = None
        self.group_mask = 0
        self.ever = False

    @property
    def active(self) -> bool:
        return self.state in (FLYING, LANDING)

    def finished(self, t: float) -> bool:
        return self.traj is None or self.traj.finished(t)

    def stop(self, now: float) -> None:
        self.state = IDLE
        self.traj = None

    def handle(self, payload: bytes, now: float, can_fly: bool, est_pos: Vec3, est_yaw: float) -> bytes:
        """Reply `[cmd, d1, d2, ret]` (`crtpCommanderHighLevelTask()`)."""
        head = (payload[:3] + b"\0\0\0")[:3]
        return head + bytes((self._run(payload, now, can_fly, est_pos, est_yaw),))

    def _run(self, payload: bytes, now: float, can_fly: bool, est_pos: Vec3, est_yaw: float) -> int:
        if not payload:
            return ENOEXEC
        cmd = payload[0]
        if cmd == 0 and len(payload) >= 2:  # set group mask
            self.group_mask = payload[1]
            return 0
        if cmd == 3 and len(payload) >= 2:  # stop
            if self._mine(payload[1]):
                self.stop(now)
            return 0
        if cmd not in (7, 8, 12):
            return ENOEXEC
        if not can_fly:
            return EBUSY
        if cmd in (7, 8) and len(payload) >= 15:
            mask, height, yaw, use_current, duration = struct.unpack("<BBff?f", payload[:15])[1:]
            if not self._mine(mask):
                return 0
            if cmd == 7 and self.state != IDLE:
                return 1
            if cmd == 8 and self.state == LANDING:
                return 1
            start, yaw0 = self._start(est_pos, est_yaw, now)
            yaw1 = yaw0 if use_current else _shortest(yaw0, yaw)
            self.traj = _Trajectory(now, duration, start, (start[0], start[1], height), yaw0, yaw1)
            self.state = FLYING if cmd == 7 else LANDING
            self.ever = True
            return 0
        if cmd == 12 and len(payload) >= 24:
            mask, relative, linear, x, y, z, yaw, duration = struct.unpack("<BBBBfffff", payload[:24])[1:]
            if not self._mine(mask):
                return 0
            start, yaw0 = self._start(est_pos, est_yaw, now)
            end = (start[0] + x, start[1] + y, start[2] + z) if relative else (x, y, z)
            yaw1 = yaw0 + yaw if relative else _shortest(yaw0, yaw)
            self.traj = _Trajectory(now, duration, start, end, yaw0, yaw1, bool(linear))
            self.state = FLYING
            self.ever = True
            return 0
        return ENOEXEC

    def _mine(self, mask: int) -> bool:
        return mask == 0 or bool(mask & self.group_mask)

    def _start(self, est_pos: Vec3, est_yaw: float, now: float) -> tuple[Vec3, float]:
        """From the state estimate when idle, else from where the current trajectory is now."""
        if self.state == IDLE or self.traj is None:
            return est_pos, est_yaw
        pos, _vel, _acc, yaw = self.traj.sample(now)
        return pos, yaw

    def setpoint(self, now: float) -> Setpoint:
        """What the planner commands now (`crtpCommanderHighLevelGetSetpoint()`)."""
        if self.state == IDLE or self.traj is None:
            return NULL
        pos, vel, acc, yaw = self.traj.sample(now)
        if self.state == LANDING and self.traj.finished(now):
            self.state = IDLE
            return NULL
        return Setpoint("position", pos=pos, vel=vel, acc=acc, yaw=yaw)


def _shortest(yaw0: float, yaw: float) -> float:
    return yaw0 + math.remainder(yaw - yaw0, 2.0 * math.pi)
