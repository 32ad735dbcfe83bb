// plush-board-emu: a winch board on a pseudo-terminal.
//
// Serves the protocol of hw/PROTOCOL.md with the firmware's own
// protocol_core.cpp, drives every motor with the firmware's own control
// law (plush::AxisControl, every 2 ms as on the board) and simulates the
// motors as hw/simavr does: a first-order DC motor (top speed at full PWM,
// time constant, dead zone, instant short brake). The first line on stdout
// is the path of the pseudo-terminal to open (e.g. /dev/pts/7); see --help.
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <string>

#include "../firmware/plush_winch/protocol_core.h"

namespace {

const char kVersion[] = "1.1.0";

volatile sig_atomic_t g_stop = 0;

void on_signal(int) { g_stop = 1; }

// SIGUSR1 closes the window of position extremes (tests measure one move's overshoot).
volatile sig_atomic_t g_window_request = 0;

void on_window(int) { g_window_request = 1; }

struct Options {
  int winches = 4;
  double speed = 3000.0;   // motor speed at full PWM, ticks/s
  double tau = 0.05;       // mechanical time constant of the motor, s
  double deadzone = 0.06;  // PWM fraction below which the motor does not turn
  double step_ms = 1.0;    // simulation step
  long watchdog_ms = 1000;
  long deadband = 1;
  long settle_ms = 50;     // the firmware's: at rest this long within the deadband = arrived
  const char* state_file = nullptr;
  long state_interval_ms = 20;
  const char* link = nullptr;
  bool verbose = false;
};

void usage(FILE* out) {
  fprintf(out,
          "usage: plush-board-emu [options]\n"
          "\n"
          "Emulates a plush winch board (hw/PROTOCOL.md) on a pseudo-terminal.\n"
          "Prints the terminal's path on the first line of stdout, then serves\n"
          "the protocol until SIGTERM or SIGINT. SIGUSR1 closes the window of\n"
          "position extremes in the state file.\n"
          "\n"
          "  --winches N          number of winches, 1..%d (default 4)\n"
          "  --speed TICKS_PER_S  motor speed at full PWM (default 3000)\n"
          "  --tau SECONDS        motor time constant (default 0.05)\n"
          "  --deadzone FRACTION  PWM fraction that does not turn the motor (default 0.06:\n"
          "                       the firmware's smallest PWM, 25/255, just turns it)\n"
          "  --step-ms MS         simulation step (default 1)\n"
          "  --watchdog MS        watchdog timeout at power-up (default 1000)\n"
          "  --deadband TICKS     position error that counts as arrived (default 1)\n"
          "  --settle-ms MS       ... once the position has not changed for this long (default 50)\n"
          "  --state-file PATH    write the true state as JSON to PATH (atomically)\n"
          "  --state-interval MS  how often to write it (default 20)\n"
          "  --link PATH          also make PATH a symlink to the terminal\n"
          "  --verbose            log every line in and out on stderr\n"
          "  --version, --help\n",
          static_cast<int>(plush::kMaxAxes));
}

bool parse_double(const char* s, double lo, double hi, double* out) {
  char* end = nullptr;
  errno = 0;
  double v = strtod(s, &end);
  if (errno != 0 || end == s || *end != '\0' || !(v >= lo && v <= hi)) return false;
  *out = v;
  return true;
}

bool parse_long(const char* s, long lo, long hi, long* out) {
  char* end = nullptr;
  errno = 0;
  long v = strtol(s, &end, 10);
  if (errno != 0 || end == s || *end != '\0' || v < lo || v > hi) return false;
  *out = v;
  return true;
}

// Returns 0 to run, or the exit status.
int parse_args(int argc, char** argv, Options* o) {
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      usage(stdout);
      return -1;
    }
    if (a == "--version") {
      printf("plush-board-emu %s (protocol %d)\n", kVersion, static_cast<int>(plush::kProtocolVersion));
      return -1;
    }
    if (a == "--verbose") {
      o->verbose = true;
      continue;
    }
    if (i + 1 >= argc) {
      fprintf(stderr, "plush-board-emu: %s needs a value (see --help)\n", a.c_str());
      return 2;
    }
    const char* v = argv[++i];
    long l = 0;
    bool ok = true;
    if (a == "--winches") {
      ok = parse_long(v, 1, plush::kMaxAxes, &l);
      o->winches = static_cast<int>(l);
    } else if (a == "--speed") {
      ok = parse_double(v, 1e-3, 1e7, &o->speed);
    } else if (a == "--tau") {
      ok = parse_double(v, 0.0, 100.0, &o->tau);
    } else if (a == "--deadzone") {
      ok = parse_double(v, 0.0, 0.9, &o->deadzone);
    } else if (a == "--step-ms") {
      ok = parse_double(v, 0.1, 100.0, &o->step_ms);
    } else if (a == "--watchdog") {
      ok = parse_long(v, plush::kMinWatchdogMs, plush::kMaxWatchdogMs, &o->watchdog_ms);
    } else if (a == "--deadband") {
      ok = parse_long(v, 0, 1000000, &o->deadband);
    } else if (a == "--settle-ms") {
      ok = parse_long(v, 0, 60000, &o->settle_ms);
    } else if (a == "--state-file") {
      o->state_file = v;
    } else if (a == "--state-interval") {
      ok = parse_long(v, 1, 60000, &o->state_interval_ms);
    } else if (a == "--link") {
      o->link = v;
    } else {
      fprintf(stderr, "plush-board-emu: unknown option %s (see --help)\n", a.c_str());
      return 2;
    }
    if (!ok) {
      fprintf(stderr, "plush-board-emu: bad value for %s: %s (see --help)\n", a.c_str(), v);
      return 2;
    }
  }
  return 0;
}

double now_s() {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// Replies wait here until the terminal takes them. Only whole replies are
// queued or dropped, so the host never reads half a line followed by the
// next reply.
struct Outbox {
  static const size_t kMaxPending = 4096;  // about one terminal buffer of replies not yet read
  std::string pending;
  unsigned long dropped = 0;  // whole replies lost

  void queue(const char* reply, size_t n) {
    if (pending.size() + n > kMaxPending) {
      ++dropped;  // the host does not read its replies: a board would lose them too
      return;
    }
    pending.append(reply, n);
  }

  void flush(int fd) {
    while (!pending.empty()) {
      ssize_t w = write(fd, pending.data(), pending.size());
      if (w > 0) {
        pending.erase(0, static_cast<size_t>(w));
      } else if (w < 0 && errno == EINTR) {
        continue;
      } else {
        if (w < 0 && errno == EIO) {  // nobody has the port open: the replies go nowhere
          for (char c : pending) dropped += (c == '\n');
          pending.clear();
        }
        return;  // EAGAIN: the rest goes out when the host reads
      }
    }
  }
};

const double kControlPeriod = 0.002;  // s: the firmware's control cycle (plush_winch.ino)
const double kMotorStep = 50e-6;      // s: motor integration step, as hw/simavr's

struct Sim {
  double x[plush::kMaxAxes] = {};       // true position, raw ticks
  double v[plush::kMaxAxes] = {};       // speed, ticks/s
  plush::Drive drive[plush::kMaxAxes] = {};  // what the control law last asked of each motor
  plush::AxisControl control[plush::kMaxAxes];
  double t = 0.0;                       // simulated time, s since start
  double next_control = 0.0;
  long min_ticks[plush::kMaxAxes] = {};  // extremes of the reported position
  long max_ticks[plush::kMaxAxes] = {};
  long window_min[plush::kMaxAxes] = {};  // extremes since the last window was closed (SIGUSR1)
  long window_max[plush::kMaxAxes] = {};
  long closed_min[plush::kMaxAxes] = {};  // ... of the window closed last
  long closed_max[plush::kMaxAxes] = {};
  unsigned long windows = 0;              // windows closed

  void track(int a, long pos) {
    if (pos < min_ticks[a]) min_ticks[a] = pos;
    if (pos > max_ticks[a]) max_ticks[a] = pos;
    if (pos < window_min[a]) window_min[a] = pos;
    if (pos > window_max[a]) window_max[a] = pos;
  }

  void close_window(const plush::ProtocolCore& core, int winches) {
    for (int a = 0; a < winches; ++a) {
      closed_min[a] = window_min[a];
      closed_max[a] = window_max[a];
      window_min[a] = window_max[a] = core.position(static_cast<uint8_t>(a));
    }
    ++windows;
  }
};

// One motor step of kMotorStep: a first-order DC motor (hw/simavr/board_sim.c's).
void motor_step(const Options& o, Sim* sim, int a) {
  const plush::Drive& d = sim->drive[a];
  if (d.brake) {
    sim->v[a] = 0.0;  // short brake through a high-ratio gearbox: stops at once, holds
    return;
  }
  const double duty = d.pwm / 255.0;
  double goal = 0.0;  // speed the drive sustains
  if (fabs(duty) > o.deadzone) goal = copysign((fabs(duty) - o.deadzone) / (1.0 - o.deadzone), duty) * o.speed;
  const double relax = o.tau > 0 ? 1.0 - exp(-kMotorStep / o.tau) : 1.0;
  sim->v[a] += (goal - sim->v[a]) * relax;
  sim->x[a] += sim->v[a] * kMotorStep;
}

// Advance the motors by dt s, running the firmware's control cycle every
// kControlPeriod as the board does (positions in, watchdog, drive out).
void advance(const Options& o, plush::ProtocolCore& core, Sim* sim, double dt, uint32_t now_ms) {
  const double end = sim->t + dt;
  while (sim->t < end) {
    if (sim->t >= sim->next_control) {
      sim->next_control += kControlPeriod;
      if (sim->next_control <= sim->t) sim->next_control = sim->t + kControlPeriod;
      for (uint8_t a = 0; a < o.winches; ++a) core.set_position(a, static_cast<int32_t>(lround(sim->x[a])));
      core.update(now_ms);
      for (uint8_t a = 0; a < o.winches; ++a)
        sim->drive[a] = sim->control[a].step(core, a, static_cast<int32_t>(lround(sim->x[a])),
                                              static_cast<float>(kControlPeriod));
    }
    for (int a = 0; a < o.winches; ++a) motor_step(o, sim, a);
    sim->t += kMotorStep;
    for (uint8_t a = 0; a < o.winches; ++a) {
      core.set_position(a, static_cast<int32_t>(lround(sim->x[a])));
      sim->track(a, core.position(a));
    }
  }
  core.update(now_ms);
}

void write_state(const Options& o, const plush::ProtocolCore& core, const Sim& sim, double t, bool connected,
                 unsigned long dropped) {
  if (!o.state_file) return;
  std::string s = "{";
  char buf[64];
  auto num = [&](double v) {
    snprintf(buf, sizeof buf, "%.3f", v);
    s += buf;
  };
  auto integer = [&](long v) {
    snprintf(buf, sizeof buf, "%ld", v);
    s += buf;
  };
  auto list = [&](const char* key, auto value) {
    s += "\"";
    s += key;
    s += "\": [";
    for (int a = 0; a < o.winches; ++a) {
      if (a) s += ", ";
      value(static_cast<uint8_t>(a));
    }
    s += "], ";
  };
  s += "\"time\": ";
  num(t);
  s += ", \"winches\": ";
  integer(o.winches);
  s += ", \"connected\": ";
  s += connected ? "true" : "false";
  s += ", ";
  list("position", [&](uint8_t a) { num(sim.x[a] - core.offset(a)); });
  list("ticks", [&](uint8_t a) { integer(core.position(a)); });
  list("target", [&](uint8_t a) { integer(core.target(a)); });
  list("enabled", [&](uint8_t a) { s += core.enabled(a) ? "true" : "false"; });
  list("moving", [&](uint8_t a) { s += core.moving(a) ? "true" : "false"; });
  list("limit_lo", [&](uint8_t a) { integer(core.limit_lo(a)); });
  list("limit_hi", [&](uint8_t a) { integer(core.limit_hi(a)); });
  list("speed", [&](uint8_t a) { integer(core.speed_limit(a)); });
  list("min_ticks", [&](uint8_t a) { integer(sim.min_ticks[a]); });
  list("max_ticks", [&](uint8_t a) { integer(sim.max_ticks[a]); });
  list("drive", [&](uint8_t a) { num(sim.drive[a].brake ? 0.0 : sim.drive[a].pwm / 255.0); });
  list("window_min", [&](uint8_t a) { integer(sim.window_min[a]); });
  list("window_max", [&](uint8_t a) { integer(sim.window_max[a]); });
  list("closed_min", [&](uint8_t a) { integer(sim.closed_min[a]); });
  list("closed_max", [&](uint8_t a) { integer(sim.closed_max[a]); });
  s += "\"windows\": ";
  integer(static_cast<long>(sim.windows));
  s += ", ";
  s += "\"watchdog_ms\": ";
  integer(static_cast<long>(core.watchdog_ms()));
  s += ", \"stops\": {\"command\": ";
  integer(static_cast<long>(core.stop_count(plush::STOP_COMMAND)));
  s += ", \"watchdog\": ";
  integer(static_cast<long>(core.stop_count(plush::STOP_WATCHDOG)));
  s += ", \"hangup\": ";
  integer(static_cast<long>(core.stop_count(plush::STOP_HANGUP)));
  s += "}, \"lines\": ";
  integer(static_cast<long>(core.lines()));
  s += ", \"errors\": ";
  integer(static_cast<long>(core.errors()));
  s += ", \"dropped_replies\": ";
  integer(static_cast<long>(dropped));
  s += "}\n";

  // Write a sibling file and rename it: readers never see half a state.
  std::string tmp = std::string(o.state_file) + ".tmp";
  FILE* f = fopen(tmp.c_str(), "w");
  if (!f) return;
  bool ok = fwrite(s.data(), 1, s.size(), f) == s.size();
  ok = (fclose(f) == 0) && ok;
  if (ok) rename(tmp.c_str(), o.state_file);
}

void log_line(const Options& o, const char* dir, const char* s, size_t n) {
  if (!o.verbose) return;
  fprintf(stderr, "%s ", dir);
  for (size_t i = 0; i < n; ++i) {
    unsigned char c = static_cast<unsigned char>(s[i]);
    if (c == '\n') continue;
    if (c >= 0x20 && c < 0x7f)
      fputc(c, stderr);
    else
      fprintf(stderr, "\\x%02x", c);
  }
  fputc('\n', stderr);
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  int rc = parse_args(argc, argv, &o);
  if (rc != 0) return rc < 0 ? 0 : rc;

  int master = posix_openpt(O_RDWR | O_NOCTTY);
  if (master < 0 || grantpt(master) != 0 || unlockpt(master) != 0) {
    fprintf(stderr, "plush-board-emu: cannot create a pseudo-terminal: %s\n", strerror(errno));
    return 1;
  }
  const char* slave = ptsname(master);
  if (!slave) {
    fprintf(stderr, "plush-board-emu: ptsname failed: %s\n", strerror(errno));
    return 1;
  }
  std::string slave_path = slave;
  fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
  // Raw mode for the pair until the host configures it: no echo, no
  // newline translation.
  struct termios tio;
  if (tcgetattr(master, &tio) == 0) {
    cfmakeraw(&tio);
    tcsetattr(master, TCSANOW, &tio);
  }
  if (o.link) {
    unlink(o.link);
    if (symlink(slave_path.c_str(), o.link) != 0) {
      fprintf(stderr, "plush-board-emu: cannot create link %s: %s\n", o.link, strerror(errno));
      return 1;
    }
  }

  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGTERM, &sa, nullptr);
  sigaction(SIGINT, &sa, nullptr);
  sa.sa_handler = on_window;
  sigaction(SIGUSR1, &sa, nullptr);
  signal(SIGPIPE, SIG_IGN);
  signal(SIGHUP, SIG_IGN);

  printf("%s\n", slave_path.c_str());
  fflush(stdout);

  plush::CoreConfig cfg;
  cfg.board_name = "plush-winch-emu";
  cfg.firmware_version = kVersion;
  cfg.n_axes = static_cast<uint8_t>(o.winches);
  cfg.deadband = static_cast<int32_t>(o.deadband);
  cfg.settle_ms = static_cast<uint32_t>(o.settle_ms);
  cfg.watchdog_ms = static_cast<uint32_t>(o.watchdog_ms);
  cfg.default_speed = static_cast<int32_t>(o.speed < plush::kMaxSpeed ? o.speed : plush::kMaxSpeed);
  plush::ProtocolCore core(cfg);
  Sim sim;

  const double t0 = now_s();
  double t_last = t0;
  double t_state = -1.0;
  bool connected = false;  // a host has the terminal open
  Outbox outbox;
  char line_in[512];
  size_t line_in_len = 0;

  if (o.verbose)
    fprintf(stderr, "plush-board-emu: %d winches on %s (speed %.0f ticks/s, tau %.3f s)\n", o.winches,
            slave_path.c_str(), o.speed, o.tau);

  while (!g_stop) {
    // Without a host the master reports POLLHUP at once: then sleep instead
    // of spinning and only look whether someone opened the terminal.
    struct pollfd p;
    p.fd = master;
    p.events = POLLIN;
    p.revents = 0;
    int timeout_ms = static_cast<int>(ceil(o.step_ms));
    if (!connected) {
      struct timespec ts = {0, static_cast<long>(o.step_ms * 1e6)};
      nanosleep(&ts, nullptr);
      timeout_ms = 0;
    }
    int n = poll(&p, 1, timeout_ms);
    const double t = now_s();
    const uint32_t now_ms = static_cast<uint32_t>((t - t0) * 1000.0);
    bool hup = false;
    if (n > 0) {
      if (p.revents & POLLIN) {
        unsigned char buf[256];
        ssize_t r = read(master, buf, sizeof buf);
        if (r > 0) {
          connected = true;
          for (ssize_t i = 0; i < r; ++i) {
            if (o.verbose) {
              if (buf[i] == '\n' || buf[i] == '\r' || line_in_len == sizeof line_in) {
                if (line_in_len) log_line(o, "<-", line_in, line_in_len);
                line_in_len = 0;
              }
              if (buf[i] != '\n' && buf[i] != '\r') line_in[line_in_len++] = static_cast<char>(buf[i]);
            }
            const char* reply = core.feed(buf[i], now_ms);
            if (reply) {
              log_line(o, "->", reply, strlen(reply));
              outbox.queue(reply, strlen(reply));
            }
          }
        } else if (r < 0 && errno == EIO) {
          hup = true;
        }
      } else if (p.revents & (POLLHUP | POLLERR)) {
        hup = true;
      }
    } else if (n == 0 && !connected) {
      connected = true;  // no POLLHUP any more: a host opened the terminal
      if (o.verbose) fprintf(stderr, "plush-board-emu: host connected\n");
    }
    outbox.flush(master);
    if (hup && connected) {
      connected = false;
      core.hangup();
      if (o.verbose) fprintf(stderr, "plush-board-emu: host hung up, motors stopped\n");
    }

    // An axis the host just stopped (STOP, hang-up) brakes at once, not at
    // the next control cycle: its target is the position it stops at.
    for (uint8_t a = 0; a < o.winches; ++a)
      if (!core.enabled(a)) sim.drive[a] = plush::Drive{true, 0};

    // Motors and the control law in simulated time; after a stall
    // (debugger, suspended process) at most 0.1 s is caught up.
    double dt = t - t_last;
    t_last = t;
    if (dt > 0.1) dt = 0.1;
    advance(o, core, &sim, dt, now_ms);
    if (g_window_request) {
      g_window_request = 0;
      sim.close_window(core, o.winches);
      t_state = -1.0;  // write the state now: the host waits for the new window
    }

    if (o.state_file && (t - t_state) * 1000.0 >= o.state_interval_ms) {
      t_state = t;
      write_state(o, core, sim, t - t0, connected, outbox.dropped);
    }
  }

  core.stop_all(plush::STOP_COMMAND);
  write_state(o, core, sim, now_s() - t0, connected, outbox.dropped);
  if (o.link) unlink(o.link);
  close(master);
  if (o.verbose) fprintf(stderr, "plush-board-emu: stopped\n");
  return 0;
}
