/*
 * Wheel protocol, version 2: encode and decode (see wheels_protocol.h and ../PROTOCOL.md).
 * Little-endian on the wire, built byte by byte: no struct packing, no host byte order.
 */
#include "wheels_protocol.h"

static void put_u16(uint8_t *p, uint16_t v)
{
  p[0] = (uint8_t)(v & 0xFFu);
  p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v)
{
  p[0] = (uint8_t)(v & 0xFFu);
  p[1] = (uint8_t)((v >> 8) & 0xFFu);
  p[2] = (uint8_t)((v >> 16) & 0xFFu);
  p[3] = (uint8_t)(v >> 24);
}

static void put_i16(uint8_t *p, int16_t v)
{
  put_u16(p, (uint16_t)v); /* two's complement: conversion to unsigned is modulo 2^16 */
}

static uint16_t get_u16(const uint8_t *p)
{
  return (uint16_t)((uint16_t)p[0] | (uint16_t)((uint16_t)p[1] << 8));
}

static uint32_t get_u32(const uint8_t *p)
{
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static int16_t get_i16(const uint8_t *p)
{
  uint16_t u = get_u16(p);
  /* Portable two's-complement read (no implementation-defined unsigned -> signed conversion). */
  return u < 0x8000u ? (int16_t)u : (int16_t)((int32_t)u - 0x10000);
}

/* Version and type checks shared by both directions. */
static wheels_rx_t head(const uint8_t *payload, size_t len, uint8_t *type)
{
  if (payload == NULL || len < 2u) {
    return WHEELS_RX_SHORT;
  }
  if (payload[0] != WHEELS_PROTOCOL_VERSION) {
    return WHEELS_RX_BAD_VERSION;
  }
  *type = payload[1];
  return WHEELS_RX_WHEELS; /* "ok so far": the caller dispatches on *type */
}

wheels_rx_t wheels_decode_uplink(const uint8_t *payload, size_t len, wheels_msg_t *out)
{
  uint8_t type = 0;
  wheels_rx_t r = head(payload, len, &type);
  if (r != WHEELS_RX_WHEELS) {
    out->kind = r;
    return r;
  }
  if (type == WHEELS_MSG_WHEELS) {
    if (len != WHEELS_SIZE_WHEELS) {
      r = WHEELS_RX_BAD_LENGTH;
    } else {
      r = WHEELS_RX_WHEELS;
      out->u.wheels.left_mm_s = get_i16(payload + 2);
      out->u.wheels.right_mm_s = get_i16(payload + 4);
    }
  } else if (type == WHEELS_MSG_STATUS_REQUEST) {
    if (len != WHEELS_SIZE_STATUS_REQUEST) {
      r = WHEELS_RX_BAD_LENGTH;
    } else {
      r = WHEELS_RX_STATUS_REQUEST;
      out->u.request.seq = get_u32(payload + 2);
    }
  } else {
    r = WHEELS_RX_BAD_TYPE;
  }
  out->kind = r;
  return r;
}

wheels_rx_t wheels_decode_downlink(const uint8_t *payload, size_t len, wheels_msg_t *out)
{
  uint8_t type = 0;
  wheels_rx_t r = head(payload, len, &type);
  if (r != WHEELS_RX_WHEELS) {
    out->kind = r;
    return r;
  }
  if (type != WHEELS_MSG_STATUS) {
    r = WHEELS_RX_BAD_TYPE;
  } else if (len != WHEELS_SIZE_STATUS) {
    r = WHEELS_RX_BAD_LENGTH;
  } else {
    wheels_msg_status_t *st = &out->u.status;
    r = WHEELS_RX_STATUS;
    st->echo_seq = get_u32(payload + 2);
    st->received = get_u32(payload + 6);
    st->uptime_ms = get_u32(payload + 10);
    st->rejected = get_u16(payload + 14);
    st->vbat_mv = get_u16(payload + 16);
    st->wheel_left_mm_s = get_i16(payload + 18);
    st->wheel_right_mm_s = get_i16(payload + 20);
    st->setpoint_age_ms = get_u16(payload + 22);
    st->flags = payload[24];
  }
  out->kind = r;
  return r;
}

size_t wheels_encode_wheels(const wheels_msg_wheels_t *msg, uint8_t *out)
{
  out[0] = (uint8_t)WHEELS_PROTOCOL_VERSION;
  out[1] = (uint8_t)WHEELS_MSG_WHEELS;
  put_i16(out + 2, msg->left_mm_s);
  put_i16(out + 4, msg->right_mm_s);
  return WHEELS_SIZE_WHEELS;
}

size_t wheels_encode_status_request(const wheels_msg_status_request_t *msg, uint8_t *out)
{
  out[0] = (uint8_t)WHEELS_PROTOCOL_VERSION;
  out[1] = (uint8_t)WHEELS_MSG_STATUS_REQUEST;
  put_u32(out + 2, msg->seq);
  return WHEELS_SIZE_STATUS_REQUEST;
}

size_t wheels_encode_status(const wheels_msg_status_t *msg, uint8_t *out)
{
  out[0] = (uint8_t)WHEELS_PROTOCOL_VERSION;
  out[1] = (uint8_t)WHEELS_MSG_STATUS;
  put_u32(out + 2, msg->echo_seq);
  put_u32(out + 6, msg->received);
  put_u32(out + 10, msg->uptime_ms);
  put_u16(out + 14, msg->rejected);
  put_u16(out + 16, msg->vbat_mv);
  put_i16(out + 18, msg->wheel_left_mm_s);
  put_i16(out + 20, msg->wheel_right_mm_s);
  put_u16(out + 22, msg->setpoint_age_ms);
  out[24] = msg->flags;
  return WHEELS_SIZE_STATUS;
}

const char *wheels_rx_name(wheels_rx_t kind)
{
  switch (kind) {
    case WHEELS_RX_WHEELS: return "wheels";
    case WHEELS_RX_STATUS_REQUEST: return "status_request";
    case WHEELS_RX_STATUS: return "status";
    case WHEELS_RX_SHORT: return "short";
    case WHEELS_RX_BAD_VERSION: return "version";
    case WHEELS_RX_BAD_TYPE: return "type";
    case WHEELS_RX_BAD_LENGTH: return "length";
    default: return "?";
  }
}
