"""The supervisor (crazyflie-firmware `src/modules/src/supervisor.c`, `supervisor_state_machine.c`,
docs/functional-areas/supervisor/): who may fly, and what it does when something goes wrong.

It runs at 25 Hz (every 40 ms, `supervisorUpdate()`); each run evaluates the conditions, takes at most
one transition (the first match in the current state's ordered list) and then the actions of the new
state. Conditions: armed; is flying (a motor above idle thrust within the last 2 s, the "is flying"
hysteresis); tumbled (tilted past ~60 deg for 1 s, or upside down for 0.1 s); commander watchdog
warning (no setpoint for 500 ms) and timeout (2000 ms); emergency stop; crashed; preflight timeout
(armed 30 s on the ground); landing timeout (3 s landed). The transitions that matter for a fleet:
Flying -> WarningLevelOut on the watchdog warning is checked *before* Flying -> Landed, and
WarningLevelOut only goes back to Flying (a fresh setpoint) or on to ExceptFreeFall and then Locked,
which only a reboot leaves. So a stop followed by silence while the motors ran less than 2 s ago locks
the vehicle (§12.7 of the research notes, firmware issue #1297).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class State(IntEnum):
    NOT_INITIALIZED = 0
    PRE_FLIGHT_CHECKS_NOT_PASSED = 1
    PRE_FLIGHT_CHECKS_PASSED = 2
    ARMING = 3
    READY_TO_FLY = 4
    FLYING = 5
    LANDED = 6
    RESET = 7
    WARNING_LEVEL_OUT = 8
    EXCEPT_FREE_FALL = 9
    LOCKED = 10
    CRASHED = 11


PERIOD_S = 0.04
"""RATE_SUPERVISOR: 25 Hz."""
WDT_WARNING_S = 0.5
"""COMMANDER_WDT_TIMEOUT_STABILIZE."""
WDT_TIMEOUT_S = 2.0
"""COMMANDER_WDT_TIMEOUT_SHUTDOWN."""
IS_FLYING_HYSTERESIS_S = 2.0
"""IS_FLYING_HYSTERESIS_THRESHOLD."""
TUMBLE_TILT_ACCZ, TUMBLE_TILT_S = 0.5, 1.0
"""SUPERVISOR_TUMBLE_CHECK_ACCEPTED_TILT_ACCZ / _TILT_TIME (platform_defaults.h)."""
TUMBLE_UPSIDE_DOWN_ACCZ, TUMBLE_UPSIDE_DOWN_S = -0.2, 0.1
SPINUP_TIMEOUT_S = 2.0

CAN_FLY = {State.READY_TO_FLY, State.FLYING, State.WARNING_LEVEL_OUT, State.LANDED}
MOTORS_ALLOWED = {State.ARMING, State.READY_TO_FLY, State.FLYING, State.WARNING_LEVEL_OUT, State.LANDED}
KEEPS_ARMING = MOTORS_ALLOWED

# supervisor.info bits (supervisor.c supervisorGetInfoField())
INFO_CAN_ARM, INFO_ARMED, INFO_AUTO_ARM, INFO_CAN_FLY = 0x0001, 0x0002, 0x0004, 0x0008
INFO_FLYING, INFO_TUMBLED, INFO_LOCKED, INFO_CRASHED = 0x0010, 0x0020, 0x0040, 0x0080
INFO_HL_ACTIVE, INFO_HL_FINISHED, INFO_HL_DISABLED = 0x0100, 0x0200, 0x0400


@dataclass
class Conditions:
    armed: bool = False
    flying: bool = False
    tumbled: bool = False
    wdt_warning: bool = False
    wdt_timeout: bool = False
    emergency_stop: bool = False
    crashed: bool = False
    preflight_timeout: bool = False
    landing_timeout: bool = False
    spinup_timeout: bool = False


@dataclass(frozen=True)
class Inputs:
    """What the supervisor looks at, sampled by the firmware each run."""

    now: float
    setpoint_age_s: float
    motors_above_idle: bool
    acc_z_g: float
    emergency_stop: bool


class Supervisor:
    """`auto_arm`: brushed Crazyflie 2.x (arms itself); False for the 2.1 Brushless, which needs an
    arming request (Kconfig MOTORS_REQUIRE_ARMING). Timeouts are the `supervisor.*` parameters."""

    def __init__(self, auto_arm: bool = True, preflight_timeout_s: float = 30.0,
                 landed_timeout_s: float = 3.0, tumble_check: bool = True) -> None:
        self.auto_arm = auto_arm
        self.preflight_timeout_s = preflight_timeout_s
        self.landed_timeout_s = landed_timeout_s
        self.tumble_check = tumble_check
        self.reboot(0.0)

    def reboot(self, now: float) -> None:
        self.state = State.NOT_INITIALIZED
        self.armed = False
        self.crashed = False
        self.cond = Conditions()
        self._latest_thrust = -1e9
        self._latest_arming = now
        self._latest_landing = now
        self._arming_since = now
        self._tumble_since: float | None = None
        self.transitions: list[tuple[float, State, State]] = []

    # ---- requests (port 9 ch 1, platform ch 0) ------------------------------------------------
    def request_arming(self, arm: bool) -> bool:
        """`supervisorRequestArming()`: arming only from PreFlChecksPassed; disarming always."""
        if arm == self.armed:
            return True
        if arm and self.state != State.PRE_FLIGHT_CHECKS_PASSED:
            return False
        self.armed = arm
        return True

    def request_crash_recovery(self) -> bool:
        """`supervisorRequestCrashRecovery()`: clears the crash unless still tumbled."""
        if not self.crashed:
            return True
        if self.cond.tumbled:
            return False
        self.crashed = False
        return True

    # ---- queries ------------------------------------------------------------------------------
    @property
    def can_fly(self) -> bool:
        return self.state in CAN_FLY

    @property
    def motors_allowed(self) -> bool:
        return self.state in MOTORS_ALLOWED

    @property
    def is_flying(self) -> bool:
        return self.state in (State.FLYING, State.WARNING_LEVEL_OUT)

    @property
    def locked(self) -> bool:
        return self.state == State.LOCKED

    @property
    def level_out(self) -> bool:
        return self.state == State.WARNING_LEVEL_OUT

    def info(self, hl_active: bool, hl_finished: bool) -> int:
        bits = 0
        for flag, on in ((INFO_CAN_ARM, self.state == State.PRE_FLIGHT_CHECKS_PASSED), (INFO_ARMED, self.armed),
                         (INFO_AUTO_ARM, self.auto_arm), (INFO_CAN_FLY, self.can_fly), (INFO_FLYING, self.is_flying),
                         (INFO_TUMBLED, self.cond.tumbled), (INFO_LOCKED, self.locked),
                         (INFO_CRASHED, self.crashed), (INFO_HL_ACTIVE, hl_active), (INFO_HL_FINISHED, hl_finished)):
            if on:
                bits |= flag
        return bits

    # ---- one run ------------------------------------------------------------------------------
    def update(self, inp: Inputs) -> None:
        self._conditions(inp)
        new = self._transition()
        if new is not None and new != self.state:
            self.transitions.append((inp.now, self.state, new))
            self.state = new
            self._entered(new, inp.now)

    def _conditions(self, inp: Inputs) -> None:
        now = inp.now
        if inp.motors_above_idle:
            self._latest_thrust = now
        c = self.cond
        c.armed = self.armed
        c.flying = now - self._latest_thrust < IS_FLYING_HYSTERESIS_S
        c.tumbled = self.tumble_check and self._tumbled(inp)
        c.wdt_warning = inp.setpoint_age_s > WDT_WARNING_S
        c.wdt_timeout = inp.setpoint_age_s > WDT_TIMEOUT_S
        c.emergency_stop = inp.emergency_stop
        c.crashed = self.crashed
        c.preflight_timeout = self.state == State.READY_TO_FLY and now - self._latest_arming > self.preflight_timeout_s
        c.landing_timeout = now - self._latest_landing > self.landed_timeout_s
        c.spinup_timeout = self.state == State.ARMING and now - self._arming_since > SPINUP_TIMEOUT_S

    def _tumbled(self, inp: Inputs) -> bool:
        """`isTumbledCheck()`: tilted (az < 0.5 g) for 1 s, or upside down (az < -0.2 g) for 0.1 s."""
        if inp.acc_z_g >= TUMBLE_TILT_ACCZ:
            self._tumble_since = None
            return False
        if self._tumble_since is None:
            self._tumble_since = inp.now
        held = inp.now - self._tumble_since
        return held > TUMBLE_TILT_S or (inp.acc_z_g < TUMBLE_UPSIDE_DOWN_ACCZ and held > TUMBLE_UPSIDE_DOWN_S)

    def _transition(self) -> State | None:
        """The first matching transition of the current state (supervisor_state_machine.c)."""
        c, s = self.cond, self.state
        if s == State.NOT_INITIALIZED:
            return State.PRE_FLIGHT_CHECKS_NOT_PASSED
        if s == State.PRE_FLIGHT_CHECKS_NOT_PASSED:
            if c.emergency_stop:
                return State.EXCEPT_FREE_FALL
            return None if c.tumbled else State.PRE_FLIGHT_CHECKS_PASSED
        if s == State.PRE_FLIGHT_CHECKS_PASSED:
            if c.emergency_stop:
                return State.EXCEPT_FREE_FALL
            if c.tumbled:
                return State.PRE_FLIGHT_CHECKS_NOT_PASSED
            return State.ARMING if c.armed else None
        if s == State.ARMING:
            if c.emergency_stop:
                return State.EXCEPT_FREE_FALL
            if c.tumbled or c.spinup_timeout or not c.armed:
                return State.PRE_FLIGHT_CHECKS_NOT_PASSED
            return State.READY_TO_FLY
        if s == State.READY_TO_FLY:
            if c.emergency_stop:
                return State.EXCEPT_FREE_FALL
            if c.tumbled or c.preflight_timeout or not c.armed:
                return State.PRE_FLIGHT_CHECKS_NOT_PASSED
            return State.FLYING if c.flying else None
        if s == State.FLYING:
            if c.wdt_timeout or c.emergency_stop:
                return State.EXCEPT_FREE_FALL
            if c.tumbled:
                return State.CRASHED
            if not c.armed:
                return State.RESET
            if c.wdt_warning:
                return State.WARNING_LEVEL_OUT
            return None if c.flying else State.LANDED
        if s == State.LANDED:
            if c.landing_timeout or not c.armed:
                return State.RESET
            return State.FLYING if c.flying else None
        if s == State.RESET:
            return State.PRE_FLIGHT_CHECKS_NOT_PASSED
        if s == State.WARNING_LEVEL_OUT:
            if c.wdt_timeout or c.tumbled or c.emergency_stop:
                return State.EXCEPT_FREE_FALL
            return State.FLYING if not c.wdt_warning else None
        if s == State.EXCEPT_FREE_FALL:
            return State.LOCKED
        if s == State.CRASHED:
            if not (c.crashed or c.tumbled):
                return State.PRE_FLIGHT_CHECKS_NOT_PASSED
            return State.LOCKED if c.emergency_stop else None
        return None  # LOCKED: reboot required

    def _entered(self, state: State, now: float) -> None:
        """`postTransitionActions()`."""
        if state == State.READY_TO_FLY:
            self._latest_arming = now
        elif state == State.LANDED:
            self._latest_landing = now
        elif state == State.ARMING:
            self._arming_since = now
        elif state == State.CRASHED:
            self.crashed = True
        if state not in KEEPS_ARMING:
            self.armed = False
        if state == State.PRE_FLIGHT_CHECKS_PASSED and self.auto_arm:
            self.armed = True
