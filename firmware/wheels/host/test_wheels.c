/*
 * Host tests of the wheel app's portable logic (../src/wheels_protocol.c, ../src/wheels_logic.c).
 * No framework: CHECK records a failure and goes on; main prints "N passed, N failed" and exits
 * non-zero on any failure. Example bytes are the ones in ../PROTOCOL.md.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "wheels_logic.h"
#include "wheels_protocol.h"

static int passed;
static int failed;

#define CHECK(cond)                                                     \
  do {                                                                  \
    if (cond) {                                                         \
      passed++;                                                         \
    } else {                                                            \
      failed++;                                                         \
      fprintf(stderr, "%s:%d: %s: CHECK(%s) failed\n", __FILE__, __LINE__, \
              __func__, #cond);                                         \
    }                                                                   \
  } while (0)

#define CHECK_EQ(a, b)                                                          \
  do {                                                                          \
    long long a_ = (long long)(a), b_ = (long long)(b);                         \
    if (a_ == b_) {                                                             \
      passed++;                                                                 \
    } else {                                                                    \
      failed++;                                                                 \
      fprintf(stderr, "%s:%d: %s: %s == %lld, expected %s == %lld\n", __FILE__, \
              __LINE__, __func__, #a, a_, #b, b_);                              \
    }                                                                           \
  } while (0)

static void check_bytes(const char *what, const uint8_t *got, size_t n, const uint8_t *want, size_t m)
{
  size_t i;
  if (n == m && memcmp(got, want, n) == 0) {
    passed++;
    return;
  }
  failed++;
  fprintf(stderr, "%s: got", what);
  for (i = 0; i < n; i++) {
    fprintf(stderr, " %02x", got[i]);
  }
  fprintf(stderr, "\n%s: want", what);
  for (i = 0; i < m; i++) {
    fprintf(stderr, " %02x", want[i]);
  }
  fprintf(stderr, "\n");
}

/* ---- protocol ------------------------------------------------------------------------------ */

static const uint8_t EX_WHEELS[] = {0x02, 0x01, 0x64, 0x00, 0xce, 0xff};
static const uint8_t EX_REQUEST[] = {0x02, 0x02, 0xd2, 0x04, 0x00, 0x00};
/* PROTOCOL.md, STATUS examples A, B and C. */
static const uint8_t EX_STATUS_A[] = {0x02, 0x81, 0xd2, 0x04, 0x00, 0x00, 0xce, 0x04, 0x00,
                                      0x00, 0x32, 0xef, 0x00, 0x00, 0x00, 0x00, 0x1e, 0x0f,
                                      0x64, 0x00, 0xce, 0xff, 0xff, 0xff, 0x10};
static const uint8_t EX_STATUS_B[] = {0x02, 0x81, 0xd8, 0x04, 0x00, 0x00, 0xd4, 0x04, 0x00,
                                      0x00, 0x52, 0xf2, 0x00, 0x00, 0x00, 0x00, 0x16, 0x0f,
                                      0x00, 0x00, 0x00, 0x00, 0xff, 0xff, 0x11};
static const uint8_t EX_STATUS_C[] = {0x02, 0x81, 0x88, 0x13, 0x00, 0x00, 0x7e, 0x13, 0x00,
                                      0x00, 0xb4, 0xd6, 0x01, 0x00, 0x02, 0x00, 0x42, 0x0e,
                                      0x00, 0x00, 0x00, 0x00, 0x08, 0x00, 0x1c};

static void test_decode_wheels(void)
{
  wheels_msg_t m;
  uint8_t buf[WHEELS_MAX_PAYLOAD];
  wheels_msg_wheels_t w = {-32768, 32767};

  CHECK_EQ(wheels_decode_uplink(EX_WHEELS, sizeof EX_WHEELS, &m), WHEELS_RX_WHEELS);
  CHECK_EQ(m.kind, WHEELS_RX_WHEELS);
  CHECK_EQ(m.u.wheels.left_mm_s, 100);
  CHECK_EQ(m.u.wheels.right_mm_s, -50);

  CHECK_EQ(wheels_encode_wheels(&w, buf), WHEELS_SIZE_WHEELS);
  CHECK_EQ(wheels_decode_uplink(buf, WHEELS_SIZE_WHEELS, &m), WHEELS_RX_WHEELS);
  CHECK_EQ(m.u.wheels.left_mm_s, -32768);
  CHECK_EQ(m.u.wheels.right_mm_s, 32767);
  w.left_mm_s = 100;
  w.right_mm_s = -50;
  wheels_encode_wheels(&w, buf);
  check_bytes("encode WHEELS", buf, WHEELS_SIZE_WHEELS, EX_WHEELS, sizeof EX_WHEELS);
}

static void test_decode_status_request(void)
{
  wheels_msg_t m;
  uint8_t buf[WHEELS_MAX_PAYLOAD];
  wheels_msg_status_request_t r = {0xFFFFFFFFu};

  CHECK_EQ(wheels_decode_uplink(EX_REQUEST, sizeof EX_REQUEST, &m), WHEELS_RX_STATUS_REQUEST);
  CHECK_EQ(m.u.request.seq, 1234);
  CHECK_EQ(wheels_encode_status_request(&r, buf), WHEELS_SIZE_STATUS_REQUEST);
  CHECK_EQ(wheels_decode_uplink(buf, WHEELS_SIZE_STATUS_REQUEST, &m), WHEELS_RX_STATUS_REQUEST);
  CHECK_EQ(m.u.request.seq, 0xFFFFFFFFu);
  r.seq = 1234;
  wheels_encode_status_request(&r, buf);
  check_bytes("encode STATUS_REQUEST", buf, WHEELS_SIZE_STATUS_REQUEST, EX_REQUEST, sizeof EX_REQUEST);
}

static void test_decode_status(void)
{
  wheels_msg_t m;
  const wheels_msg_status_t *st = &m.u.status;

  CHECK_EQ(wheels_decode_downlink(EX_STATUS_C, sizeof EX_STATUS_C, &m), WHEELS_RX_STATUS);
  CHECK_EQ(st->echo_seq, 5000);
  CHECK_EQ(st->received, 4990);
  CHECK_EQ(st->uptime_ms, 120500);
  CHECK_EQ(st->rejected, 2);
  CHECK_EQ(st->vbat_mv, 3650);
  CHECK_EQ(st->wheel_left_mm_s, 0);
  CHECK_EQ(st->wheel_right_mm_s, 0);
  CHECK_EQ(st->setpoint_age_ms, 8);
  CHECK_EQ(st->flags, WHEELS_FLAG_MOTORS | WHEELS_FLAG_FLYING | WHEELS_FLAG_ARMED);

  CHECK_EQ(wheels_decode_downlink(EX_STATUS_A, sizeof EX_STATUS_A, &m), WHEELS_RX_STATUS);
  CHECK_EQ(st->wheel_left_mm_s, 100);
  CHECK_EQ(st->wheel_right_mm_s, -50);
  CHECK_EQ(st->setpoint_age_ms, WHEELS_AGE_NEVER);
  /* The vehicle never takes a STATUS; the gateway never takes a WHEELS. */
  CHECK_EQ(wheels_decode_uplink(EX_STATUS_A, sizeof EX_STATUS_A, &m), WHEELS_RX_BAD_TYPE);
  CHECK_EQ(wheels_decode_downlink(EX_WHEELS, sizeof EX_WHEELS, &m), WHEELS_RX_BAD_TYPE);
  CHECK_EQ(wheels_decode_downlink(EX_STATUS_A, sizeof EX_STATUS_A - 1, &m), WHEELS_RX_BAD_LENGTH);
}

static void test_reject(void)
{
  wheels_msg_t m;
  uint8_t buf[WHEELS_MAX_PAYLOAD + 2];
  const uint8_t v1_wheels[] = {0x01, 0x01, 0x64, 0x00, 0xce, 0xff};
  const uint8_t v3_wheels[] = {0x03, 0x01, 0x64, 0x00, 0xce, 0xff};
  const uint8_t v0[] = {0x00, 0x01};
  const uint8_t unknown[] = {0x02, 0x03, 0x00, 0x00, 0x00, 0x00};
  const uint8_t zero_type[] = {0x02, 0x00, 0x00, 0x00, 0x00, 0x00};

  CHECK_EQ(wheels_decode_uplink(NULL, 0, &m), WHEELS_RX_SHORT);
  CHECK_EQ(wheels_decode_uplink(EX_WHEELS, 1, &m), WHEELS_RX_SHORT);
  CHECK_EQ(m.kind, WHEELS_RX_SHORT);
  CHECK_EQ(wheels_decode_uplink(v1_wheels, sizeof v1_wheels, &m), WHEELS_RX_BAD_VERSION);
  CHECK_EQ(wheels_decode_uplink(v3_wheels, sizeof v3_wheels, &m), WHEELS_RX_BAD_VERSION);
  CHECK_EQ(wheels_decode_uplink(v0, sizeof v0, &m), WHEELS_RX_BAD_VERSION);
  CHECK_EQ(wheels_decode_uplink(unknown, sizeof unknown, &m), WHEELS_RX_BAD_TYPE);
  CHECK_EQ(wheels_decode_uplink(zero_type, sizeof zero_type, &m), WHEELS_RX_BAD_TYPE);
  CHECK_EQ(wheels_decode_uplink(EX_WHEELS, 2, &m), WHEELS_RX_BAD_LENGTH);
  CHECK_EQ(wheels_decode_uplink(EX_WHEELS, 5, &m), WHEELS_RX_BAD_LENGTH);
  memset(buf, 0, sizeof buf);
  memcpy(buf, EX_WHEELS, sizeof EX_WHEELS);
  CHECK_EQ(wheels_decode_uplink(buf, 7, &m), WHEELS_RX_BAD_LENGTH);
  CHECK_EQ(wheels_decode_uplink(buf, WHEELS_MAX_PAYLOAD, &m), WHEELS_RX_BAD_LENGTH);
  memcpy(buf, EX_REQUEST, sizeof EX_REQUEST);
  CHECK_EQ(wheels_decode_uplink(buf, 5, &m), WHEELS_RX_BAD_LENGTH);
  CHECK_EQ(wheels_decode_uplink(buf, 7, &m), WHEELS_RX_BAD_LENGTH);
  /* A version-1 STATUS (21 bytes) is not a version-2 one. */
  buf[0] = 0x01;
  buf[1] = 0x81;
  CHECK_EQ(wheels_decode_downlink(buf, 21, &m), WHEELS_RX_BAD_VERSION);
  CHECK(strcmp(wheels_rx_name(WHEELS_RX_BAD_LENGTH), "length") == 0);
}

/* ---- watchdog and counting ----------------------------------------------------------------- */

static wheels_rx_t send_wheels(wheels_state_t *s, const wheels_config_t *cfg, int16_t l, int16_t r,
                               uint32_t t)
{
  uint8_t buf[WHEELS_MAX_PAYLOAD];
  wheels_msg_wheels_t w;
  w.left_mm_s = l;
  w.right_mm_s = r;
  return wheels_receive(s, cfg, buf, wheels_encode_wheels(&w, buf), t, NULL);
}

static void test_watchdog(void)
{
  wheels_state_t s;
  wheels_config_t cfg;
  wheels_default_config(&cfg);
  wheels_init(&s);

  CHECK(!wheels_tick(&s, &cfg, 100000u)); /* nothing commanded: nothing to stop */
  CHECK_EQ(send_wheels(&s, &cfg, 100, -50, 1000u), WHEELS_RX_WHEELS);
  CHECK(s.running);
  CHECK(!wheels_tick(&s, &cfg, 1000u));
  CHECK(!wheels_tick(&s, &cfg, 1499u));
  CHECK(!wheels_tick(&s, &cfg, 1500u)); /* exactly 0.5 s: not yet */
  CHECK_EQ(s.left_mm_s, 100);
  CHECK_EQ(s.right_mm_s, -50);
  CHECK_EQ(s.latched, 0);
  CHECK(wheels_tick(&s, &cfg, 1501u)); /* more than 0.5 s: stopped */
  CHECK_EQ(s.left_mm_s, 0);
  CHECK_EQ(s.right_mm_s, 0);
  CHECK(!s.running);
  CHECK_EQ(s.latched, WHEELS_FLAG_WHEEL_WATCHDOG);
  CHECK_EQ(s.watchdogs, 1);
  CHECK(!wheels_tick(&s, &cfg, 5000u)); /* fires once */
  CHECK_EQ(s.watchdogs, 1);
}

static void test_watchdog_rearm(void)
{
  wheels_state_t s;
  wheels_config_t cfg;
  wheels_default_config(&cfg);
  wheels_init(&s);

  send_wheels(&s, &cfg, 200, 200, 1000u);
  send_wheels(&s, &cfg, 200, 200, 1400u); /* the refresh re-arms */
  CHECK(!wheels_tick(&s, &cfg, 1800u));
  CHECK(!wheels_tick(&s, &cfg, 1900u));
  CHECK(wheels_tick(&s, &cfg, 1901u));

  /* A new command after the watchdog drives again; the flag stays until a STATUS. */
  send_wheels(&s, &cfg, -30, 40, 3000u);
  CHECK(s.running);
  CHECK_EQ(s.left_mm_s, -30);
  CHECK_EQ(s.right_mm_s, 40);
  CHECK_EQ(s.latched, WHEELS_FLAG_WHEEL_WATCHDOG);
  CHECK(!wheels_tick(&s, &cfg, 3500u));
  CHECK(wheels_tick(&s, &cfg, 3501u));
  CHECK_EQ(s.watchdogs, 2);

  /* A late command (0.6 s after the last) is still a watchdog stop, then it drives. */
  wheels_init(&s);
  send_wheels(&s, &cfg, 100, 100, 10000u);
  CHECK_EQ(send_wheels(&s, &cfg, 120, 120, 10600u), WHEELS_RX_WHEELS);
  CHECK_EQ(s.watchdogs, 1);
  CHECK_EQ(s.latched, WHEELS_FLAG_WHEEL_WATCHDOG);
  CHECK_EQ(s.left_mm_s, 120);
  CHECK(s.running);
}

static void test_watchdog_zero_and_wrap(void)
{
  wheels_state_t s;
  wheels_config_t cfg;
  wheels_default_config(&cfg);
  wheels_init(&s);

  /* "0, 0" stops at once and leaves nothing for the watchdog to do. */
  send_wheels(&s, &cfg, 100, 0, 1000u);
  send_wheels(&s, &cfg, 0, 0, 1100u);
  CHECK(!s.running);
  CHECK(!wheels_tick(&s, &cfg, 9000u));
  CHECK_EQ(s.latched, 0);
  /* One wheel alone keeps the watchdog armed. */
  send_wheels(&s, &cfg, 0, -1, 9000u);
  CHECK(s.running);
  CHECK(wheels_tick(&s, &cfg, 9501u));

  /* The millisecond clock wraps. */
  wheels_init(&s);
  send_wheels(&s, &cfg, 100, 100, 0xFFFFFF00u);
  CHECK(!wheels_tick(&s, &cfg, 0x000000F4u)); /* 500 ms later */
  CHECK(wheels_tick(&s, &cfg, 0x000000F5u));  /* 501 ms later */

  /* A configurable timeout. */
  cfg.watchdog_ms = 100u;
  wheels_init(&s);
  send_wheels(&s, &cfg, 100, 100, 0u);
  CHECK(!wheels_tick(&s, &cfg, 100u));
  CHECK(wheels_tick(&s, &cfg, 101u));
}

static void test_counts(void)
{
  wheels_state_t s;
  wheels_config_t cfg;
  uint32_t seq = 0;
  const uint8_t bad_version[] = {0x01, 0x01, 0x64, 0x00, 0xce, 0xff};
  uint8_t out[WHEELS_MAX_PAYLOAD];
  wheels_vehicle_t v = {4000u, WHEELS_AGE_NEVER, 0u};
  wheels_msg_t m;

  wheels_default_config(&cfg);
  wheels_init(&s);
  send_wheels(&s, &cfg, 10, 10, 0u);
  CHECK_EQ(wheels_receive(&s, &cfg, bad_version, sizeof bad_version, 1u, &seq), WHEELS_RX_BAD_VERSION);
  CHECK_EQ(s.left_mm_s, 10); /* a rejected packet is never acted on */
  CHECK_EQ(wheels_receive(&s, &cfg, EX_WHEELS, 3, 2u, &seq), WHEELS_RX_BAD_LENGTH);
  CHECK_EQ(wheels_receive(&s, &cfg, EX_REQUEST, sizeof EX_REQUEST, 3u, &seq), WHEELS_RX_STATUS_REQUEST);
  CHECK_EQ(seq, 1234);
  CHECK_EQ(s.received, 4);
  CHECK_EQ(s.rejected, 2);
  CHECK_EQ(s.wheels, 1);
  CHECK_EQ(s.requests, 1);
  CHECK_EQ(wheels_status(&s, seq, 3u, &v, out), WHEELS_SIZE_STATUS);
  CHECK_EQ(wheels_decode_downlink(out, WHEELS_SIZE_STATUS, &m), WHEELS_RX_STATUS);
  CHECK_EQ(m.u.status.echo_seq, 1234);
  CHECK_EQ(m.u.status.received, 4); /* this request included */
  CHECK_EQ(m.u.status.rejected, 2);
  CHECK_EQ(m.u.status.uptime_ms, 3);
  CHECK_EQ(m.u.status.wheel_left_mm_s, 10);
}

/* ---- STATUS -------------------------------------------------------------------------------- */

static void test_status_examples(void)
{
  wheels_state_t s;
  wheels_config_t cfg;
  uint8_t out[WHEELS_MAX_PAYLOAD];
  wheels_vehicle_t v;
  wheels_msg_t m;

  wheels_default_config(&cfg);

  /* A: driving on the ground, armed, no flight setpoint ever; 4 packets lost so far. */
  wheels_init(&s);
  send_wheels(&s, &cfg, 100, -50, 61000u);
  s.received = 1230u; /* as if 1228 packets had come before this WHEELS and the request */
  v.vbat_mv = wheels_volts_to_mv(3.87f);
  v.setpoint_age_ms = wheels_age_u16(0xFFFFFFFFu);
  v.flags = WHEELS_FLAG_ARMED;
  CHECK_EQ(wheels_status(&s, 1234u, 61234u, &v, out), WHEELS_SIZE_STATUS);
  check_bytes("STATUS example A", out, WHEELS_SIZE_STATUS, EX_STATUS_A, sizeof EX_STATUS_A);

  /* B: 0.8 s later, the wheel watchdog has stopped the wheels. */
  CHECK(wheels_tick(&s, &cfg, 61501u));
  s.received = 1236u;
  v.vbat_mv = 3862u;
  CHECK_EQ(wheels_status(&s, 1240u, 62034u, &v, out), WHEELS_SIZE_STATUS);
  check_bytes("STATUS example B", out, WHEELS_SIZE_STATUS, EX_STATUS_B, sizeof EX_STATUS_B);
  /* The latched flag went out with B: the next STATUS has only the vehicle's. */
  wheels_status(&s, 1241u, 62100u, &v, out);
  CHECK_EQ(wheels_decode_downlink(out, WHEELS_SIZE_STATUS, &m), WHEELS_RX_STATUS);
  CHECK_EQ(m.u.status.flags, WHEELS_FLAG_ARMED);

  /* C: hovering, the last setpoint 8 ms old, 2 malformed packets so far. */
  wheels_init(&s);
  s.received = 4990u;
  s.rejected = 2u;
  v.vbat_mv = 3650u;
  v.setpoint_age_ms = wheels_age_u16(8u);
  v.flags = WHEELS_FLAG_MOTORS | WHEELS_FLAG_FLYING | WHEELS_FLAG_ARMED;
  CHECK_EQ(wheels_status(&s, 5000u, 120500u, &v, out), WHEELS_SIZE_STATUS);
  check_bytes("STATUS example C", out, WHEELS_SIZE_STATUS, EX_STATUS_C, sizeof EX_STATUS_C);
}

static void test_status_flags(void)
{
  wheels_state_t s;
  wheels_msg_t m;
  uint8_t out[WHEELS_MAX_PAYLOAD];
  wheels_vehicle_t v = {3700u, 0u, 0xFFu}; /* the glue cannot set the logic's own bits */

  wheels_init(&s);
  wheels_status(&s, 1u, 0u, &v, out);
  wheels_decode_downlink(out, WHEELS_SIZE_STATUS, &m);
  CHECK_EQ(m.u.status.flags, WHEELS_FLAGS_VEHICLE);

  v.flags = 0u;
  wheels_note_overflow(&s);
  wheels_status(&s, 2u, 0u, &v, out);
  wheels_decode_downlink(out, WHEELS_SIZE_STATUS, &m);
  CHECK_EQ(m.u.status.flags, WHEELS_FLAG_RX_OVERFLOW);
  CHECK_EQ(s.overflows, 1);
  wheels_status(&s, 3u, 0u, &v, out);
  wheels_decode_downlink(out, WHEELS_SIZE_STATUS, &m);
  CHECK_EQ(m.u.status.flags, 0);
}

static void test_conversions(void)
{
  CHECK_EQ(wheels_volts_to_mv(3.87f), 3870);
  CHECK_EQ(wheels_volts_to_mv(4.2004f), 4200);
  CHECK_EQ(wheels_volts_to_mv(0.0f), 0);
  CHECK_EQ(wheels_volts_to_mv(-1.0f), 0);
  CHECK_EQ(wheels_volts_to_mv(NAN), 0);
  CHECK_EQ(wheels_volts_to_mv(70.0f), 65535);
  CHECK_EQ(wheels_age_u16(0u), 0);
  CHECK_EQ(wheels_age_u16(65534u), 65534);
  CHECK_EQ(wheels_age_u16(65535u), WHEELS_AGE_NEVER);
  CHECK_EQ(wheels_age_u16(1000000u), WHEELS_AGE_NEVER);
}

/* ---- H-bridge mapping ---------------------------------------------------------------------- */

static void test_drive(void)
{
  wheels_config_t cfg;
  wheels_default_config(&cfg); /* 1000 mm/s at full drive, no minimum */

  CHECK_EQ(wheels_drive_for(&cfg, 0), 0);
  CHECK_EQ(wheels_drive_for(&cfg, 100), 1000);
  CHECK_EQ(wheels_drive_for(&cfg, -50), 500);
  CHECK_EQ(wheels_drive_for(&cfg, 999), 9990);
  CHECK_EQ(wheels_drive_for(&cfg, 1000), 10000);
  CHECK_EQ(wheels_drive_for(&cfg, 5000), 10000);   /* clamped */
  CHECK_EQ(wheels_drive_for(&cfg, 32767), 10000);
  CHECK_EQ(wheels_drive_for(&cfg, -32768), 10000); /* clamped, sign apart */

  cfg.max_speed_mm_s = 3u; /* rounding half up: 3333.3 -> 3333, 6666.7 -> 6667 */
  CHECK_EQ(wheels_drive_for(&cfg, 1), 3333);
  CHECK_EQ(wheels_drive_for(&cfg, -2), 6667);

  cfg.max_speed_mm_s = 1000u;
  cfg.min_drive = 2000u; /* a minimum to overcome static friction */
  CHECK_EQ(wheels_drive_for(&cfg, 1), 2008);
  CHECK_EQ(wheels_drive_for(&cfg, 500), 6000);
  CHECK_EQ(wheels_drive_for(&cfg, -1000), 10000);
  CHECK_EQ(wheels_drive_for(&cfg, 0), 0);
  cfg.min_drive = 20000u; /* out of range: full */
  CHECK_EQ(wheels_drive_for(&cfg, 1), 10000);

  cfg.min_drive = 0u;
  cfg.max_speed_mm_s = 0u; /* disabled */
  CHECK_EQ(wheels_drive_for(&cfg, 500), 0);

  cfg.max_speed_mm_s = 65535u;
  CHECK_EQ(wheels_drive_for(&cfg, 32767), 5000);
}

static void check_bridge(const wheels_config_t *cfg, int16_t v, bool invert, int dir, int drive,
                         int in1, int in2, int pwm)
{
  wheels_bridge_t b;
  wheels_bridge(cfg, v, invert, &b);
  CHECK_EQ(b.dir, dir);
  CHECK_EQ(b.drive, drive);
  CHECK_EQ(b.in1, in1);
  CHECK_EQ(b.in2, in2);
  CHECK_EQ(b.pwm, pwm);
}

static void test_bridge_drv8833(void)
{
  wheels_config_t cfg;
  wheels_default_config(&cfg);
  cfg.driver = WHEELS_DRIVER_DRV8833;

  check_bridge(&cfg, 100, false, 1, 1000, 1, 0, 9000);   /* forward: IN1 high, IN2 low 10 % */
  check_bridge(&cfg, -100, false, -1, 1000, 0, 0, 1000); /* reverse: IN1 low, IN2 high 10 % */
  check_bridge(&cfg, 2000, false, 1, 10000, 1, 0, 0);    /* full forward: IN2 always low */
  check_bridge(&cfg, -2000, false, -1, 10000, 0, 0, 10000);
  check_bridge(&cfg, 0, false, 0, 0, 1, 0, 10000);       /* brake: both high */
  check_bridge(&cfg, 100, true, -1, 1000, 0, 0, 1000);   /* inverted polarity */
  check_bridge(&cfg, -100, true, 1, 1000, 1, 0, 9000);
  cfg.brake = 0u;
  check_bridge(&cfg, 0, false, 0, 0, 0, 0, 0);           /* coast: both low */
}

static void test_bridge_tb6612(void)
{
  wheels_config_t cfg;
  wheels_default_config(&cfg);
  cfg.driver = WHEELS_DRIVER_TB6612;

  check_bridge(&cfg, 100, false, 1, 1000, 1, 0, 1000);
  check_bridge(&cfg, -100, false, -1, 1000, 0, 1, 1000);
  check_bridge(&cfg, -32768, false, -1, 10000, 0, 1, 10000);
  check_bridge(&cfg, 0, false, 0, 0, 1, 1, 0);           /* short brake */
  check_bridge(&cfg, 250, true, -1, 2500, 0, 1, 2500);
  cfg.brake = 0u;
  check_bridge(&cfg, 0, false, 0, 0, 0, 0, 10000);       /* off: IN1 = IN2 = L, PWM = H */
}

static void test_outputs(void)
{
  wheels_state_t s;
  wheels_config_t cfg;
  wheels_bridge_t l, r;
  wheels_default_config(&cfg);
  cfg.invert_right = 1u; /* a mirrored right motor */
  wheels_init(&s);
  send_wheels(&s, &cfg, 300, 300, 0u);
  wheels_outputs(&s, &cfg, &l, &r);
  CHECK_EQ(l.dir, 1);
  CHECK_EQ(r.dir, -1);
  CHECK_EQ(l.drive, 3000);
  CHECK_EQ(r.drive, 3000);
  CHECK(wheels_tick(&s, &cfg, 501u));
  wheels_outputs(&s, &cfg, &l, &r);
  CHECK_EQ(l.dir, 0);
  CHECK_EQ(r.dir, 0);
  CHECK_EQ(l.pwm, 10000); /* braked */
}

int main(void)
{
  test_decode_wheels();
  test_decode_status_request();
  test_decode_status();
  test_reject();
  test_watchdog();
  test_watchdog_rearm();
  test_watchdog_zero_and_wrap();
  test_counts();
  test_status_examples();
  test_status_flags();
  test_conversions();
  test_drive();
  test_bridge_drv8833();
  test_bridge_tb6612();
  test_outputs();
  printf("%d passed, %d failed\n", passed, failed);
  return failed == 0 ? 0 : 1;
}
