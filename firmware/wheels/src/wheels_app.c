/*
 * Wheel app for the Crazyflie (firmware app layer): the vehicle's side of the wheel protocol,
 * version 2 (../PROTOCOL.md). This file is the thin glue to the firmware:
 *
 *   - appMain: receive app-channel packets with a timeout, feed them and the time to the portable
 *     logic (wheels_logic.c), answer STATUS_REQUESTs, run the wheel watchdog when idle;
 *   - write the dual H-bridge's inputs: direction pins with the deck GPIO API, PWM with TIM3;
 *   - sample what the firmware knows for STATUS: battery (pm), motors, supervisor, commander;
 *   - parameter group "wheels" (configuration) and log group "wheels" (state).
 *
 * Wiring and build: ../README.md.
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "app.h"
#include "app_channel.h"

#include "FreeRTOS.h"
#include "task.h"

#include "commander.h"
#include "debug.h"
#include "deck.h"
#include "log.h"
#include "motors.h"
#include "param.h"
#include "pm.h"
#include "stm32fxxx.h"
#include "supervisor.h"

#include "wheels_config.h"
#include "wheels_logic.h"
#include "wheels_protocol.h"

#define DEBUG_MODULE "WHEELS"

/* ---- state -------------------------------------------------------------------------------- */

/* Statically initialised, never reset at run time: persistent parameters are loaded into it
 * before appMain starts. */
static wheels_config_t cfg = {
  .max_speed_mm_s = WHEELS_DEFAULT_MAX_SPEED_MM_S,
  .min_drive = WHEELS_DEFAULT_MIN_DRIVE,
  .watchdog_ms = WHEELS_WATCHDOG_MS_DEFAULT,
  .brake = WHEELS_DEFAULT_BRAKE,
  .invert_left = 0,
  .invert_right = 0,
#if WHEELS_USE_TB6612
  .driver = (uint8_t)WHEELS_DRIVER_TB6612,
#else
  .driver = (uint8_t)WHEELS_DRIVER_DRV8833,
#endif
};

static wheels_state_t state;
static wheels_bridge_t outLeft;
static wheels_bridge_t outRight;
static int16_t logDriveLeft;   /* signed drive, -10000..10000 */
static int16_t logDriveRight;
static uint16_t txDropped;     /* STATUS replies the full TX queue refused */
static uint32_t pwmPeriod;     /* timer counts per PWM period */

/* ---- outputs ------------------------------------------------------------------------------ */

#if WHEELS_PWM_LEFT_ON_MISO
#define LEFT_PWM_PORT GPIOA
#define LEFT_PWM_RCC RCC_AHB1Periph_GPIOA
#define LEFT_PWM_PIN GPIO_Pin_6
#define LEFT_PWM_SOURCE GPIO_PinSource6
#else
#define LEFT_PWM_PORT GPIOB
#define LEFT_PWM_RCC RCC_AHB1Periph_GPIOB
#define LEFT_PWM_PIN GPIO_Pin_4
#define LEFT_PWM_SOURCE GPIO_PinSource4
#endif

#if WHEELS_PWM_RIGHT_ON_MOSI
#define RIGHT_PWM_PORT GPIOA
#define RIGHT_PWM_RCC RCC_AHB1Periph_GPIOA
#define RIGHT_PWM_PIN GPIO_Pin_7
#define RIGHT_PWM_SOURCE GPIO_PinSource7
#else
#define RIGHT_PWM_PORT GPIOB
#define RIGHT_PWM_RCC RCC_AHB1Periph_GPIOB
#define RIGHT_PWM_PIN GPIO_Pin_5
#define RIGHT_PWM_SOURCE GPIO_PinSource5
#endif

static void pwmPinInit(GPIO_TypeDef *port, uint16_t pin, uint8_t source)
{
  GPIO_InitTypeDef gpio;
  GPIO_StructInit(&gpio);
  gpio.GPIO_Pin = pin;
  gpio.GPIO_Mode = GPIO_Mode_AF;
  gpio.GPIO_OType = GPIO_OType_PP;
  gpio.GPIO_PuPd = GPIO_PuPd_NOPULL;
  gpio.GPIO_Speed = GPIO_Speed_25MHz;
  GPIO_Init(port, &gpio);
  GPIO_PinAFConfig(port, source, GPIO_AF_TIM3);
}

static void pwmInit(void)
{
  TIM_TimeBaseInitTypeDef base;
  TIM_OCInitTypeDef oc;

  pwmPeriod = WHEELS_TIM_CLOCK_HZ / (uint32_t)WHEELS_PWM_HZ;

  RCC_APB1PeriphClockCmd(RCC_APB1Periph_TIM3, ENABLE);
  RCC_AHB1PeriphClockCmd(LEFT_PWM_RCC | RIGHT_PWM_RCC, ENABLE);

  TIM_TimeBaseStructInit(&base);
  base.TIM_Prescaler = 0;
  base.TIM_Period = pwmPeriod - 1u;
  base.TIM_ClockDivision = TIM_CKD_DIV1;
  base.TIM_CounterMode = TIM_CounterMode_Up;
  TIM_TimeBaseInit(TIM3, &base);

  /* PWM mode 1: the pin is high while the counter is below the compare value; compare =
   * pwmPeriod keeps it high all period. Both channels start low. */
  TIM_OCStructInit(&oc);
  oc.TIM_OCMode = TIM_OCMode_PWM1;
  oc.TIM_OutputState = TIM_OutputState_Enable;
  oc.TIM_Pulse = 0;
  oc.TIM_OCPolarity = TIM_OCPolarity_High;
  TIM_OC1Init(TIM3, &oc);
  TIM_OC1PreloadConfig(TIM3, TIM_OCPreload_Enable);
  TIM_OC2Init(TIM3, &oc);
  TIM_OC2PreloadConfig(TIM3, TIM_OCPreload_Enable);
  TIM_ARRPreloadConfig(TIM3, ENABLE);
  TIM_Cmd(TIM3, ENABLE);

  /* Only now hand the pins to the timer (they were inputs: the drivers' pull-downs held them low). */
  pwmPinInit(LEFT_PWM_PORT, LEFT_PWM_PIN, LEFT_PWM_SOURCE);
  pwmPinInit(RIGHT_PWM_PORT, RIGHT_PWM_PIN, RIGHT_PWM_SOURCE);
}

static uint32_t pwmCompare(uint16_t duty)
{
  return ((uint32_t)duty * pwmPeriod + WHEELS_DRIVE_FULL / 2u) / WHEELS_DRIVE_FULL;
}

static void outputsInit(void)
{
  pinMode(WHEELS_PIN_LEFT_IN1, OUTPUT);
  digitalWrite(WHEELS_PIN_LEFT_IN1, LOW);
  pinMode(WHEELS_PIN_RIGHT_IN1, OUTPUT);
  digitalWrite(WHEELS_PIN_RIGHT_IN1, LOW);
#if WHEELS_USE_TB6612
  pinMode(WHEELS_PIN_LEFT_IN2, OUTPUT);
  digitalWrite(WHEELS_PIN_LEFT_IN2, LOW);
  pinMode(WHEELS_PIN_RIGHT_IN2, OUTPUT);
  digitalWrite(WHEELS_PIN_RIGHT_IN2, LOW);
#endif
  pwmInit();
#if WHEELS_USE_TB6612 && WHEELS_HAS_STBY
  pinMode(WHEELS_PIN_STBY, OUTPUT);
  digitalWrite(WHEELS_PIN_STBY, HIGH);
#endif
}

static void outputsApply(void)
{
  wheels_outputs(&state, &cfg, &outLeft, &outRight);

  digitalWrite(WHEELS_PIN_LEFT_IN1, outLeft.in1 ? HIGH : LOW);
  digitalWrite(WHEELS_PIN_RIGHT_IN1, outRight.in1 ? HIGH : LOW);
#if WHEELS_USE_TB6612
  digitalWrite(WHEELS_PIN_LEFT_IN2, outLeft.in2 ? HIGH : LOW);
  digitalWrite(WHEELS_PIN_RIGHT_IN2, outRight.in2 ? HIGH : LOW);
#endif
  TIM_SetCompare1(TIM3, pwmCompare(outLeft.pwm));
  TIM_SetCompare2(TIM3, pwmCompare(outRight.pwm));

  logDriveLeft = (int16_t)(outLeft.dir * (int32_t)outLeft.drive);
  logDriveRight = (int16_t)(outRight.dir * (int32_t)outRight.drive);
}

/* ---- what the firmware knows, for STATUS -------------------------------------------------- */

static void sampleVehicle(wheels_vehicle_t *v)
{
  uint8_t flags = 0;
  uint32_t i;

  for (i = 0; i < NBR_OF_MOTORS; i++) {
    if (motorsGetRatio(i) > 0) {
      flags = (uint8_t)(flags | WHEELS_FLAG_MOTORS);
    }
  }
  if (supervisorIsFlying()) {
    flags = (uint8_t)(flags | WHEELS_FLAG_FLYING);
  }
  if (supervisorIsArmed()) {
    flags = (uint8_t)(flags | WHEELS_FLAG_ARMED);
  }
  if (supervisorIsLocked()) {
    flags = (uint8_t)(flags | WHEELS_FLAG_LOCKED);
  }
  if (pmIsBatteryLow()) {
    flags = (uint8_t)(flags | WHEELS_FLAG_LOW_BATTERY);
  }
  /* WHEELS_FLAG_MEASURED stays 0: this build has no encoders, the speeds are the commanded ones. */
  v->flags = flags;
  v->vbat_mv = wheels_volts_to_mv(pmGetBatteryVoltage());
  v->setpoint_age_ms = wheels_age_u16(T2M(commanderGetInactivityTime()));
}

/* ---- main loop ---------------------------------------------------------------------------- */

void appMain(void)
{
  static uint8_t rx[APPCHANNEL_MTU];
  static uint8_t tx[APPCHANNEL_MTU];

  wheels_init(&state);
  outputsInit();
  outputsApply();
  DEBUG_PRINT("wheel protocol v%u, %s, PWM %u Hz\n", (unsigned)WHEELS_PROTOCOL_VERSION,
              WHEELS_USE_TB6612 ? "TB6612FNG" : "DRV8833", (unsigned)WHEELS_PWM_HZ);

  while (true) {
    size_t n = appchannelReceiveDataPacket(rx, sizeof rx, WHEELS_LOOP_MS);
    uint32_t now = T2M(xTaskGetTickCount());

    if (appchannelHasOverflowOccurred()) {
      wheels_note_overflow(&state);
    }
    if (n > 0) {
      uint32_t seq = 0;
      if (wheels_receive(&state, &cfg, rx, n, now, &seq) == WHEELS_RX_STATUS_REQUEST) {
        wheels_vehicle_t v;
        size_t len;
        sampleVehicle(&v);
        len = wheels_status(&state, seq, now, &v, tx);
        /* Never block: a full TX queue (no link) must not stall the watchdog. */
        if (appchannelSendDataPacket(tx, len) != pdTRUE) {
          txDropped++;
        }
      }
    } else {
      (void)wheels_tick(&state, &cfg, now);
    }
    outputsApply();
  }
}

/* ---- parameters and logs ------------------------------------------------------------------ */

/**
 * Wheel app configuration (firmware/wheels in the fleet repository).
 */
PARAM_GROUP_START(wheels)
/**
 * @brief Wheel rim speed at full drive (mm/s); 0 keeps the wheels stopped
 */
PARAM_ADD(PARAM_UINT16 | PARAM_PERSISTENT, maxSpeed, &cfg.max_speed_mm_s)
/**
 * @brief Drive of the smallest non-zero speed, 0..10000 (static friction)
 */
PARAM_ADD(PARAM_UINT16 | PARAM_PERSISTENT, minDrive, &cfg.min_drive)
/**
 * @brief Wheel watchdog (ms); the protocol expects 500
 */
PARAM_ADD(PARAM_UINT16, wdtMs, &cfg.watchdog_ms)
/**
 * @brief At zero speed: 1 short brake, 0 coast
 */
PARAM_ADD(PARAM_UINT8 | PARAM_PERSISTENT, brake, &cfg.brake)
/**
 * @brief 1: the left motor runs backwards for forward (swapped wires)
 */
PARAM_ADD(PARAM_UINT8 | PARAM_PERSISTENT, invLeft, &cfg.invert_left)
/**
 * @brief 1: the right motor runs backwards for forward (swapped wires)
 */
PARAM_ADD(PARAM_UINT8 | PARAM_PERSISTENT, invRight, &cfg.invert_right)
/**
 * @brief Motor driver of this build: 0 DRV8833, 1 TB6612FNG
 */
PARAM_ADD(PARAM_UINT8 | PARAM_RONLY, driver, &cfg.driver)
PARAM_GROUP_STOP(wheels)

/**
 * Wheel app state.
 */
LOG_GROUP_START(wheels)
/**
 * @brief Left wheel speed setpoint in effect (mm/s; 0 after the watchdog)
 */
LOG_ADD(LOG_INT16, left, &state.left_mm_s)
/**
 * @brief Right wheel speed setpoint in effect (mm/s)
 */
LOG_ADD(LOG_INT16, right, &state.right_mm_s)
/**
 * @brief Left motor drive, signed, -10000..10000
 */
LOG_ADD(LOG_INT16, driveL, &logDriveLeft)
/**
 * @brief Right motor drive, signed, -10000..10000
 */
LOG_ADD(LOG_INT16, driveR, &logDriveRight)
/**
 * @brief App-channel packets received (STATUS field "received")
 */
LOG_ADD(LOG_UINT32, rx, &state.received)
/**
 * @brief Malformed app-channel packets dropped
 */
LOG_ADD(LOG_UINT16, rejected, &state.rejected)
/**
 * @brief Times the wheel watchdog stopped the wheels
 */
LOG_ADD(LOG_UINT32, wdt, &state.watchdogs)
/**
 * @brief App-channel receive-queue overflows seen
 */
LOG_ADD(LOG_UINT32, overflow, &state.overflows)
/**
 * @brief STATUS replies dropped by a full TX queue
 */
LOG_ADD(LOG_UINT16, txDrop, &txDropped)
LOG_GROUP_STOP(wheels)
