"""Constants of the Crazyflie firmware (bitcraze/crazyflie-firmware) that the gateway and the
simulated Crazyflie both rely on; each names where the firmware defines it."""

WATCHDOG_LEVEL_S = 0.5
"""Crazyflie firmware COMMANDER_WDT_TIMEOUT_STABILIZE: level the attitude, keep the thrust."""
WATCHDOG_CUT_S = 2.0
"""Crazyflie firmware COMMANDER_WDT_TIMEOUT_SHUTDOWN: motors off."""
FIRMWARE_MIN_THRUST = 1000
"""crtp_commander_rpyt.c: a thrust command below this means motors off."""
