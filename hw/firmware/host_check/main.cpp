// Links the sketch against the stub API and runs setup() and loop() over a
// short scripted exchange, so that the firmware-check target catches
// link errors and obvious misbehaviour as well as compile errors.
#include <stdio.h>

#include "Arduino.h"

volatile uint8_t PINK, PCMSK2, PCICR;
HostSerial Serial;

static unsigned long fake_us = 0;
static const char* input = "1 ID\n2 LIMIT 0 0 100\n3 SET 0 50\n4 GET\n5 STOP\n";
static size_t input_pos = 0;
static int replies = 0;
static int pwm_writes = 0;

void pinMode(uint8_t, uint8_t) {}
void digitalWrite(uint8_t, uint8_t) {}
void analogWrite(uint8_t, int value) { pwm_writes += value != 0; }
unsigned long millis() { return fake_us / 1000; }
unsigned long micros() { return fake_us += 100; }
void noInterrupts() {}
void interrupts() {}
void HostSerial::begin(long) {}
// One byte every 2 ms of fake time, so the control loop runs between lines.
int HostSerial::available() { return input[input_pos] != '\0' && fake_us > 2000UL * input_pos; }
int HostSerial::read() { return input[input_pos] ? input[input_pos++] : -1; }
size_t HostSerial::write(const char* s) {
  fputs(s, stdout);
  ++replies;
  return strlen(s);
}

void setup();
void loop();
extern "C" void PCINT2_vect(void);

int main() {
  setup();
  for (int i = 0; i < 5000; ++i) {
    loop();
    PCINT2_vect();
  }
  if (replies != 5 || pwm_writes == 0) {
    fprintf(stderr, "firmware-check: expected 5 replies and motor output, got %d replies, %d PWM writes\n",
            replies, pwm_writes);
    return 1;
  }
  printf("firmware-check: ok\n");
  return 0;
}
