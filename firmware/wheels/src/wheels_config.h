/*
 * Build-time configuration of the wheel app: motor driver and deck pins (see ../README.md,
 * "Wiring"). Every value can be overridden from the command line, for example
 *
 *   make CRAZYFLIE_BASE=~/crazyflie-firmware \
 *        EXTRA_CFLAGS="-DWHEELS_USE_TB6612=1 -DWHEELS_PIN_LEFT_IN2=DECK_GPIO_TX1"
 *
 * (the firmware's out-of-tree build passes EXTRA_CFLAGS to every file it compiles). The
 * firmware's own Kconfig does not read an out-of-tree app's Kconfig, hence #defines.
 *
 * Only the glue (wheels_app.c) includes this file: it names deck pins.
 */
#ifndef WHEELS_CONFIG_H
#define WHEELS_CONFIG_H

/* Motor driver: 0 = DRV8833 (4 signals), 1 = TB6612FNG (6 signals, + STBY). */
#ifndef WHEELS_USE_TB6612
#define WHEELS_USE_TB6612 0
#endif

/* Direction inputs (any deck GPIO: DECK_GPIO_IO1..IO4, TX1, RX1, TX2, RX2, SCK, MISO, MOSI, SDA,
 * SCL). DRV8833: AIN1 / BIN1. TB6612FNG: AIN1 / BIN1 and AIN2 / BIN2. */
#ifndef WHEELS_PIN_LEFT_IN1
#define WHEELS_PIN_LEFT_IN1 DECK_GPIO_IO1
#endif
#ifndef WHEELS_PIN_RIGHT_IN1
#define WHEELS_PIN_RIGHT_IN1 DECK_GPIO_IO4
#endif
#ifndef WHEELS_PIN_LEFT_IN2 /* TB6612FNG only */
#define WHEELS_PIN_LEFT_IN2 DECK_GPIO_TX2
#endif
#ifndef WHEELS_PIN_RIGHT_IN2 /* TB6612FNG only */
#define WHEELS_PIN_RIGHT_IN2 DECK_GPIO_RX2
#endif

/* TB6612FNG STBY: 0 = tied to VCC on the board (default), 1 = driven high by the app from
 * WHEELS_PIN_STBY once the outputs are initialised (the driver stays in standby before). */
#ifndef WHEELS_HAS_STBY
#define WHEELS_HAS_STBY 0
#endif
#ifndef WHEELS_PIN_STBY
#define WHEELS_PIN_STBY DECK_GPIO_SCK
#endif

/* PWM outputs: timer TIM3, channel 1 for the left motor, channel 2 for the right one.
 * DRV8833: AIN2 / BIN2. TB6612FNG: PWMA / PWMB.
 * Left:  0 = IO3 (PB4, default), 1 = MISO (PA6).
 * Right: 0 = IO2 (PB5, default), 1 = MOSI (PA7). */
#ifndef WHEELS_PWM_LEFT_ON_MISO
#define WHEELS_PWM_LEFT_ON_MISO 0
#endif
#ifndef WHEELS_PWM_RIGHT_ON_MOSI
#define WHEELS_PWM_RIGHT_ON_MOSI 0
#endif

/* PWM frequency (Hz). TIM3 counts at 84 MHz without prescaler: 20 kHz gives 4200 steps and is
 * above hearing. Allowed: 1300 .. 100000 (DRV8833 up to 50 kHz, TB6612FNG up to 100 kHz). */
#ifndef WHEELS_PWM_HZ
#define WHEELS_PWM_HZ 20000
#endif
#define WHEELS_TIM_CLOCK_HZ 84000000u

#if WHEELS_PWM_HZ < 1300 || WHEELS_PWM_HZ > 100000
#error "WHEELS_PWM_HZ must be between 1300 and 100000"
#endif

/* The receive timeout of the app's loop (ms): the longest the watchdog and the outputs wait. */
#ifndef WHEELS_LOOP_MS
#define WHEELS_LOOP_MS 10
#endif

#endif /* WHEELS_CONFIG_H */
