"""A Crazyflie's firmware at the CRTP level, simulated: every port cflib 0.1.34 uses, answering as the
current crazyflie-firmware does (2026.08; sources and behaviours per row in docs/firmware_model.md).

I/O free: `receive(raw, now)` takes one packet and returns the packets to send back; `tick(now)`
runs the periodic tasks (every 10 ms: the high-level commander, the estimator and controller, the
wheel app; every 40 ms: the supervisor; due log blocks) and returns what the vehicle sends on its
own. The firmware drives `car` (`SimFlyingCar`): after every setpoint and every tick it applies the
attitude command the stabilizer would hand the motors (or motors off), and the wheel speeds.

Ports: 0 console (supervisor messages), 2 parameters, 3 RPYT setpoints, 4 memory (no memories),
5 log, 6 localization (external position and pose, emergency stop), 7 generic setpoints and
notify-setpoint-stop, 8 high-level commander, 9 supervisor, 13 platform (protocol version 12,
firmware version, device type, legacy arming; channel 2 the app: the wheel app when fitted), 15 link
(echo, source, sink). The radio chip's power commands (null packets starting 0xFE, cflib
`PowerSwitch`) reboot or power the firmware off and on; while it boots (`boot_s`) or is off, only the
radio chip answers. The power switch (`switch_off`, `switch_on`: fault injection) cuts the radio
chip too: nothing answers until it is switched on and has booted.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

from common.bus.messages import FlightSetpoint, StopSetpoint, WheelSetpoint
from common.crazyflie.crtp import (
    PORT_COMMANDER,
    PORT_COMMANDER_GENERIC,
    PORT_CONSOLE,
    PORT_HIGH_LEVEL,
    PORT_LINK,
    PORT_LOCALIZATION,
    PORT_LOG,
    PORT_MEM,
    PORT_PARAM,
    PORT_PLATFORM,
    PORT_SUPERVISOR,
)
from common.crazyflie.thrust import thrust_newtons
from common.domain.vehicle_model import G
from services.sim.crazyflie.firmware import logs, params
from services.sim.crazyflie.firmware.commander import (
    NULL,
    PRIO_CRTP,
    PRIO_HIGHLEVEL,
    Commander,
    HighLevel,
    Setpoint,
    generic,
)
from services.sim.crazyflie.firmware.logs import FLOAT, INT8, UINT8, UINT16, LogService, LogVar
from services.sim.crazyflie.firmware.onboard import (
    CF_MASS,
    COMPLEMENTARY,
    MELLINGER,
    MELLINGER_GAINS,
    PID,
    OnboardEstimator,
    OnboardState,
    PositionController,
)
from services.sim.crazyflie.firmware.params import CORE, EXTENDED, RONLY, Param, ParamService
from services.sim.crazyflie.firmware.supervisor import PERIOD_S, Inputs, State, Supervisor
from services.sim.crazyflie.firmware.wheels_app import AppView, WheelsApp
from services.sim.crazyflie.physics import SimFlyingCar

PROTOCOL_VERSION = 12
"""CRTP_PROTOCOL_VERSION (src/modules/interface/crtp.h)."""
FIRMWARE_VERSION = b"2026.08"
TICK_S = 0.01
"""The firmware's periodic work runs at 100 Hz here (the high-level commander's rate)."""
LINK_ACTIVITY_S = 1.0
"""CONFIG_RADIO_ACTIVITY_TIMEOUT_MS: the link counts as connected this long after a packet."""
ESTOP_WATCHDOG_S = 1.0
LOW_BATTERY_S = 5.0
"""DEFAULT_BAT_LOW_DURATION_TO_TRIGGER_SEC."""
PM_PERIOD_S = 0.1
"""pm_stm32f4.c `pmTask`: `vTaskDelay(100)` between its looks at the battery voltage."""
RADIO_ADDRESS = bytes.fromhex("e7e7e7e7e7e7")
FREE_FALL_G = 0.1
"""Specific force below which the supervisor sees free fall (all axes < 0.1 g)."""
RSSI = 40
"""radio.rssi, -dBm (a constant: the simulated radio has no signal strength)."""

POWER_PREFIX = 0xFE
PWR_ALLOFF, PWR_SYSOFF, PWR_SYSON, PWR_GETVBAT, PWR_RESET, PWR_RESET_INIT = 0x01, 0x02, 0x03, 0x04, 0xF0, 0xFF

Packet = bytes


def _h(port: int, channel: int) -> int:
    """The header byte the firmware builds (`CRTP_HEADER`: bits 3-2 clear)."""
    return (port & 0x0F) << 4 | (channel & 0x03)


@dataclass(frozen=True)
class Platform:
    """The vehicle: "Crazyflie 2.1" (brushed, arms itself) or "Crazyflie 2.1 Brushless" (needs an
    arming request; idle thrust 7000); `boot_s`: from power-on or reboot until CRTP answers."""

    name: str = "Crazyflie 2.1"
    auto_arm: bool = True
    idle_thrust: int = 0
    low_voltage: float = 3.2
    boot_s: float = 1.5


CF21 = Platform()
CF21_BRUSHLESS = Platform("Crazyflie 2.1 Brushless", auto_arm=False, idle_thrust=7000, low_voltage=3.35)


class CrazyflieFirmware:
    """One vehicle's firmware (module docstring); `wheels`: the wheel app is fitted (a flying car)."""

    def __init__(self, car: SimFlyingCar, platform: Platform = CF21, wheels: bool = True, seed: int = 0,
                 on_event: Callable[[str, str], None] | None = None) -> None:
        self.car = car
        self.platform = platform
        self.app = WheelsApp() if wheels else None
        self.on_event = on_event or (lambda kind, detail: None)
        self.supervisor = Supervisor(auto_arm=platform.auto_arm)
        self.commander = Commander(car.t)
        self.hl = HighLevel()
        self.estimator = OnboardEstimator(seed)
        self.controller = PositionController(car.model.mass)
        self.params = ParamService(self._param_table())
        self.logs = LogService(self._log_table())
        self.running = True
        self.booted_at = car.t
        self.boot_due: float | None = None
        self.powered = True
        self.estop_latched = False
        self.estop_watchdog_at: float | None = None
        self.last_rx = -math.inf
        self.received = 0
        self.malformed = 0
        self.echoes = 0
        """Link echo requests answered (cflib's link-statistics pings)."""
        self.locks = 0
        self.console: list[str] = []
        self._est: OnboardState | None = None
        self._last_tick = car.t
        self._next_supervisor = car.t
        self._low_since: float | None = None
        self._pm_due = car.t
        self._motor_cmd = 0
        self._control: FlightSetpoint | None = None
        self._power_due: tuple[float, int] | None = None
        self._start(car.t)  # the simulator starts with its vehicles switched on and booted

    # ---- tables ---------------------------------------------------------------------------------
    def _param_table(self) -> list[Param]:
        p = self.platform

        def est(v: float) -> None:
            self.estimator.kind = int(v) if int(v) in (1, 2) else 1
            self.params.values["stabilizer.estimator"] = self.estimator.kind

        def reset_est(v: float) -> None:
            if v:
                pv, c = self.params.values, self.car
                self.estimator.reset((c.x, c.y, c.z), c.yaw, initial=(pv["kalman.initialX"], pv["kalman.initialY"],
                                                                       pv["kalman.initialZ"]))
                pv["kalman.resetEstimation"] = 0  # cleared silently, as estimator_kalman.c does

        def ctrl(v: float) -> None:  # controller.c: 0 (any) is the PID; Mellinger is 2
            self.controller.kind = MELLINGER if int(v) == MELLINGER else PID

        def sup(attr: str) -> Callable[[float], None]:
            return lambda v: setattr(self.supervisor, attr, v / 1000.0)

        return [
            Param("stabilizer", "estimator", params.UINT8 | CORE, 1, est),
            Param("stabilizer", "controller", params.UINT8 | CORE, 1, ctrl),
            Param("ctrlMel", "mass", params.FLOAT | CORE | EXTENDED, CF_MASS,
                  lambda v: setattr(self.controller, "mel_mass", v)),
            *(Param("ctrlMel", name, params.FLOAT | CORE | EXTENDED, value, self._mel_gain(name))
              for name, value in MELLINGER_GAINS.items()),
            Param("stabilizer", "stop", params.UINT8 | CORE, 0),
            Param("commander", "enHighLevel", params.UINT8 | CORE, 0),
            Param("hlCommander", "vtoff", params.FLOAT | CORE, 0.5),
            Param("hlCommander", "vland", params.FLOAT | CORE, 0.5),
            Param("locSrv", "extPosStdDev", params.FLOAT | CORE, 0.01,
                  lambda v: setattr(self.estimator, "ext_std", max(v, 1e-6))),
            Param("locSrv", "extQuatStdDev", params.FLOAT | CORE, 0.0045),
            Param("kalman", "resetEstimation", params.UINT8 | CORE, 0, reset_est),
            Param("kalman", "initialX", params.FLOAT | CORE, 0.0),
            Param("kalman", "initialY", params.FLOAT | CORE, 0.0),
            Param("kalman", "initialZ", params.FLOAT | CORE, 0.0),
            Param("kalman", "initialYaw", params.FLOAT | CORE, 0.0),
            Param("motorPowerSet", "enable", params.UINT8 | CORE, 0),
            Param("supervisor", "infdmp", params.UINT8, 0),
            Param("supervisor", "prefltTimeout", params.UINT16 | EXTENDED, 30000, sup("preflight_timeout_s")),
            Param("supervisor", "landedTimeout", params.UINT16 | EXTENDED, 3000, sup("landed_timeout_s")),
            Param("supervisor", "tmblChckEn", params.UINT8 | EXTENDED, 1,
                  lambda v: setattr(self.supervisor, "tumble_check", bool(v))),
            Param("pm", "lowVoltage", params.FLOAT | CORE | EXTENDED, p.low_voltage),
            Param("pm", "criticalLowVoltage", params.FLOAT | CORE | EXTENDED, 3.0),
            Param("powerDist", "idleThrust", params.UINT16 | CORE | EXTENDED, p.idle_thrust),
            Param("crtpsrv", "echoDelay", params.UINT16, 0),
            Param("firmware", "revision0", params.UINT32 | RONLY, 0x2A18FC29),
            Param("system", "selftestPassed", params.INT8 | RONLY, 1),
        ]

    def _log_table(self) -> list[LogVar]:
        car = self.car

        def est(i: int) -> Callable[[], float]:
            return lambda: self._state().pos[i]

        def est_v(i: int) -> Callable[[], float]:
            return lambda: self._state().vel[i]

        ctrl = lambda: self._control  # noqa: E731
        return [
            LogVar("pm", "vbat", FLOAT, lambda: car.battery.vbat),
            LogVar("pm", "vbatMV", UINT16, lambda: round(car.battery.vbat * 1000.0)),
            LogVar("pm", "state", INT8, self._pm_state),
            LogVar("pm", "batteryLevel", UINT8, self._battery_level),
            LogVar("supervisor", "info", UINT16, self.info),
            LogVar("sys", "canfly", UINT8, lambda: int(self.supervisor.can_fly)),
            LogVar("sys", "isFlying", UINT8, lambda: int(self.supervisor.is_flying)),
            LogVar("sys", "isTumbled", UINT8, lambda: int(self.supervisor.cond.tumbled)),
            LogVar("radio", "rssi", UINT8, lambda: RSSI),
            LogVar("radio", "isConnected", UINT8, lambda: int(self.link_active(car.t))),
            LogVar("stateEstimate", "x", FLOAT, est(0)),
            LogVar("stateEstimate", "y", FLOAT, est(1)),
            LogVar("stateEstimate", "z", FLOAT, est(2)),
            LogVar("stateEstimate", "vx", FLOAT, est_v(0)),
            LogVar("stateEstimate", "vy", FLOAT, est_v(1)),
            LogVar("stateEstimate", "vz", FLOAT, est_v(2)),
            LogVar("stateEstimate", "roll", FLOAT, lambda: math.degrees(car.roll)),
            LogVar("stateEstimate", "pitch", FLOAT, lambda: -math.degrees(car.pitch)),  # the legacy sign
            LogVar("stateEstimate", "yaw", FLOAT, lambda: math.degrees(self._state().yaw)),
            LogVar("stabilizer", "thrust", FLOAT, lambda: float(self._motor_cmd)),
            LogVar("motor", "m1", UINT16, lambda: self._motor_cmd),
            LogVar("acc", "z", FLOAT, self._acc_z),
            LogVar("kalman", "varPX", FLOAT, lambda: self._variance(0)),
            LogVar("kalman", "varPY", FLOAT, lambda: self._variance(1)),
            LogVar("kalman", "varPZ", FLOAT, lambda: self._variance(2)),
            LogVar("locSrv", "x", FLOAT, lambda: (self.estimator.ext_pos or (0.0, 0.0, 0.0))[0]),
            LogVar("locSrv", "y", FLOAT, lambda: (self.estimator.ext_pos or (0.0, 0.0, 0.0))[1]),
            LogVar("locSrv", "z", FLOAT, lambda: (self.estimator.ext_pos or (0.0, 0.0, 0.0))[2]),
            LogVar("ctrltarget", "roll", FLOAT, lambda: ctrl().roll if ctrl() else 0.0),
            LogVar("ctrltarget", "pitch", FLOAT, lambda: ctrl().pitch if ctrl() else 0.0),
        ]

    def _mel_gain(self, name: str) -> Callable[[float], None]:
        return lambda v: self.controller.mel_gains.__setitem__(name, v)

    # ---- state ----------------------------------------------------------------------------------
    def _state(self) -> OnboardState:
        if self._est is None:
            c = self.car
            self._est = self.estimator.update(0.0, (c.x, c.y, c.z), (c.vx, c.vy, c.vz), c.yaw, c.yaw_rate)
        return self._est

    @property
    def motor_command(self) -> int:
        """The thrust command the stabilizer gives the motors now (0: motors off)."""
        return self._motor_cmd

    def uptime_ms(self, now: float) -> float:
        return (now - self.booted_at) * 1000.0

    def heard(self, now: float) -> None:
        """A packet reached the radio: any raw radio packet, a null one too, refreshes the link's
        activity (`radiolink.c: radiolinkSyslinkDispatch()`, `lastPacketTick`)."""
        if self.running:
            self.last_rx = now

    def link_active(self, now: float) -> bool:
        return now - self.last_rx < LINK_ACTIVITY_S

    def info(self) -> int:
        return self.supervisor.info(self.hl.active, self.hl.finished(self.car.t))

    def _pm_state(self) -> int:
        return 3 if self._low_since is not None and self.car.t - self._low_since > LOW_BATTERY_S else 0

    def _battery_level(self) -> int:
        curve = (3.00, 3.78, 3.83, 3.87, 3.89, 3.92, 3.96, 4.00, 4.04, 4.10)
        v = self.car.battery.vbat
        return 10 * sum(1 for c in curve[1:] if v >= c)

    def _variance(self, axis: int) -> float:
        """`kalman.varPX` ...: the Kalman filter's position variance (`onboard.py`)."""
        return self.estimator.variance(axis)

    def _acc_z(self) -> float:
        """Body z specific force in g (the supervisor's tumble input): 1 at rest, thrust over weight in
        flight, 0 in free fall."""
        c = self.car
        if not c.airborne:
            return math.cos(c.roll) * math.cos(c.pitch)
        return c.thrust / (c.mass * G)

    def _emergency_stop(self, now: float) -> bool:
        watchdog = self.estop_watchdog_at is not None and now >= self.estop_watchdog_at + ESTOP_WATCHDOG_S
        return self.estop_latched or watchdog or self.params.get("stabilizer.stop") != 0

    # ---- power and boot ---------------------------------------------------------------------------
    def _boot(self, now: float) -> None:
        """Power-on or reboot: everything in RAM back to its start (docs/firmware_model.md)."""
        self.running = False
        self.boot_due = now + self.platform.boot_s
        self.car.apply(StopSetpoint(), now)
        self._motor_cmd = 0
        self._control = None

    def _start(self, now: float) -> None:
        self.running = True
        self.boot_due = None
        self.booted_at = now
        self.params.reboot()
        self.logs.reset()
        self.supervisor.reboot(now)
        self.supervisor.auto_arm = self.platform.auto_arm
        self.commander.reboot(now)
        self.hl.reboot()
        c = self.car
        self.estimator.kind = COMPLEMENTARY
        self.estimator.ext_std = self.params.get("locSrv.extPosStdDev")
        self.estimator.ext_pos = self.estimator.ext_at = None
        self.estimator.ext_count = 0
        self.estimator.reset((c.x, c.y, c.z), c.yaw)
        self.controller.kind = PID
        self.controller.mel_mass = self.params.get("ctrlMel.mass")
        self.controller.mel_gains = {name: self.params.get(f"ctrlMel.{name}") for name in MELLINGER_GAINS}
        self.controller.reset()
        self.estop_latched = False
        self.estop_watchdog_at = None
        self._next_supervisor = now
        if self.app is not None:
            self.app.reboot()

    def power_off(self, now: float) -> None:
        self.running = False
        self.boot_due = None
        self.car.apply(StopSetpoint(), now)
        self._motor_cmd = 0

    def reboot(self, now: float) -> None:
        self._boot(now)

    def switch_off(self, now: float) -> None:
        """The power switch off (fault injection `power_off`): the radio chip too, so nothing answers
        on the radio, not even the power commands; motors off."""
        self.power_off(now)
        self.powered = False
        self._power_due = None
        self.on_event("sim_power_off", "switched off")

    def switch_on(self, now: float) -> None:
        """The power switch on: a fresh power-on (`_boot`), CRTP answers `boot_s` later."""
        self.powered = True
        self._power_due = None
        self.on_event("sim_power_on", "switched on: booting")
        self._boot(now)

    def _power(self, payload: bytes, now: float) -> list[Packet]:
        """The radio chip's power commands (crazyflie2-nrf-firmware `handleBootloaderCmd()`)."""
        if len(payload) < 2 or not self.powered:
            return []
        cmd = payload[1]
        if cmd == PWR_RESET_INIT:
            return [bytes((0xFF, POWER_PREFIX, PWR_RESET_INIT)) + RADIO_ADDRESS]
        if cmd == PWR_GETVBAT:
            return [bytes((0xFF, POWER_PREFIX, PWR_GETVBAT)) + struct.pack("<f", self.car.battery.vbat)]
        if cmd in (PWR_RESET, PWR_SYSOFF, PWR_SYSON, PWR_ALLOFF):
            self._power_due = (now + 0.1, cmd)
        return [bytes((0xFF, POWER_PREFIX, cmd))]

    def _power_action(self, cmd: int, now: float) -> None:
        if cmd in (PWR_RESET, PWR_SYSON):
            self.on_event("sim_reboot", "rebooted by the radio's power command")
            self._boot(now)
        elif cmd == PWR_SYSOFF:
            self.power_off(now)
        elif cmd == PWR_ALLOFF:
            self.power_off(now)
            self.powered = False

    # ---- packets ----------------------------------------------------------------------------------
    def receive(self, raw: bytes, now: float) -> list[Packet]:
        """One packet from the radio; the packets the vehicle sends back."""
        if not raw:
            return []
        port, ch, payload = raw[0] >> 4, raw[0] & 0x03, bytes(raw[1:])
        self.heard(now)
        if port == PORT_LINK and ch == 3:
            return self._power(payload, now) if payload[:1] == bytes((POWER_PREFIX,)) else []
        if not self.running:
            return []
        self.received += 1
        handler = self._ports.get(port)
        if handler is None:
            return []
        try:
            return handler(self, raw[0], ch, payload, now)
        except (struct.error, IndexError, ValueError):
            self.malformed += 1
            return []

    def _link(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        if ch == 0:
            self.echoes += 1
            return [bytes((header,)) + payload]  # echo
        if ch == 1:
            return [bytes((header,)) + b"Bitcraze Crazyflie".ljust(30, b"\0")]
        return []

    def _platform(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        if ch == 2:
            return self._app(payload, now)
        if ch == 1 and payload:
            cmd = payload[0]
            reply = {0: struct.pack("<i", PROTOCOL_VERSION), 1: FIRMWARE_VERSION,
                     2: self.platform.name.encode()}.get(cmd)
            return [] if reply is None else [bytes((header, cmd)) + reply]
        if ch == 0 and payload:
            if payload[0] == 1:  # legacy arming request
                ok = self.supervisor.request_arming(bool(payload[1]) if len(payload) > 1 else False)
                return [bytes((header, 1, int(ok), int(self.supervisor.armed)))]
            if payload[0] == 2:  # legacy crash recovery
                ok = self.supervisor.request_crash_recovery()
                return [bytes((header, 2, int(ok), int(not self.supervisor.crashed)))]
            return [bytes((header,)) + payload]
        return []

    def _app(self, payload: bytes, now: float) -> list[Packet]:
        if self.app is None or not payload:
            return []
        sup = self.supervisor
        view = AppView(uptime_ms=int(self.uptime_ms(now)) & 0xFFFFFFFF, vbat=self.car.battery.vbat,
                       setpoint_age_s=self.commander.age(now), motors=self._motor_cmd > 0, flying=sup.is_flying,
                       armed=sup.armed, locked=sup.locked, low_battery=self._pm_state() == 3)
        reply = self.app.receive(payload, now, view)
        self._wheels(now)
        return [] if reply is None else [reply]

    def _supervisor(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        if not payload:
            return []
        cmd, sup = payload[0], self.supervisor
        if ch == 0:
            info = self.info()
            if cmd == 0x0C:
                return [bytes((header, 0x8C)) + struct.pack("<H", info)]
            if 1 <= cmd <= 0x0B:
                return [bytes((header, cmd | 0x80, info >> (cmd - 1) & 1))]
            return []
        if cmd == 0x01:
            ok = sup.request_arming(bool(payload[1]) if len(payload) > 1 else False)
            return [bytes((header, 0x81, int(ok), int(sup.armed)))]
        if cmd == 0x02:
            ok = sup.request_crash_recovery()
            return [bytes((header, 0x82, int(ok), int(not sup.crashed)))]
        if cmd == 0x03:
            self._estop(now)
        elif cmd == 0x04:
            self.estop_watchdog_at = now
        return []

    def _estop(self, now: float) -> None:
        """Latched until a reboot; the supervisor acts on it at its next run (at most 40 ms later)."""
        if not self.estop_latched:
            self.estop_latched = True
            self.on_event("sim_emergency_stop", "emergency stop requested")

    def _localization(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        c = self.car
        if ch == 0 and len(payload) >= 12:
            self.estimator.on_ext_position(struct.unpack("<fff", payload[:12]), now, (c.x, c.y, c.z))
        elif ch == 1 and payload:
            kind = payload[0]
            if kind == 8 and len(payload) >= 29:
                x, y, z, qx, qy, qz, qw = struct.unpack("<fffffff", payload[1:29])
                self.estimator.on_ext_position((x, y, z), now, (c.x, c.y, c.z))
                self.estimator.on_ext_yaw(math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz)), c.yaw)
            elif kind == 3:
                self._estop(now)
            elif kind == 4:
                self.estop_watchdog_at = now
        self._est = None
        return []

    def _setpoint(self, sp: Setpoint | None, priority: int, now: float) -> None:
        if sp is None:
            self.malformed += 1
            return
        self.commander.set(sp, priority, now, self.hl)
        self._actuate(now)

    def _rpyt(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        if ch == 0:
            self._setpoint(self.commander.rpyt(payload), PRIO_CRTP, now)
        return []

    def _generic(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        if ch == 0:
            self._setpoint(generic(payload), PRIO_CRTP, now)
        elif ch == 1 and len(payload) >= 5 and payload[0] == 0:
            self.commander.relax()
        return []

    def _high_level(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        est = self._state()
        return [bytes((header,)) + self.hl.handle(payload, now, self.supervisor.can_fly, est.pos, est.yaw)]

    def _param(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        if ch == 0:
            reply = self.params.toc.answer(payload)
        else:
            reply = (self.params.read, self.params.write, self.params.misc)[ch - 1](payload)
        return [] if reply is None else [bytes((header,)) + reply]

    def _log(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        if ch == 0:
            reply = self.logs.toc.answer(payload)
        elif ch == 1:
            reply = self.logs.control(payload, self.uptime_ms(now))
        else:
            reply = None
        return [] if reply is None else [bytes((header,)) + reply]

    def _mem(self, header: int, ch: int, payload: bytes, now: float) -> list[Packet]:
        if ch == 0 and payload[:1] == b"\x01":
            return [bytes((header, 1, 0))]  # no memories
        return []

    _ports: dict[int, Callable[..., list[Packet]]] = {
        PORT_LINK: _link, PORT_PLATFORM: _platform, PORT_SUPERVISOR: _supervisor, PORT_LOCALIZATION: _localization,
        PORT_COMMANDER: _rpyt, PORT_COMMANDER_GENERIC: _generic, PORT_HIGH_LEVEL: _high_level,
        PORT_PARAM: _param, PORT_LOG: _log, PORT_MEM: _mem,
    }

    # ---- periodic work ------------------------------------------------------------------------------
    def tick(self, now: float) -> list[Packet]:
        """The firmware's periodic tasks up to `now`; the packets it sends on its own."""
        if self._power_due is not None and now >= self._power_due[0]:
            cmd = self._power_due[1]
            self._power_due = None
            self._power_action(cmd, now)
        if not self.running:
            if self.boot_due is None or now < self.boot_due:
                return []
            self._start(now)
            self.on_event("sim_booted", f"firmware {FIRMWARE_VERSION.decode()} up")
        dt = now - self._last_tick
        self._last_tick = now
        c = self.car
        self._est = self.estimator.update(dt, (c.x, c.y, c.z), (c.vx, c.vy, c.vz), c.yaw, c.yaw_rate)
        if self.supervisor.can_fly:
            self.commander.set(self.hl.setpoint(now), PRIO_HIGHLEVEL, now, self.hl)
        out: list[Packet] = []
        while now >= self._next_supervisor:
            out += self._run_supervisor(self._next_supervisor)
            self._next_supervisor += PERIOD_S
        self._actuate(now, dt)
        if self.app is not None:
            self.app.tick(now)
            self._wheels(now)
        self._battery(now)
        out += [bytes((_h(PORT_LOG, logs.CH_DATA),)) + data
                for data in self.logs.due(self.uptime_ms(now), self.link_active(now))]
        return out

    def _run_supervisor(self, at: float) -> list[Packet]:
        sup = self.supervisor
        before = sup.state
        acc_z = self._acc_z()
        if self.car.airborne and acc_z < FREE_FALL_G:
            acc_z = 1.0  # free fall resets the tumble check (isTumbledCheck())
        age = self.commander.age(at)
        sup.update(Inputs(now=at, setpoint_age_s=age, motors_above_idle=self._motor_cmd > self.platform.idle_thrust,
                          acc_z_g=acc_z, emergency_stop=self._emergency_stop(at)))
        if sup.state == before:
            return []
        text = {State.LOCKED: "Locked, reboot required", State.EXCEPT_FREE_FALL: "free falling!",
                State.CRASHED: "Crashed, recovery required", State.READY_TO_FLY: "Ready to fly"}.get(sup.state)
        if sup.state == State.WARNING_LEVEL_OUT:
            self.on_event("sim_watchdog_level", f"no setpoint for {age:.2f} s: levelled out")
        elif sup.state == State.EXCEPT_FREE_FALL:
            why = "emergency stop" if sup.cond.emergency_stop else f"no setpoint for {age:.2f} s"
            self.on_event("sim_watchdog_cut", f"{why}: motors stopped (free fall)")
        elif sup.state == State.LOCKED:
            self.locks += 1
            self.on_event("sim_locked", "supervisor locked: reboot required")
        elif sup.state == State.CRASHED:
            self.on_event("sim_crashed", "supervisor: crashed")
        if text is None:
            return []
        self.console.append(f"SUP: {text}")
        return [bytes((_h(PORT_CONSOLE, 0),)) + f"SUP: {text}\n".encode()[:30]]

    def _actuate(self, now: float, dt: float = 0.0) -> None:
        """The stabilizer: the setpoint in force, through the supervisor, to the motors."""
        sup = self.supervisor
        sp = self.commander.setpoint if sup.can_fly else NULL
        cmd = self.controller.command(sp, self._state(), dt, level=sup.level_out) if sup.motors_allowed else None
        if cmd is None or cmd.thrust <= 0:
            self._motor_cmd = 0
            self._control = None
            self.car.apply(FlightSetpoint(roll=0.0, pitch=0.0, yawrate=0.0, thrust=0), now)
            return
        self._control = cmd
        self._motor_cmd = cmd.thrust if thrust_newtons(cmd.thrust) > 0 else 0
        self.car.apply(cmd, now)

    def _wheels(self, now: float) -> None:
        if self.app is not None:
            left, right = self.app.speeds_m_s
            self.car.apply(WheelSetpoint(left=left, right=right), now)

    def _battery(self, now: float) -> None:
        """`pmTask`: every `PM_PERIOD_S`, whether the voltage is at or below `pm.lowVoltage` and since when."""
        if now < self._pm_due:
            return
        self._pm_due = now + PM_PERIOD_S
        low = self.car.battery.vbat <= self.params.get("pm.lowVoltage")
        if not low:
            self._low_since = None
        elif self._low_since is None:
            self._low_since = now
