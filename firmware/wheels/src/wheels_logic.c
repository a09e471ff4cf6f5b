/*
 * The wheel app's logic (see wheels_logic.h). No firmware headers, no floating point except the
 * battery-voltage conversion.
 */
#include "wheels_logic.h"

void wheels_default_config(wheels_config_t *cfg)
{
  cfg->max_speed_mm_s = WHEELS_DEFAULT_MAX_SPEED_MM_S;
  cfg->min_drive = WHEELS_DEFAULT_MIN_DRIVE;
  cfg->watchdog_ms = WHEELS_WATCHDOG_MS_DEFAULT;
  cfg->brake = WHEELS_DEFAULT_BRAKE;
  cfg->invert_left = 0u;
  cfg->invert_right = 0u;
  cfg->driver = (uint8_t)WHEELS_DRIVER_DRV8833;
}

void wheels_init(wheels_state_t *s)
{
  s->left_mm_s = 0;
  s->right_mm_s = 0;
  s->last_wheels_ms = 0u;
  s->running = false;
  s->latched = 0u;
  s->received = 0u;
  s->rejected = 0u;
  s->wheels = 0u;
  s->requests = 0u;
  s->watchdogs = 0u;
  s->overflows = 0u;
}

bool wheels_tick(wheels_state_t *s, const wheels_config_t *cfg, uint32_t now_ms)
{
  if (!s->running) {
    return false;
  }
  if ((uint32_t)(now_ms - s->last_wheels_ms) <= (uint32_t)cfg->watchdog_ms) {
    return false;
  }
  s->left_mm_s = 0;
  s->right_mm_s = 0;
  s->running = false;
  s->latched = (uint8_t)(s->latched | WHEELS_FLAG_WHEEL_WATCHDOG);
  s->watchdogs++;
  return true;
}

wheels_rx_t wheels_receive(wheels_state_t *s, const wheels_config_t *cfg, const uint8_t *payload,
                           size_t len, uint32_t now_ms, uint32_t *seq)
{
  wheels_msg_t msg;
  wheels_rx_t kind;

  (void)wheels_tick(s, cfg, now_ms);
  s->received++;
  kind = wheels_decode_uplink(payload, len, &msg);
  switch (kind) {
    case WHEELS_RX_WHEELS:
      s->wheels++;
      s->left_mm_s = msg.u.wheels.left_mm_s;
      s->right_mm_s = msg.u.wheels.right_mm_s;
      s->last_wheels_ms = now_ms;
      s->running = s->left_mm_s != 0 || s->right_mm_s != 0;
      break;
    case WHEELS_RX_STATUS_REQUEST:
      s->requests++;
      if (seq != NULL) {
        *seq = msg.u.request.seq;
      }
      break;
    default:
      s->rejected++;
      break;
  }
  return kind;
}

void wheels_note_overflow(wheels_state_t *s)
{
  s->overflows++;
  s->latched = (uint8_t)(s->latched | WHEELS_FLAG_RX_OVERFLOW);
}

size_t wheels_status(wheels_state_t *s, uint32_t echo_seq, uint32_t now_ms, const wheels_vehicle_t *v,
                     uint8_t *out)
{
  wheels_msg_status_t st;
  st.echo_seq = echo_seq;
  st.received = s->received;
  st.uptime_ms = now_ms;
  st.rejected = s->rejected;
  st.vbat_mv = v->vbat_mv;
  st.wheel_left_mm_s = s->left_mm_s;
  st.wheel_right_mm_s = s->right_mm_s;
  st.setpoint_age_ms = v->setpoint_age_ms;
  st.flags = (uint8_t)((s->latched & (WHEELS_FLAG_WHEEL_WATCHDOG | WHEELS_FLAG_RX_OVERFLOW)) |
                       (v->flags & WHEELS_FLAGS_VEHICLE));
  s->latched = 0u;
  return wheels_encode_status(&st, out);
}

uint16_t wheels_drive_for(const wheels_config_t *cfg, int32_t speed_mm_s)
{
  uint32_t mag = speed_mm_s < 0 ? (uint32_t)(-(int64_t)speed_mm_s) : (uint32_t)speed_mm_s;
  uint32_t max = cfg->max_speed_mm_s;
  uint32_t min = cfg->min_drive > WHEELS_DRIVE_FULL ? WHEELS_DRIVE_FULL : cfg->min_drive;
  uint32_t drive;

  if (mag == 0u || max == 0u) {
    return 0u;
  }
  if (mag >= max) {
    return (uint16_t)WHEELS_DRIVE_FULL;
  }
  /* mag < max <= 65535 and span <= 10000: 2 * span * mag < 2^31, no overflow. */
  drive = min + (2u * (WHEELS_DRIVE_FULL - min) * mag + max) / (2u * max);
  return (uint16_t)(drive > WHEELS_DRIVE_FULL ? WHEELS_DRIVE_FULL : drive);
}

void wheels_bridge(const wheels_config_t *cfg, int16_t speed_mm_s, bool invert, wheels_bridge_t *out)
{
  int32_t v = invert ? -(int32_t)speed_mm_s : (int32_t)speed_mm_s;
  uint16_t drive = wheels_drive_for(cfg, v);
  int8_t dir = drive == 0u ? 0 : (v > 0 ? 1 : -1);

  out->dir = dir;
  out->drive = drive;
  if (cfg->driver == (uint8_t)WHEELS_DRIVER_TB6612) {
    /* xIN1/xIN2 pick the direction, PWMx chops: low PWM phases short-brake (slow decay). */
    if (dir > 0) {
      out->in1 = 1u;
      out->in2 = 0u;
      out->pwm = drive;
    } else if (dir < 0) {
      out->in1 = 0u;
      out->in2 = 1u;
      out->pwm = drive;
    } else if (cfg->brake) {
      out->in1 = 1u; /* IN1 = IN2 = H: short brake whatever PWM */
      out->in2 = 1u;
      out->pwm = 0u;
    } else {
      out->in1 = 0u; /* IN1 = IN2 = L with PWM = H: outputs off (coast) */
      out->in2 = 0u;
      out->pwm = (uint16_t)WHEELS_DRIVE_FULL;
    }
  } else {
    /* DRV8833, sign-magnitude on one PWM pin: xIN1 = direction, xIN2 = PWM.
     * Forward: IN1 = 1, IN2 low drives, IN2 high brakes (slow decay): pwm = full - drive.
     * Reverse: IN1 = 0, IN2 high drives, IN2 low coasts (fast decay): pwm = drive. */
    out->in2 = 0u;
    if (dir > 0) {
      out->in1 = 1u;
      out->pwm = (uint16_t)(WHEELS_DRIVE_FULL - drive);
    } else if (dir < 0) {
      out->in1 = 0u;
      out->pwm = drive;
    } else if (cfg->brake) {
      out->in1 = 1u; /* IN1 = IN2 = 1: brake */
      out->pwm = (uint16_t)WHEELS_DRIVE_FULL;
    } else {
      out->in1 = 0u; /* IN1 = IN2 = 0: coast */
      out->pwm = 0u;
    }
  }
}

void wheels_outputs(const wheels_state_t *s, const wheels_config_t *cfg, wheels_bridge_t *left,
                    wheels_bridge_t *right)
{
  wheels_bridge(cfg, s->left_mm_s, cfg->invert_left != 0u, left);
  wheels_bridge(cfg, s->right_mm_s, cfg->invert_right != 0u, right);
}

uint16_t wheels_volts_to_mv(float volts)
{
  float mv = volts * 1000.0f + 0.5f;
  if (!(mv >= 0.0f)) { /* negative or NaN */
    return 0u;
  }
  if (mv >= 65535.0f) {
    return 0xFFFFu;
  }
  return (uint16_t)mv;
}

uint16_t wheels_age_u16(uint32_t ms)
{
  return ms >= (uint32_t)WHEELS_AGE_NEVER ? (uint16_t)WHEELS_AGE_NEVER : (uint16_t)ms;
}
