// Just enough of the Arduino and AVR API to compile plush_winch.ino on the
// host (make -C hw firmware-check): a type and syntax check of the sketch,
// not a simulation. The emulator is the simulation.
#ifndef PLUSH_HOST_ARDUINO_STUB_H
#define PLUSH_HOST_ARDUINO_STUB_H

#include <stdint.h>
#include <string.h>

#define HIGH 1
#define LOW 0
#define INPUT 0
#define OUTPUT 1
#define INPUT_PULLUP 2
#define PCIE2 2

enum : uint8_t { A8 = 62, A9, A10, A11, A12, A13, A14, A15 };

extern volatile uint8_t PINK, PCMSK2, PCICR;

#define ISR(vector) extern "C" void vector(void)

void pinMode(uint8_t pin, uint8_t mode);
void digitalWrite(uint8_t pin, uint8_t value);
void analogWrite(uint8_t pin, int value);
unsigned long millis();
unsigned long micros();
void noInterrupts();
void interrupts();

struct HostSerial {
  void begin(long baud);
  int available();
  int read();
  size_t write(const char* s);
};
extern HostSerial Serial;

#endif
