/*
 * wheels_filter: the wheel app's logic on the host, driven by text, for cross-checking other
 * implementations of the protocol (the gateway's Python codec) against the C one.
 *
 * Input, one line each (blank lines and text after '#' are ignored):
 *   <t_ms> <hex>            a CRTP packet (header byte then payload) received at t_ms; spaces
 *                           between hex digits are allowed
 *   <t_ms>                  no packet: only let the time pass (runs the wheel watchdog)
 *   <t_ms> set vbat <mV>    vehicle state used by later STATUS replies (default 0)
 *   <t_ms> set age <ms>     setpoint age (default 65535: never)
 *   <t_ms> set flags <n>    vehicle flags, bits 2-7 (decimal or 0x hex; default 0)
 *   <t_ms> set overflow     the app-channel receive queue overflowed
 * t_ms is a decimal millisecond count that must not go back.
 *
 * Output, for every input line, in this order:
 *   <t_ms> watchdog                     the wheel watchdog stopped the wheels on the way to t_ms
 *   <t_ms> ignored                      not for the app: another port or channel, an empty
 *                                       app-channel packet, or more than 30 payload bytes
 *   <t_ms> rejected <why>               dropped and counted: short, version, type or length
 *   <t_ms> wheels <left> <right>        a WHEELS taken (mm/s)
 *   <t_ms> reply <hex>                  the STATUS packet sent back (header d2, then payload)
 *   <t_ms> out <left> <right> <L> <R>   always last: the setpoint in effect (mm/s), then for the
 *                                       left and right motor five integers: dir drive in1 in2 pwm
 *                                       (see wheels_bridge_t; drive and pwm in 1/10000)
 *
 * Options: -d drv8833|tb6612 (driver, default drv8833), -s <max_speed_mm_s> (1000),
 * -m <min_drive> (0), -w <watchdog_ms> (500), -c (coast at zero speed; default brake),
 * -l / -r (invert the left / right motor).
 * Exit status 0, or 2 on a malformed input line or option (message on stderr).
 */
#include <ctype.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "wheels_logic.h"
#include "wheels_protocol.h"

#define LINE_MAX_CHARS 1024

static int fail(unsigned long lineno, const char *what)
{
  fprintf(stderr, "wheels_filter: line %lu: %s\n", lineno, what);
  return 2;
}

static int parse_ulong(const char *s, unsigned long max, unsigned long *out)
{
  char *end = NULL;
  unsigned long v;
  if (s == NULL || *s == '\0' || *s == '-') {
    return -1;
  }
  errno = 0;
  v = strtoul(s, &end, 0);
  if (errno != 0 || end == s || *end != '\0' || v > max) {
    return -1;
  }
  *out = v;
  return 0;
}

static int hex_value(int c)
{
  if (c >= '0' && c <= '9') {
    return c - '0';
  }
  c = tolower(c);
  if (c >= 'a' && c <= 'f') {
    return c - 'a' + 10;
  }
  return -1;
}

/* Hex digits (spaces allowed between them) to bytes; -1 on odd digits, bad chars or overflow. */
static long parse_hex(const char *s, uint8_t *out, size_t cap)
{
  size_t n = 0;
  int hi = -1;
  for (; *s != '\0'; s++) {
    int v;
    if (isspace((unsigned char)*s)) {
      continue;
    }
    v = hex_value((unsigned char)*s);
    if (v < 0) {
      return -1;
    }
    if (hi < 0) {
      hi = v;
    } else {
      if (n >= cap) {
        return -1;
      }
      out[n++] = (uint8_t)(hi << 4 | v);
      hi = -1;
    }
  }
  return hi >= 0 ? -1 : (long)n;
}

static void print_bridge(const wheels_bridge_t *b)
{
  printf(" %d %u %u %u %u", b->dir, b->drive, b->in1, b->in2, b->pwm);
}

int main(int argc, char **argv)
{
  wheels_config_t cfg;
  wheels_state_t s;
  wheels_vehicle_t veh;
  char line[LINE_MAX_CHARS];
  unsigned long lineno = 0;
  unsigned long last_t = 0;
  int i;

  wheels_default_config(&cfg);
  wheels_init(&s);
  veh.vbat_mv = 0u;
  veh.setpoint_age_ms = WHEELS_AGE_NEVER;
  veh.flags = 0u;

  for (i = 1; i < argc; i++) {
    unsigned long v = 0;
    const char *a = argv[i];
    if (strcmp(a, "-c") == 0) {
      cfg.brake = 0u;
    } else if (strcmp(a, "-l") == 0) {
      cfg.invert_left = 1u;
    } else if (strcmp(a, "-r") == 0) {
      cfg.invert_right = 1u;
    } else if (i + 1 < argc && strcmp(a, "-d") == 0) {
      const char *d = argv[++i];
      if (strcmp(d, "drv8833") == 0) {
        cfg.driver = (uint8_t)WHEELS_DRIVER_DRV8833;
      } else if (strcmp(d, "tb6612") == 0) {
        cfg.driver = (uint8_t)WHEELS_DRIVER_TB6612;
      } else {
        return fail(0, "-d takes drv8833 or tb6612");
      }
    } else if (i + 1 < argc && (strcmp(a, "-s") == 0 || strcmp(a, "-m") == 0 || strcmp(a, "-w") == 0)) {
      if (parse_ulong(argv[++i], 0xFFFFu, &v) != 0) {
        return fail(0, "option value must be 0..65535");
      }
      if (a[1] == 's') {
        cfg.max_speed_mm_s = (uint16_t)v;
      } else if (a[1] == 'm') {
        cfg.min_drive = (uint16_t)v;
      } else {
        cfg.watchdog_ms = (uint16_t)v;
      }
    } else {
      fprintf(stderr, "usage: wheels_filter [-d drv8833|tb6612] [-s max_mm_s] [-m min_drive] "
                      "[-w watchdog_ms] [-c] [-l] [-r] < lines\n");
      return 2;
    }
  }

  while (fgets(line, sizeof line, stdin) != NULL) {
    char *hash;
    char *tok;
    char *rest;
    unsigned long t = 0;
    uint32_t now;
    wheels_bridge_t bl, br;

    lineno++;
    if (strchr(line, '\n') == NULL && !feof(stdin)) {
      return fail(lineno, "line too long");
    }
    hash = strchr(line, '#');
    if (hash != NULL) {
      *hash = '\0';
    }
    tok = strtok(line, " \t\r\n");
    if (tok == NULL) {
      continue;
    }
    if (parse_ulong(tok, 0xFFFFFFFFu, &t) != 0) {
      return fail(lineno, "expected a time stamp in ms");
    }
    if (lineno > 1 && t < last_t) {
      return fail(lineno, "time went back");
    }
    last_t = t;
    now = (uint32_t)t;
    rest = strtok(NULL, "\r\n");
    while (rest != NULL && isspace((unsigned char)*rest)) {
      rest++;
    }

    if (wheels_tick(&s, &cfg, now)) {
      printf("%lu watchdog\n", t);
    }

    if (rest != NULL && strncmp(rest, "set", 3) == 0 && (rest[3] == '\0' || isspace((unsigned char)rest[3]))) {
      char *name = strtok(rest + 3, " \t");
      char *value = strtok(NULL, " \t");
      unsigned long v = 0;
      if (name == NULL) {
        return fail(lineno, "set what?");
      }
      if (strcmp(name, "overflow") == 0) {
        wheels_note_overflow(&s);
      } else if (value == NULL || parse_ulong(value, 0xFFFFFFFFu, &v) != 0) {
        return fail(lineno, "set needs a number");
      } else if (strcmp(name, "vbat") == 0 && v <= 0xFFFFu) {
        veh.vbat_mv = (uint16_t)v;
      } else if (strcmp(name, "age") == 0) {
        veh.setpoint_age_ms = wheels_age_u16((uint32_t)v);
      } else if (strcmp(name, "flags") == 0 && v <= 0xFFu) {
        veh.flags = (uint8_t)v;
      } else {
        return fail(lineno, "set vbat|age|flags <n> or set overflow");
      }
    } else if (rest != NULL && *rest != '\0') {
      uint8_t pkt[64];
      long n = parse_hex(rest, pkt, sizeof pkt);
      if (n < 1) {
        return fail(lineno, "expected hex bytes: CRTP header then payload");
      }
      if ((pkt[0] >> 4) != WHEELS_CRTP_PORT || (pkt[0] & 0x03u) != WHEELS_CRTP_CHANNEL ||
          n == 1 || n - 1 > (long)WHEELS_MAX_PAYLOAD) {
        /* The firmware hands only port 0x0D channel 2 to the app, and an empty payload reads as
         * "nothing received" through appchannelReceiveDataPacket. */
        printf("%lu ignored\n", t);
      } else {
        uint32_t seq = 0;
        wheels_rx_t kind = wheels_receive(&s, &cfg, pkt + 1, (size_t)(n - 1), now, &seq);
        if (kind == WHEELS_RX_WHEELS) {
          printf("%lu wheels %d %d\n", t, s.left_mm_s, s.right_mm_s);
        } else if (kind == WHEELS_RX_STATUS_REQUEST) {
          uint8_t reply[1 + WHEELS_MAX_PAYLOAD];
          size_t len = wheels_status(&s, seq, now, &veh, reply + 1);
          size_t k;
          reply[0] = (uint8_t)WHEELS_CRTP_HEADER_DOWN;
          printf("%lu reply ", t);
          for (k = 0; k < len + 1u; k++) {
            printf("%02x", reply[k]);
          }
          printf("\n");
        } else {
          printf("%lu rejected %s\n", t, wheels_rx_name(kind));
        }
      }
    }

    wheels_outputs(&s, &cfg, &bl, &br);
    printf("%lu out %d %d", t, s.left_mm_s, s.right_mm_s);
    print_bridge(&bl);
    print_bridge(&br);
    printf("\n");
    fflush(stdout);
  }
  return 0;
}
