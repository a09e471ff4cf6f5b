/*
 * Wheel protocol, version 2: the bytes on the Crazyflie app channel (CRTP port 0x0D, channel 2).
 * The specification is ../PROTOCOL.md; this is its one C implementation (encode and decode).
 *
 * Portable: standard C11 only, no firmware headers, so it builds for the Crazyflie and for the
 * host tests alike. Payloads here start at the version byte: the CRTP header byte is not part of
 * them (the firmware's app channel hands over and takes payloads only).
 */
#ifndef WHEELS_PROTOCOL_H
#define WHEELS_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#define WHEELS_PROTOCOL_VERSION 2u

#define WHEELS_MSG_WHEELS 0x01u
#define WHEELS_MSG_STATUS_REQUEST 0x02u
#define WHEELS_MSG_STATUS 0x81u

/* Payload sizes in bytes, version and type bytes included. Every message has exactly its size. */
#define WHEELS_SIZE_WHEELS 6u
#define WHEELS_SIZE_STATUS_REQUEST 6u
#define WHEELS_SIZE_STATUS 25u
#define WHEELS_MAX_PAYLOAD 30u /* CRTP: at most 30 payload bytes per packet */

/* CRTP header byte of an app-channel packet as the firmware sends it (port 0x0D, channel 2, bits
 * 3-2 zero). Receivers ignore bits 3-2: cflib sends 0xDE for the same port and channel. */
#define WHEELS_CRTP_PORT 0x0Du
#define WHEELS_CRTP_CHANNEL 2u
#define WHEELS_CRTP_HEADER_DOWN 0xD2u

/* STATUS flags. "latched": set when the event happens, cleared when a STATUS is built.
 * "now": sampled when the STATUS is built. */
#define WHEELS_FLAG_WHEEL_WATCHDOG 0x01u /* latched: the wheel watchdog stopped the wheels */
#define WHEELS_FLAG_RX_OVERFLOW 0x02u    /* latched: the app-channel receive queue overflowed */
#define WHEELS_FLAG_MOTORS 0x04u         /* now: a propeller motor is commanded (ratio > 0) */
#define WHEELS_FLAG_FLYING 0x08u         /* now: the supervisor believes the vehicle flies */
#define WHEELS_FLAG_ARMED 0x10u          /* now: the supervisor is armed */
#define WHEELS_FLAG_LOCKED 0x20u         /* now: the supervisor is locked (only a reboot clears it) */
#define WHEELS_FLAG_LOW_BATTERY 0x40u    /* now: the power manager reports a low battery */
#define WHEELS_FLAG_MEASURED 0x80u       /* the wheel speeds are measured (encoders), not commanded */

/* The vehicle-state flags the firmware glue supplies (bits 2-7); the others the logic owns. */
#define WHEELS_FLAGS_VEHICLE (WHEELS_FLAG_MOTORS | WHEELS_FLAG_FLYING | WHEELS_FLAG_ARMED | \
                              WHEELS_FLAG_LOCKED | WHEELS_FLAG_LOW_BATTERY | WHEELS_FLAG_MEASURED)

#define WHEELS_AGE_NEVER 0xFFFFu /* setpoint_age_ms: no setpoint yet, or 65.535 s and more */

typedef enum {
  WHEELS_RX_WHEELS = 0,         /* a valid WHEELS */
  WHEELS_RX_STATUS_REQUEST = 1, /* a valid STATUS_REQUEST */
  WHEELS_RX_STATUS = 2,         /* a valid STATUS (what the gateway decodes) */
  WHEELS_RX_SHORT = 3,          /* fewer than 2 bytes: no version and type */
  WHEELS_RX_BAD_VERSION = 4,    /* version byte is not WHEELS_PROTOCOL_VERSION */
  WHEELS_RX_BAD_TYPE = 5,       /* unknown type (or a type that does not go this way) */
  WHEELS_RX_BAD_LENGTH = 6,     /* known type, wrong length */
} wheels_rx_t;

typedef struct {
  int16_t left_mm_s;  /* wheel rim speed, mm/s, positive forward */
  int16_t right_mm_s;
} wheels_msg_wheels_t;

typedef struct {
  uint32_t seq; /* app-channel packets the gateway has sent this vehicle, this request included */
} wheels_msg_status_request_t;

typedef struct {
  uint32_t echo_seq;        /* the seq of the request answered */
  uint32_t received;        /* app-channel packets the app has received since boot, this request included */
  uint32_t uptime_ms;       /* ms since boot when the STATUS was built, mod 2^32 */
  uint16_t rejected;        /* of them, dropped as malformed (version, type, length), mod 2^16 */
  uint16_t vbat_mv;         /* battery voltage, mV */
  int16_t wheel_left_mm_s;  /* commanded (or measured, see WHEELS_FLAG_MEASURED) rim speeds */
  int16_t wheel_right_mm_s;
  uint16_t setpoint_age_ms; /* ms since the stabilizer last took a commander setpoint, saturated */
  uint8_t flags;            /* WHEELS_FLAG_* */
} wheels_msg_status_t;

typedef struct {
  wheels_rx_t kind;
  union {
    wheels_msg_wheels_t wheels;
    wheels_msg_status_request_t request;
    wheels_msg_status_t status;
  } u;
} wheels_msg_t;

/* Decode an uplink payload (what the vehicle receives): WHEELS or STATUS_REQUEST; anything else
 * is one of the WHEELS_RX_* errors. `out->u` is only written for a valid message. */
wheels_rx_t wheels_decode_uplink(const uint8_t *payload, size_t len, wheels_msg_t *out);

/* Decode a downlink payload (what the gateway receives): STATUS, or an error. */
wheels_rx_t wheels_decode_downlink(const uint8_t *payload, size_t len, wheels_msg_t *out);

/* Encoders: write the payload to `out` (room for its size) and return its size. */
size_t wheels_encode_wheels(const wheels_msg_wheels_t *msg, uint8_t *out);
size_t wheels_encode_status_request(const wheels_msg_status_request_t *msg, uint8_t *out);
size_t wheels_encode_status(const wheels_msg_status_t *msg, uint8_t *out);

/* A short name for a wheels_rx_t ("wheels", "short", "version", ...). */
const char *wheels_rx_name(wheels_rx_t kind);

#endif /* WHEELS_PROTOCOL_H */
