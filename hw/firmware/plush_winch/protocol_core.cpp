// Portable core of the plush winch board protocol. See protocol_core.h and
// hw/PROTOCOL.md (the grammar and every reply are specified there).
#include "protocol_core.h"

#include <string.h>

namespace plush {

namespace {

bool is_space(char c) { return c == ' ' || c == '\t'; }

bool is_digit(char c) { return c >= '0' && c <= '9'; }

// Sequence number: 1..5 decimal digits, value <= kMaxSeq.
bool parse_seq(const char* s, uint32_t* out) {
  uint32_t v = 0;
  size_t n = 0;
  for (; s[n] != '\0'; ++n) {
    if (!is_digit(s[n]) || n >= 5) return false;
    v = v * 10 + static_cast<uint32_t>(s[n] - '0');
  }
  if (n == 0 || v > kMaxSeq) return false;
  *out = v;
  return true;
}

// Integer: optional sign, 1..10 digits, |value| <= bound.
bool parse_int(const char* s, int32_t bound, int32_t* out) {
  bool negative = false;
  if (*s == '+' || *s == '-') {
    negative = (*s == '-');
    ++s;
  }
  uint32_t v = 0;
  size_t n = 0;
  for (; s[n] != '\0'; ++n) {
    if (!is_digit(s[n]) || n >= 10) return false;
    uint32_t d = static_cast<uint32_t>(s[n] - '0');
    // 10 digits can exceed 2^32: check before multiplying.
    if (v > (static_cast<uint32_t>(bound) - d) / 10) return false;
    v = v * 10 + d;
  }
  if (n == 0) return false;
  *out = negative ? -static_cast<int32_t>(v) : static_cast<int32_t>(v);
  return true;
}

int32_t abs32(int32_t v) { return v < 0 ? -v : v; }

}  // namespace

ProtocolCore::ProtocolCore(const CoreConfig& config)
    : config_(config),
      n_axes_(config.n_axes == 0 ? 1 : (config.n_axes > kMaxAxes ? kMaxAxes : config.n_axes)),
      watchdog_ms_(config.watchdog_ms),
      last_rx_ms_(0),
      lines_(0),
      errors_(0),
      line_len_(0),
      overflow_(false),
      n_tokens_(0),
      seq_(0),
      reply_len_(0) {
  if (watchdog_ms_ < kMinWatchdogMs) watchdog_ms_ = kMinWatchdogMs;
  if (watchdog_ms_ > kMaxWatchdogMs) watchdog_ms_ = kMaxWatchdogMs;
  int32_t speed = config.default_speed;
  if (speed < 1) speed = 1;
  if (speed > kMaxSpeed) speed = kMaxSpeed;
  for (uint8_t a = 0; a < kMaxAxes; ++a) {
    Axis& ax = axes_[a];
    ax.raw = 0;
    ax.offset = 0;
    ax.target = 0;
    // Power-up limits [0, 0]: nothing moves until the host sets limits.
    ax.lo = 0;
    ax.hi = 0;
    ax.speed = speed;
    ax.enabled = false;
    ax.last_raw = 0;
    ax.still_since_ms = 0;
    ax.settled = false;
  }
  for (int r = 0; r < 3; ++r) stops_[r] = 0;
  line_[0] = '\0';
  reply_[0] = '\0';
}

// ---------------------------------------------------------------- axes --

void ProtocolCore::set_position(uint8_t axis, int32_t raw_ticks) {
  if (axis < n_axes_) axes_[axis].raw = raw_ticks;
}

int32_t ProtocolCore::position(uint8_t axis) const {
  if (axis >= n_axes_) return 0;
  // Wrapping unsigned arithmetic: defined behaviour for any raw/offset.
  return static_cast<int32_t>(static_cast<uint32_t>(axes_[axis].raw) -
                              static_cast<uint32_t>(axes_[axis].offset));
}

int32_t ProtocolCore::setpoint_raw(uint8_t axis) const {
  if (axis >= n_axes_) return 0;
  return static_cast<int32_t>(static_cast<uint32_t>(axes_[axis].target) +
                              static_cast<uint32_t>(axes_[axis].offset));
}

int32_t ProtocolCore::target(uint8_t axis) const { return axis < n_axes_ ? axes_[axis].target : 0; }
int32_t ProtocolCore::offset(uint8_t axis) const { return axis < n_axes_ ? axes_[axis].offset : 0; }
int32_t ProtocolCore::limit_lo(uint8_t axis) const { return axis < n_axes_ ? axes_[axis].lo : 0; }
int32_t ProtocolCore::limit_hi(uint8_t axis) const { return axis < n_axes_ ? axes_[axis].hi : 0; }
bool ProtocolCore::enabled(uint8_t axis) const { return axis < n_axes_ && axes_[axis].enabled; }
int32_t ProtocolCore::speed_limit(uint8_t axis) const { return axis < n_axes_ ? axes_[axis].speed : 0; }

bool ProtocolCore::within_deadband(uint8_t axis) const {
  int32_t err = static_cast<int32_t>(static_cast<uint32_t>(axes_[axis].target) -
                                     static_cast<uint32_t>(position(axis)));
  return abs32(err) <= config_.deadband;
}

bool ProtocolCore::moving(uint8_t axis) const {
  if (axis >= n_axes_ || !axes_[axis].enabled) return false;
  // Outside the deadband is always moving (also between update() calls),
  // so the watchdog covers every driven axis that has not arrived.
  return !(axes_[axis].settled && within_deadband(axis));
}

void ProtocolCore::arm(uint8_t axis) {
  axes_[axis].enabled = true;
  axes_[axis].settled = false;
}

bool ProtocolCore::any_moving() const {
  for (uint8_t a = 0; a < n_axes_; ++a)
    if (moving(a)) return true;
  return false;
}

void ProtocolCore::stop_all(StopReason reason) {
  for (uint8_t a = 0; a < n_axes_; ++a) {
    axes_[a].target = position(a);
    axes_[a].enabled = false;
  }
  ++stops_[reason];
}

void ProtocolCore::update(uint32_t now_ms) {
  for (uint8_t a = 0; a < n_axes_; ++a) {
    Axis& ax = axes_[a];
    if (ax.raw != ax.last_raw) {
      ax.last_raw = ax.raw;
      ax.still_since_ms = now_ms;
    }
    if (!within_deadband(a))
      ax.settled = false;
    else if (ax.enabled && static_cast<uint32_t>(now_ms - ax.still_since_ms) >= config_.settle_ms)
      ax.settled = true;
  }
  // Unsigned difference: correct across the 49-day millis() wrap.
  if (any_moving() && static_cast<uint32_t>(now_ms - last_rx_ms_) > watchdog_ms_)
    stop_all(STOP_WATCHDOG);
}

// ------------------------------------------------------------- framing --

const char* ProtocolCore::feed(uint8_t byte, uint32_t now_ms) {
  if (byte != '\n' && byte != '\r') {
    if (line_len_ < kMaxLine)
      line_[line_len_++] = static_cast<char>(byte);
    else
      overflow_ = true;
    return 0;
  }
  // End of a line ("\r\n" ends one line and leaves an empty one, ignored).
  const size_t len = line_len_;
  const bool overflow = overflow_;
  line_[len] = '\0';
  line_len_ = 0;
  overflow_ = false;
  bool blank = !overflow;
  for (size_t i = 0; i < len && blank; ++i)
    if (!is_space(line_[i])) blank = false;
  if (blank) return 0;

  last_rx_ms_ = now_ms;
  ++lines_;
  if (overflow) return reply_too_long();
  // A NUL byte inside the line would hide the rest from the C string
  // functions below: check every byte against the stored length.
  for (size_t i = 0; i < len; ++i) {
    const unsigned char c = static_cast<unsigned char>(line_[i]);
    if (!(c == '\t' || (c >= 0x20 && c <= 0x7e))) return error_noseq(E_MALFORMED, "malformed line");
  }
  return handle_line();
}

const char* ProtocolCore::reply_too_long() {
  // Echo the sequence number if the kept prefix starts with a valid one.
  size_t i = 0;
  while (i < kMaxLine && is_space(line_[i])) ++i;
  size_t j = i;
  while (j < kMaxLine && is_digit(line_[j])) ++j;
  if (j > i && j < kMaxLine && is_space(line_[j])) {
    line_[j] = '\0';
    if (parse_seq(line_ + i, &seq_)) return error(E_TOO_LONG, "line too long");
  }
  return error_noseq(E_TOO_LONG, "line too long");
}

const char* ProtocolCore::handle_line() {
  // Split in place on spaces and tabs.
  n_tokens_ = 0;
  bool too_many = false;
  char* p = line_;
  while (*p != '\0') {
    while (is_space(*p)) *p++ = '\0';
    if (*p == '\0') break;
    if (n_tokens_ < kMaxTokens)
      tokens_[n_tokens_++] = p;
    else
      too_many = true;
    while (*p != '\0' && !is_space(*p)) ++p;
  }
  if (n_tokens_ == 0 || !parse_seq(tokens_[0], &seq_)) return error_noseq(E_MALFORMED, "bad sequence number");
  if (n_tokens_ < 2) return error(E_MALFORMED, "missing command");
  if (too_many) return error(E_BAD_ARGUMENT, "too many arguments");

  // Command words are case-insensitive: compare in upper case.
  char* cmd = const_cast<char*>(tokens_[1]);
  for (char* c = cmd; *c != '\0'; ++c)
    if (*c >= 'a' && *c <= 'z') *c = static_cast<char>(*c - 'a' + 'A');
  const uint8_t nargs = static_cast<uint8_t>(n_tokens_ - 2);

  if (strcmp(cmd, "ID") == 0) return cmd_id(nargs);
  if (strcmp(cmd, "PING") == 0) return cmd_ping(nargs);
  if (strcmp(cmd, "GET") == 0) return cmd_get(nargs);
  if (strcmp(cmd, "SET") == 0) return cmd_set(nargs);
  if (strcmp(cmd, "SETALL") == 0) return cmd_setall(nargs);
  if (strcmp(cmd, "STOP") == 0) return cmd_stop(nargs);
  if (strcmp(cmd, "ZERO") == 0) return cmd_zero(nargs);
  if (strcmp(cmd, "LIMIT") == 0) return cmd_limit(nargs);
  if (strcmp(cmd, "SPEED") == 0) return cmd_speed(nargs);
  if (strcmp(cmd, "WDOG") == 0) return cmd_wdog(nargs);
  return error(E_UNKNOWN_COMMAND, "unknown command");
}

int ProtocolCore::parse_axis(const char* token, uint8_t* axis) const {
  int32_t v;
  // Plain digits only: "+1" and "-0" are not axis numbers.
  if (!is_digit(token[0]) || !parse_int(token, 999, &v)) return E_BAD_ARGUMENT;
  if (v >= n_axes_) return E_BAD_AXIS;
  *axis = static_cast<uint8_t>(v);
  return 0;
}

// ------------------------------------------------------------ commands --

const char* ProtocolCore::cmd_id(uint8_t nargs) {
  if (nargs != 0) return error(E_BAD_ARGUMENT, "expected no arguments");
  begin_ok();
  put(" board=");
  put(config_.board_name);
  put(" fw=");
  put(config_.firmware_version);
  put(" proto=");
  put_uint(kProtocolVersion);
  put(" winches=");
  put_uint(n_axes_);
  return finish();
}

const char* ProtocolCore::cmd_ping(uint8_t nargs) {
  if (nargs != 0) return error(E_BAD_ARGUMENT, "expected no arguments");
  begin_ok();
  return finish();
}

const char* ProtocolCore::cmd_get(uint8_t nargs) {
  if (nargs != 0) return error(E_BAD_ARGUMENT, "expected no arguments");
  begin_ok();
  put(" pos=");
  for (uint8_t a = 0; a < n_axes_; ++a) {
    if (a) put_char(',');
    put_int(position(a));
  }
  put(" tgt=");
  for (uint8_t a = 0; a < n_axes_; ++a) {
    if (a) put_char(',');
    put_int(axes_[a].target);
  }
  put(" mov=");
  for (uint8_t a = 0; a < n_axes_; ++a) {
    if (a) put_char(',');
    put_char(moving(a) ? '1' : '0');
  }
  put(" en=");
  for (uint8_t a = 0; a < n_axes_; ++a) {
    if (a) put_char(',');
    put_char(axes_[a].enabled ? '1' : '0');
  }
  put(" wd=");
  put_uint(stops_[STOP_WATCHDOG]);
  return finish();
}

const char* ProtocolCore::cmd_set(uint8_t nargs) {
  if (nargs != 2) return error(E_BAD_ARGUMENT, "expected axis and target");
  uint8_t axis;
  int rc = parse_axis(tokens_[2], &axis);
  if (rc == E_BAD_AXIS) return error(rc, "no such axis");
  if (rc) return error(rc, "bad axis");
  int32_t t;
  if (!parse_int(tokens_[3], kMaxTicks, &t)) return error(E_BAD_ARGUMENT, "bad target");
  Axis& ax = axes_[axis];
  if (t < ax.lo || t > ax.hi) return error(E_OUT_OF_LIMITS, "target outside limits");
  ax.target = t;
  arm(axis);
  begin_ok();
  return finish();
}

const char* ProtocolCore::cmd_setall(uint8_t nargs) {
  if (nargs != n_axes_) return error(E_BAD_ARGUMENT, "expected one target per axis");
  int32_t t[kMaxAxes];
  bool keep[kMaxAxes];
  // Validate everything first: a refused SETALL changes nothing.
  for (uint8_t a = 0; a < n_axes_; ++a) {
    const char* tok = tokens_[2 + a];
    keep[a] = (tok[0] == '-' && tok[1] == '\0');
    if (keep[a]) continue;
    if (!parse_int(tok, kMaxTicks, &t[a])) return error(E_BAD_ARGUMENT, "bad target");
    if (t[a] < axes_[a].lo || t[a] > axes_[a].hi) return error(E_OUT_OF_LIMITS, "target outside limits");
  }
  for (uint8_t a = 0; a < n_axes_; ++a) {
    if (keep[a]) continue;
    axes_[a].target = t[a];
    arm(a);
  }
  begin_ok();
  return finish();
}

const char* ProtocolCore::cmd_stop(uint8_t nargs) {
  if (nargs != 0) return error(E_BAD_ARGUMENT, "expected no arguments");
  stop_all(STOP_COMMAND);
  begin_ok();
  return finish();
}

const char* ProtocolCore::cmd_zero(uint8_t nargs) {
  if (nargs > 1) return error(E_BAD_ARGUMENT, "expected at most one axis");
  uint8_t first = 0, last = static_cast<uint8_t>(n_axes_ - 1);
  if (nargs == 1) {
    int rc = parse_axis(tokens_[2], &first);
    if (rc == E_BAD_AXIS) return error(rc, "no such axis");
    if (rc) return error(rc, "bad axis");
    last = first;
  }
  for (uint8_t a = first; a <= last; ++a)
    if (moving(a)) return error(E_BUSY, "axis is moving");
  for (uint8_t a = first; a <= last; ++a) {
    axes_[a].offset = axes_[a].raw;
    axes_[a].target = 0;
    axes_[a].enabled = false;
  }
  begin_ok();
  return finish();
}

const char* ProtocolCore::cmd_limit(uint8_t nargs) {
  if (nargs != 1 && nargs != 3) return error(E_BAD_ARGUMENT, "expected axis [lo hi]");
  uint8_t axis;
  int rc = parse_axis(tokens_[2], &axis);
  if (rc == E_BAD_AXIS) return error(rc, "no such axis");
  if (rc) return error(rc, "bad axis");
  Axis& ax = axes_[axis];
  if (nargs == 3) {
    int32_t lo, hi;
    if (!parse_int(tokens_[3], kMaxTicks, &lo) || !parse_int(tokens_[4], kMaxTicks, &hi) || lo > hi)
      return error(E_BAD_ARGUMENT, "bad limits");
    if (moving(axis)) return error(E_BUSY, "axis is moving");
    if (ax.enabled && (ax.target < lo || ax.target > hi)) return error(E_CONFLICT, "target outside new limits");
    ax.lo = lo;
    ax.hi = hi;
  }
  begin_ok();
  put(" lo=");
  put_int(ax.lo);
  put(" hi=");
  put_int(ax.hi);
  return finish();
}

const char* ProtocolCore::cmd_speed(uint8_t nargs) {
  if (nargs != 1 && nargs != 2) return error(E_BAD_ARGUMENT, "expected axis [ticks_per_s]");
  uint8_t axis;
  int rc = parse_axis(tokens_[2], &axis);
  if (rc == E_BAD_AXIS) return error(rc, "no such axis");
  if (rc) return error(rc, "bad axis");
  if (nargs == 2) {
    int32_t v;
    if (!parse_int(tokens_[3], kMaxSpeed, &v) || v < 1) return error(E_BAD_ARGUMENT, "bad speed");
    axes_[axis].speed = v;
  }
  begin_ok();
  put(" speed=");
  put_int(axes_[axis].speed);
  return finish();
}

const char* ProtocolCore::cmd_wdog(uint8_t nargs) {
  if (nargs > 1) return error(E_BAD_ARGUMENT, "expected at most one value");
  if (nargs == 1) {
    int32_t v;
    if (!parse_int(tokens_[2], static_cast<int32_t>(kMaxWatchdogMs), &v) ||
        v < static_cast<int32_t>(kMinWatchdogMs))
      return error(E_BAD_ARGUMENT, "bad timeout");
    watchdog_ms_ = static_cast<uint32_t>(v);
  }
  begin_ok();
  put(" ms=");
  put_uint(watchdog_ms_);
  return finish();
}

// --------------------------------------------------------------- reply --

void ProtocolCore::put(const char* s) {
  while (*s != '\0') put_char(*s++);
}

void ProtocolCore::put_char(char c) {
  // Keep room for "\n" and the terminating NUL; the fixed sizes make
  // truncation impossible in practice, this only keeps it memory-safe.
  if (reply_len_ + 2 < kReplySize) reply_[reply_len_++] = c;
}

void ProtocolCore::put_uint(uint32_t v) {
  char digits[10];
  int n = 0;
  do {
    digits[n++] = static_cast<char>('0' + v % 10);
    v /= 10;
  } while (v != 0);
  while (n > 0) put_char(digits[--n]);
}

void ProtocolCore::put_int(int32_t v) {
  if (v < 0) {
    put_char('-');
    put_uint(static_cast<uint32_t>(0) - static_cast<uint32_t>(v));
  } else {
    put_uint(static_cast<uint32_t>(v));
  }
}

void ProtocolCore::begin_ok() {
  reply_len_ = 0;
  put_uint(seq_);
  put(" OK");
}

const char* ProtocolCore::finish() {
  reply_[reply_len_++] = '\n';
  reply_[reply_len_] = '\0';
  return reply_;
}

const char* ProtocolCore::error(int code, const char* message) {
  ++errors_;
  reply_len_ = 0;
  put_uint(seq_);
  put(" ERR ");
  put_uint(static_cast<uint32_t>(code));
  put_char(' ');
  put(message);
  return finish();
}

const char* ProtocolCore::error_noseq(int code, const char* message) {
  ++errors_;
  reply_len_ = 0;
  put("* ERR ");
  put_uint(static_cast<uint32_t>(code));
  put_char(' ');
  put(message);
  return finish();
}

// ------------------------------------------------------------ motion --

namespace {

// b - a, saturated to the int32 range (each of them may be anywhere in it).
int32_t diff_sat(int32_t b, int32_t a) {
  const int64_t d = static_cast<int64_t>(b) - static_cast<int64_t>(a);
  if (d > 2147483647LL) return 2147483647L;
  if (d < -2147483647LL) return -2147483647L;
  return static_cast<int32_t>(d);
}

int32_t wrap_diff(int32_t b, int32_t a) {
  return static_cast<int32_t>(static_cast<uint32_t>(b) - static_cast<uint32_t>(a));
}

int32_t min32(int32_t a, int32_t b) { return a < b ? a : b; }

}  // namespace

AxisControl::AxisControl()
    : ref_(0), ref_frac_(0.0f), integral_(0.0f), prev_err_(0.0f), prev_raw_(0), speed_(0.0f), active_(false) {}

Drive AxisControl::step(const ProtocolCore& core, uint8_t axis, int32_t raw, float dt) {
  Drive out = {true, 0};
  if (!core.enabled(axis)) {
    active_ = false;
    return out;
  }
  if (!(dt > 0.0f)) dt = 1e-3f;  // a clock that did not advance: any small step will do
  if (!active_) {  // start the reference where the motor is: no jump
    ref_ = raw;
    ref_frac_ = 0.0f;
    integral_ = 0.0f;
    prev_err_ = 0.0f;
    prev_raw_ = raw;
    speed_ = 0.0f;
    active_ = true;
  }
  // Speed limit: the reference walks towards the setpoint at most at
  // speed_limit ticks/s; the PID tracks the reference. Differences of raw
  // counts are taken in integers, so they are exact at any count.
  const int32_t goal = core.setpoint_raw(axis);
  ref_frac_ += static_cast<float>(core.speed_limit(axis)) * dt;
  const int32_t step = static_cast<int32_t>(ref_frac_);
  ref_frac_ -= static_cast<float>(step);
  const int32_t to_go = wrap_diff(goal, ref_);
  if (to_go > step)
    ref_ += step;
  else if (to_go < -step)
    ref_ -= step;
  else
    ref_ = goal;

  const int32_t moved = wrap_diff(raw, prev_raw_);
  prev_raw_ = raw;
  speed_ += (static_cast<float>(moved) / dt - speed_) * (dt / (control::kSpeedFilter + dt));
  const int16_t pwm = pid(goal, raw, core.deadband(), dt);
  if (guard(core, axis, raw, moved, pwm, dt)) return out;
  out.brake = false;
  out.pwm = pwm;
  return out;
}

int16_t AxisControl::pid(int32_t goal, int32_t raw, int32_t deadband, float dt) {
  const float err = static_cast<float>(wrap_diff(ref_, raw));
  // Within the deadband the full PID stops. The core calls an axis not
  // moving only inside it (|target - position| <= deadband, and at rest),
  // so an axis the watchdog ignores is never driven by the full PID.
  if (ref_ == goal && err >= static_cast<float>(-deadband) && err <= static_cast<float>(deadband)) {
    // Arrived: hold with the integral only, no dithering around zero (the
    // guard brakes instead if that would push past the target).
    prev_err_ = err;
    return static_cast<int16_t>(integral_);
  }
  // Integrate only against a load: once the reference has stopped and the
  // motor stands (nearly) still short of it. The lag behind a walking
  // reference, or a motor still closing in on its target, is not a load.
  if (ref_ == goal && speed_ < control::kStillSpeed && speed_ > -control::kStillSpeed) {
    integral_ += control::kKi * err * dt;
    if (integral_ > control::kIntegralLimit) integral_ = control::kIntegralLimit;
    if (integral_ < -control::kIntegralLimit) integral_ = -control::kIntegralLimit;
  }
  const float deriv = (err - prev_err_) / dt;
  prev_err_ = err;
  float u = control::kKp * err + integral_ + control::kKd * deriv;
  if (u > control::kPwmMax) u = control::kPwmMax;
  if (u < -control::kPwmMax) u = -control::kPwmMax;
  int16_t pwm = static_cast<int16_t>(u);
  if (pwm > 0 && pwm < control::kPwmMin) pwm = control::kPwmMin;
  if (pwm < 0 && pwm > -control::kPwmMin) pwm = static_cast<int16_t>(-control::kPwmMin);
  return pwm;
}

bool AxisControl::guard(const ProtocolCore& core, uint8_t axis, int32_t raw, int32_t moved, int16_t pwm,
                        float dt) const {
  // In the host's (zeroed) ticks, as the target and the limits are.
  const int32_t pos = wrap_diff(raw, core.offset(axis));
  const int32_t to_target = diff_sat(core.target(axis), pos);
  // Room ahead, each way: up to the soft limit, and up to the target if it
  // lies that way (none if it lies the other way: moving away from the
  // target, the motor is stopped first, then driven back).
  const int32_t room_up = min32(diff_sat(core.limit_hi(axis), pos), to_target > 0 ? to_target : 0);
  const int32_t room_down = min32(diff_sat(pos, core.limit_lo(axis)), to_target < 0 ? -to_target : 0);
  // Ticks the motor may still travel before a brake holds it: kStopTime
  // at its speed. Several ticks in the last cycle give the speed at once;
  // below that (one tick at most per cycle) the low-passed speed is the
  // better measure, and the motor stops on the target itself.
  const int32_t ticks = moved < 0 ? -moved : moved;
  float speed = speed_ < 0.0f ? -speed_ : speed_;
  if (ticks >= 2 && static_cast<float>(ticks) / dt > speed) speed = static_cast<float>(ticks) / dt;
  const float coast = speed * control::kStopTime;
  if (moved > 0 && static_cast<float>(room_up) <= coast) return true;
  if (moved < 0 && static_cast<float>(room_down) <= coast) return true;
  // Never drive towards a target it stands on or past, nor past a soft limit.
  if (pwm > 0 && room_up <= 0) return true;
  if (pwm < 0 && room_down <= 0) return true;
  return false;
}

}  // namespace plush
