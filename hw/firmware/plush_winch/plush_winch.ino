// plush_winch: firmware of the plush robot winch board.
//
// Board: Arduino Mega 2560 (ATmega2560, 16 MHz) with two TB6612FNG dual
// H-bridges driving up to four geared DC motors with quadrature encoders.
// Wiring, flashing and calibration: docs/hardware.md. Protocol:
// hw/PROTOCOL.md.
//
// This file owns the motors only: encoder decoding, the control cycle and
// the H-bridges. Everything the host sees (parsing, validation, soft
// limits, the watchdog, targets) is decided by protocol_core.cpp, the same
// file the host emulator is built from; so is the control law (a
// speed-limited reference, a PID and a guard that brakes before the
// target or a soft limit: plush::AxisControl).
#include "protocol_core.h"

#if defined(__AVR__)
#include <avr/interrupt.h>
#include <avr/io.h>
#endif

// ------------------------------------------------------------ settings --

static const uint8_t N_AXES = 4;          // motors fitted (1..4)
static const long BAUD = 115200;           // 8N1
static const uint32_t CONTROL_PERIOD_US = 2000;  // 500 Hz control loop
static const int32_t DEADBAND = 3;         // ticks: "arrived" when within this ...
static const uint32_t SETTLE_MS = 50;      // ... and the encoder has not changed for this long (< 20 ticks/s)
static const uint32_t WATCHDOG_MS = 1000;  // at power-up; host sets WDOG
static const int32_t DEFAULT_SPEED = 600;  // ticks/s at power-up; host sets SPEED

// The control law (reference generator, PID and the guard that brakes
// before the target or a soft limit) and its gains are in protocol_core.h
// (plush::AxisControl), shared with the host emulator.

// Pins. Encoders: channels A and B of motor i on PK(2i) and PK(2i+1),
// i.e. A8/A9, A10/A11, A12/A13, A14/A15 - one pin-change interrupt for
// all eight lines gives full x4 quadrature decoding.
static const uint8_t PIN_PWM[4] = {5, 6, 7, 8};
static const uint8_t PIN_IN1[4] = {30, 32, 34, 36};
static const uint8_t PIN_IN2[4] = {31, 33, 35, 37};
static const uint8_t PIN_STBY = 38;  // both TB6612FNG STBY pins
static const uint8_t PIN_LED = 13;   // lit while any axis is enabled

// --------------------------------------------------------------- state --

static const plush::CoreConfig CORE_CONFIG = {
    "plush-winch", "1.1.0", N_AXES, DEADBAND, SETTLE_MS, WATCHDOG_MS, DEFAULT_SPEED};
static plush::ProtocolCore core(CORE_CONFIG);

static volatile int32_t enc_count[4];
static volatile uint8_t enc_prev;

static plush::AxisControl axis_control[4];
static uint32_t last_control_us;

// Quadrature decoding table, index (previous AB << 2) | current AB.
// Invalid transitions (both lines changed: a missed edge) count 0.
static const int8_t QDEC[16] = {0, -1, 1, 0, 1, 0, 0, -1, -1, 0, 0, 1, 0, 1, -1, 0};

// --------------------------------------------------------------- ISR ----

ISR(PCINT2_vect) {
  const uint8_t now = PINK;
  const uint8_t prev = enc_prev;
  enc_prev = now;
  for (uint8_t a = 0; a < N_AXES; ++a) {
    const uint8_t shift = static_cast<uint8_t>(2 * a);
    const uint8_t idx = static_cast<uint8_t>((((prev >> shift) & 3) << 2) | ((now >> shift) & 3));
    enc_count[a] += QDEC[idx];
  }
}

static int32_t read_encoder(uint8_t a) {
  noInterrupts();  // 32-bit read is not atomic on AVR
  const int32_t v = enc_count[a];
  interrupts();
  return v;
}

// -------------------------------------------------------------- motors --

static void drive(uint8_t a, int16_t pwm) {
  if (pwm > 0) {
    digitalWrite(PIN_IN1[a], HIGH);
    digitalWrite(PIN_IN2[a], LOW);
  } else if (pwm < 0) {
    digitalWrite(PIN_IN1[a], LOW);
    digitalWrite(PIN_IN2[a], HIGH);
    pwm = static_cast<int16_t>(-pwm);
  }
  analogWrite(PIN_PWM[a], pwm > plush::control::kPwmMax ? plush::control::kPwmMax : pwm);
}

static void brake(uint8_t a) {
  // TB6612FNG short brake: IN1 = IN2 = HIGH. The gearbox holds the tendon.
  digitalWrite(PIN_IN1[a], HIGH);
  digitalWrite(PIN_IN2[a], HIGH);
  analogWrite(PIN_PWM[a], 0);
}

static void control(float dt) {
  bool any_enabled = false;
  for (uint8_t a = 0; a < N_AXES; ++a) core.set_position(a, read_encoder(a));
  core.update(millis());

  for (uint8_t a = 0; a < N_AXES; ++a) {
    const plush::Drive d = axis_control[a].step(core, a, read_encoder(a), dt);
    if (d.brake)
      brake(a);
    else
      drive(a, d.pwm);
    if (core.enabled(a)) any_enabled = true;
  }
  digitalWrite(PIN_LED, any_enabled ? HIGH : LOW);
}

// ------------------------------------------------------- setup / loop --

void setup() {
  for (uint8_t a = 0; a < N_AXES; ++a) {
    pinMode(PIN_PWM[a], OUTPUT);
    pinMode(PIN_IN1[a], OUTPUT);
    pinMode(PIN_IN2[a], OUTPUT);
    brake(a);
  }
  pinMode(PIN_STBY, OUTPUT);
  digitalWrite(PIN_STBY, HIGH);
  pinMode(PIN_LED, OUTPUT);

  // Encoder lines: inputs with pull-ups, pin-change interrupt on PK0..PK7.
  for (uint8_t pin = A8; pin <= A15; ++pin) pinMode(pin, INPUT_PULLUP);
  enc_prev = PINK;
  PCMSK2 = 0xFF;
  PCICR |= (1 << PCIE2);

  Serial.begin(BAUD);
  last_control_us = micros();
}

void loop() {
  while (Serial.available() > 0) {
    const int c = Serial.read();
    if (c < 0) break;
    const char* reply = core.feed(static_cast<uint8_t>(c), millis());
    if (reply) Serial.write(reply);
  }
  const uint32_t now = micros();
  const uint32_t elapsed = now - last_control_us;
  if (elapsed >= CONTROL_PERIOD_US) {
    last_control_us = now;
    control(static_cast<float>(elapsed) * 1e-6f);
  }
}
