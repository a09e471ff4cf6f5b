/*
 * The wheel app's logic, apart from the firmware: packet counting, the wheel watchdog, STATUS
 * building and the mapping of a wheel speed to the inputs of a dual H-bridge (DRV8833 or
 * TB6612FNG). Portable C11 without firmware headers; the firmware glue (wheels_app.c) feeds it
 * packets and the time, and writes what it computes to the deck pins.
 *
 * Time is a uint32_t millisecond count that may wrap (differences are taken modulo 2^32).
 */
#ifndef WHEELS_LOGIC_H
#define WHEELS_LOGIC_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "wheels_protocol.h"

#define WHEELS_DRIVE_FULL 10000u /* drive and PWM duties are in 1/10000 of the PWM period */
#define WHEELS_WATCHDOG_MS_DEFAULT 500u    /* protocol: wheels stop 0.5 s after the last WHEELS */
#define WHEELS_DEFAULT_MAX_SPEED_MM_S 1000u /* calibrate per vehicle (parameter wheels.maxSpeed) */
#define WHEELS_DEFAULT_MIN_DRIVE 0u
#define WHEELS_DEFAULT_BRAKE 1u

typedef enum {
  WHEELS_DRIVER_DRV8833 = 0, /* per motor: xIN1 a digital pin, xIN2 the PWM pin */
  WHEELS_DRIVER_TB6612 = 1,  /* per motor: xIN1, xIN2 digital pins, PWMx the PWM pin */
} wheels_driver_t;

/* Configuration. The firmware exposes the first six fields as parameters (group "wheels"). */
typedef struct {
  uint16_t max_speed_mm_s; /* rim speed reached at full drive; 0 keeps both wheels stopped */
  uint16_t min_drive;      /* drive of the smallest non-zero speed, 0..10000 (static friction) */
  uint16_t watchdog_ms;    /* stop the wheels when no WHEELS came for longer than this */
  uint8_t brake;           /* at zero speed: 1 short brake, 0 coast */
  uint8_t invert_left;     /* 1: the left motor turns backwards for "forward" (swapped wires) */
  uint8_t invert_right;
  uint8_t driver; /* wheels_driver_t: chosen at build time with the wiring */
} wheels_config_t;

/* What one half of the dual H-bridge gets. */
typedef struct {
  int8_t dir;     /* +1 forward (OUT1 high), -1 reverse, 0 stopped; after inversion */
  uint16_t drive; /* fraction of the PWM period the motor is driven, 0..10000 */
  uint8_t in1;    /* level of the xIN1 pin (both drivers) */
  uint8_t in2;    /* level of the xIN2 pin (TB6612; always 0 for the DRV8833, whose xIN2 is the PWM pin) */
  uint16_t pwm;   /* fraction of the PWM period the PWM pin is high, 0..10000 */
} wheels_bridge_t;

/* What the firmware knows about the rest of the vehicle, sampled for a STATUS. */
typedef struct {
  uint16_t vbat_mv;
  uint16_t setpoint_age_ms; /* WHEELS_AGE_NEVER when unknown or too old */
  uint8_t flags;            /* WHEELS_FLAGS_VEHICLE bits; others are ignored */
} wheels_vehicle_t;

typedef struct {
  int16_t left_mm_s; /* setpoint in effect; 0 once the watchdog fired */
  int16_t right_mm_s;
  uint32_t last_wheels_ms; /* when the last WHEELS arrived */
  bool running;            /* a non-zero setpoint is in effect: the watchdog is armed */
  uint8_t latched;         /* WHEELS_FLAG_WHEEL_WATCHDOG | WHEELS_FLAG_RX_OVERFLOW until the next STATUS */
  uint32_t received;       /* app-channel packets taken, valid or not (mod 2^32) */
  uint16_t rejected;       /* of them, malformed (mod 2^16) */
  uint32_t wheels;         /* valid WHEELS */
  uint32_t requests;       /* valid STATUS_REQUESTs */
  uint32_t watchdogs;      /* times the wheel watchdog stopped the wheels */
  uint32_t overflows;      /* receive-queue overflows noted */
} wheels_state_t;

void wheels_default_config(wheels_config_t *cfg);
void wheels_init(wheels_state_t *s);

/* Run the wheel watchdog at `now_ms`: true when it stops the wheels now. It fires once
 * `now_ms - last_wheels_ms > watchdog_ms` while a non-zero setpoint is in effect. */
bool wheels_tick(wheels_state_t *s, const wheels_config_t *cfg, uint32_t now_ms);

/* One app-channel payload received at `now_ms`. Runs the watchdog first (so a late WHEELS still
 * latches the watchdog flag), counts the packet, applies a WHEELS. For a STATUS_REQUEST the caller
 * answers with wheels_status(..., *seq, ...). Returns the decoded kind (errors are counted). */
wheels_rx_t wheels_receive(wheels_state_t *s, const wheels_config_t *cfg, const uint8_t *payload,
                           size_t len, uint32_t now_ms, uint32_t *seq);

/* The app-channel receive queue overflowed (packets were lost inside the vehicle). */
void wheels_note_overflow(wheels_state_t *s);

/* Build the STATUS answering request `echo_seq` into `out` (WHEELS_SIZE_STATUS bytes), clear the
 * latched flags, return the size. */
size_t wheels_status(wheels_state_t *s, uint32_t echo_seq, uint32_t now_ms, const wheels_vehicle_t *v,
                     uint8_t *out);

/* Drive (0..10000) for a rim speed magnitude: 0 for 0; min_drive + (10000 - min_drive) * |v| / max,
 * rounded half up; 10000 from max_speed_mm_s on. */
uint16_t wheels_drive_for(const wheels_config_t *cfg, int32_t speed_mm_s);

/* The H-bridge inputs for one wheel at `speed_mm_s` (`invert`: that wheel's polarity flag). */
void wheels_bridge(const wheels_config_t *cfg, int16_t speed_mm_s, bool invert, wheels_bridge_t *out);

/* Both wheels at the setpoint in effect. */
void wheels_outputs(const wheels_state_t *s, const wheels_config_t *cfg, wheels_bridge_t *left,
                    wheels_bridge_t *right);

/* Volts (float, as pmGetBatteryVoltage returns) to mV for STATUS: rounded, clamped to 0..65535
 * (NaN gives 0). */
uint16_t wheels_volts_to_mv(float volts);

/* Milliseconds to a saturated uint16 age (65535 = WHEELS_AGE_NEVER). */
uint16_t wheels_age_u16(uint32_t ms);

#endif /* WHEELS_LOGIC_H */
