// Portable core of the plush winch board protocol (hw/PROTOCOL.md).
//
// Everything the protocol decides lives here: line framing, parsing,
// argument validation, soft limits, the host watchdog and the per-axis
// state. It has no Arduino dependency (only <stdint.h>, <stddef.h>) and no
// heap, so the same file is compiled into the AVR firmware and into the
// host emulator. The protocol itself uses no floating point; the motion
// control law (AxisControl, below) does, as the firmware runs it, so the
// emulator drives its simulated motors with the firmware's own law.
//
// The caller owns the motors:
//
//   loop:
//     while a byte b is available:
//       if (const char* reply = core.feed(b, now_ms)) write(reply);
//     for each axis a: core.set_position(a, encoder_count[a]);
//     core.update(now_ms);                       // watchdog
//     for each axis a:
//       Drive d = control[a].step(core, a, encoder_count[a], dt);
//       if d.brake: brake  else: apply d.pwm (-255..255)
//
// Positions given to set_position() are raw encoder counts; the core keeps
// the offset set by ZERO, so setpoint_raw() is in the same raw counts.
#ifndef PLUSH_PROTOCOL_CORE_H
#define PLUSH_PROTOCOL_CORE_H

#include <stddef.h>
#include <stdint.h>

namespace plush {

// Fixed sizes. They are not configurable per translation unit on purpose:
// the class layout must be the same in every file that includes this.
const uint8_t kMaxAxes = 8;
const uint8_t kProtocolVersion = 1;
const size_t kMaxLine = 120;            // characters, terminator excluded
const uint32_t kMaxSeq = 65535;
const int32_t kMaxTicks = 1000000000L;  // |target|, |limit| <= this
const int32_t kMaxSpeed = 1000000L;     // ticks/s
const uint32_t kMinWatchdogMs = 20;
const uint32_t kMaxWatchdogMs = 60000;

// Error codes of "ERR <code> <message>" replies; the table in
// hw/PROTOCOL.md and plush_opt/board/protocol.py must match.
enum ErrorCode {
  E_MALFORMED = 1,        // bad characters, no sequence number, no command
  E_TOO_LONG = 2,         // line longer than kMaxLine characters
  E_UNKNOWN_COMMAND = 3,  // command word not known
  E_BAD_ARGUMENT = 4,     // wrong number of arguments or not a valid number
  E_BAD_AXIS = 5,         // axis index >= number of winches
  E_OUT_OF_LIMITS = 6,    // target outside the axis' soft limits
  E_BUSY = 7,             // ZERO or LIMIT on an axis that is moving
  E_CONFLICT = 8          // LIMIT would exclude the target of an enabled axis
};

enum StopReason { STOP_COMMAND = 0, STOP_WATCHDOG = 1, STOP_HANGUP = 2 };

struct CoreConfig {
  const char* board_name;        // reported by ID, [a-z0-9-]+
  const char* firmware_version;  // reported by ID, e.g. "1.0.0"
  uint8_t n_axes;                // 1..kMaxAxes
  int32_t deadband;              // |target - position| <= deadband: may count as arrived
  uint32_t settle_ms;            // ... once the position has not changed for this long
  uint32_t watchdog_ms;          // timeout at power-up
  int32_t default_speed;         // speed limit at power-up, ticks/s
};

class ProtocolCore {
 public:
  explicit ProtocolCore(const CoreConfig& config);

  // Feed one received byte. Returns a complete reply line (ending in "\n")
  // when this byte completed a line that needs one, else a null pointer.
  // The pointer stays valid until the next call of feed().
  const char* feed(uint8_t byte, uint32_t now_ms);

  // Track arrival and run the watchdog. Call after set_position() in
  // every control cycle.
  void update(uint32_t now_ms);

  // The measured position of an axis, raw encoder counts.
  void set_position(uint8_t axis, int32_t raw_ticks);

  // What the motor should do.
  int32_t setpoint_raw(uint8_t axis) const;
  bool enabled(uint8_t axis) const;
  int32_t speed_limit(uint8_t axis) const;

  // Stop every axis: target := position, drive disabled (brake).
  void stop_all(StopReason reason);
  // The host went away (serial hang-up): same as a stop.
  void hangup() { stop_all(STOP_HANGUP); }

  // Introspection (emulator state file, tests, debugging).
  uint8_t n_axes() const { return n_axes_; }
  int32_t position(uint8_t axis) const;  // after ZERO offset
  int32_t target(uint8_t axis) const;
  int32_t offset(uint8_t axis) const;
  int32_t limit_lo(uint8_t axis) const;
  int32_t limit_hi(uint8_t axis) const;
  bool moving(uint8_t axis) const;
  bool any_moving() const;
  uint32_t watchdog_ms() const { return watchdog_ms_; }
  uint32_t watchdog_trips() const { return stops_[STOP_WATCHDOG]; }
  uint32_t stop_count(StopReason reason) const { return stops_[reason]; }
  uint32_t lines() const { return lines_; }
  int32_t deadband() const { return config_.deadband; }
  uint32_t errors() const { return errors_; }

 private:
  struct Axis {
    int32_t raw;      // last raw encoder count
    int32_t offset;   // raw count that reads as 0
    int32_t target;   // in zeroed ticks
    int32_t lo, hi;   // soft limits, zeroed ticks
    int32_t speed;    // ticks/s
    bool enabled;
    // Arrival: within the deadband AND at rest. A motor passing through
    // its deadband at speed has not arrived; it coasts on. Latched until
    // the next SET/SETALL of the axis or until it leaves the deadband, so
    // a held axis whose encoder flickers by a tick stays "not moving".
    int32_t last_raw;        // raw count at the last update()
    uint32_t still_since_ms; // when last_raw last changed
    bool settled;
  };

  bool within_deadband(uint8_t axis) const;
  void arm(uint8_t axis);  // a new target: not arrived until settled again

  static const uint8_t kMaxTokens = 2 + kMaxAxes;  // seq, command, arguments
  static const size_t kReplySize = 320;

  const char* handle_line();
  const char* reply_too_long();

  // Commands; each writes the reply and returns it.
  const char* cmd_id(uint8_t nargs);
  const char* cmd_ping(uint8_t nargs);
  const char* cmd_get(uint8_t nargs);
  const char* cmd_set(uint8_t nargs);
  const char* cmd_setall(uint8_t nargs);
  const char* cmd_stop(uint8_t nargs);
  const char* cmd_zero(uint8_t nargs);
  const char* cmd_limit(uint8_t nargs);
  const char* cmd_speed(uint8_t nargs);
  const char* cmd_wdog(uint8_t nargs);

  // Argument parsing: 0 on success, else the error code.
  int parse_axis(const char* token, uint8_t* axis) const;

  // Reply construction.
  void begin_ok();
  const char* finish();
  const char* error(int code, const char* message);
  const char* error_noseq(int code, const char* message);
  void put(const char* s);
  void put_char(char c);
  void put_int(int32_t v);
  void put_uint(uint32_t v);

  CoreConfig config_;
  uint8_t n_axes_;
  Axis axes_[kMaxAxes];
  uint32_t watchdog_ms_;
  uint32_t last_rx_ms_;
  uint32_t stops_[3];
  uint32_t lines_;
  uint32_t errors_;

  char line_[kMaxLine + 1];
  size_t line_len_;
  bool overflow_;

  const char* tokens_[kMaxTokens];
  uint8_t n_tokens_;
  uint32_t seq_;

  char reply_[kReplySize];
  size_t reply_len_;
};

// ------------------------------------------------------------ motion --

// The position control law of one axis, run every control cycle.
//
// A reference walks towards the target at most at the axis' speed limit
// and a PID tracks it (output in PWM counts, -255..255). Over both sits a
// guard on the measured position: the motor is short-braked (the H-bridge's
// IN1 = IN2 = HIGH; a geared motor stops within a few ms) as soon as the
// distance it would still travel at its measured speed reaches the target
// or a soft limit ahead of it, or when it moves away from its target, and
// it is never driven towards a target it stands on or past, nor past a
// soft limit. So the motor closes in on its target in braked steps and
// never passes it by more than the deadband, nor a soft limit at all,
// whatever the speed limit and however fast the motor.
//
// Gains: tune per motor (raise kKp until the axis rings, halve it, then
// add kKd; kKi only removes the last few ticks against tendon load).
// kStopTime is how far ahead (in time at the measured speed) the guard
// looks: one control cycle of travel before it can act, one for the brake
// to take hold, and one of margin for a motor still accelerating. A motor
// that brakes slower needs more.
namespace control {
const float kKp = 2.0f;             // PWM counts per tick of error
const float kKi = 4.0f;             // per second
const float kKd = 0.04f;            // seconds
const float kIntegralLimit = 80.0f; // anti-windup clamp of the integral term, PWM counts
const float kSpeedFilter = 0.02f;   // s: measured-speed low-pass (ticks come in steps)
const float kStillSpeed = 20.0f;    // ticks/s: slower than this the motor is held back by a load
const float kStopTime = 0.006f;     // s of travel at the measured speed the guard keeps clear
const int16_t kPwmMin = 25;         // below this the gearmotor does not turn: jump over it
const int16_t kPwmMax = 255;
}  // namespace control

struct Drive {
  bool brake;   // short brake (also when the axis is not enabled)
  int16_t pwm;  // else: signed PWM, -kPwmMax..kPwmMax (0: not driven)
};

class AxisControl {
 public:
  AxisControl();
  // One control cycle of `axis`: `raw` is its encoder count now (raw, as
  // given to set_position), `dt` the seconds since the previous cycle.
  Drive step(const ProtocolCore& core, uint8_t axis, int32_t raw, float dt);

 private:
  int16_t pid(int32_t goal, int32_t raw, int32_t deadband, float dt);
  bool guard(const ProtocolCore& core, uint8_t axis, int32_t raw, int32_t moved, int16_t pwm, float dt) const;

  // Speed-limited reference, raw ticks: whole ticks plus the fraction
  // walked so far. A float alone stalls at large counts (above 2^24 a
  // step of ~1 tick per cycle rounds away).
  int32_t ref_;
  float ref_frac_;  // 0 <= ref_frac_ < 1
  float integral_;  // PWM counts
  float prev_err_;
  int32_t prev_raw_;  // raw ticks, last cycle
  float speed_;       // measured, low-passed, ticks/s
  bool active_;
};

}  // namespace plush

#endif  // PLUSH_PROTOCOL_CORE_H
