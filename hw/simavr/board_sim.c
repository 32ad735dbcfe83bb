// plush-board-sim: the real winch board firmware on a simulated ATmega2560.
//
// Loads the firmware ELF (hw/firmware/build/plush_winch.elf) into simavr,
// bridges UART0 to a pseudo-terminal whose path is the first line on
// stdout (like plush-board-emu), and closes the loop around the firmware:
// every motor is a first-order DC motor driven by the firmware's own PWM
// and direction pins, and its position comes back to the firmware as the
// two quadrature lines of its encoder. The simulated time is kept at wall
// clock time, so the firmware's millis() and the host's clock agree.
// See hw/simavr/README.md and --help.
#define _GNU_SOURCE  // posix_openpt, ptsname
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <gelf.h>
#include <libelf.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"

#define VERSION "1.0.0"
#define MAX_MOTORS 4            // the firmware drives up to 4 (plush_winch.ino, N_AXES)
#define MCU_NAME "atmega2560"
#define MCU_HZ 16000000u

// Data-space addresses of the ATmega2560 registers the motors are read
// from (avr/iomxx0_1.h; I/O registers are at 0x20 + their I/O address).
#define REG_PORTC 0x28
#define REG_PORTE 0x2E
#define REG_PORTH 0x102
#define REG_UCSR0B 0xC1
#define BIT_RXEN0 4
#define REG_PCIFR 0x3B
#define REG_PCICR 0x68
#define REG_PCMSK2 0x6D
#define BIT_PCIE2 2
#define PCINT2_VECTOR 11

// simavr 1.6 models the pin-change interrupts of ports B and J of the
// ATmega2560 but not PCINT2 on port K, where the encoders are: this
// harness raises it, as the chip does, when an enabled PK pin changes.
static avr_int_vector_t g_pcint2 = {
    .vector = PCINT2_VECTOR,
    .enable = AVR_IO_REGBIT(REG_PCICR, BIT_PCIE2),
    .raised = AVR_IO_REGBIT(REG_PCIFR, BIT_PCIE2),
};

// Motor a: PWM on Arduino pin 5, 6, 7, 8 (OC3A, OC4A, OC4B, OC4C), IN1 on
// pin 30 + 2a and IN2 on pin 31 + 2a (PC7 - 2a and PC6 - 2a), encoder
// channels A and B on PK(2a) and PK(2a + 1) - plush_winch.ino's wiring.
typedef struct {
  uint16_t tccr;      // timer control register A
  uint8_t com_bit;    // COMnx1: the compare output drives the pin
  uint16_t ocr;       // compare register, low byte (8-bit PWM)
  uint16_t port;      // the pin's PORT register when the PWM is off
  uint8_t port_bit;
} PwmPin;

static const PwmPin PWM_PINS[MAX_MOTORS] = {
    {0x90, 7, 0x98, REG_PORTE, 3},  // pin 5: OC3A = PE3
    {0xA0, 7, 0xA8, REG_PORTH, 3},  // pin 6: OC4A = PH3
    {0xA0, 5, 0xAA, REG_PORTH, 4},  // pin 7: OC4B = PH4
    {0xA0, 3, 0xAC, REG_PORTH, 5},  // pin 8: OC4C = PH5
};

// Quadrature state (bit 0: channel A, bit 1: channel B) of encoder count
// n, in the order the firmware's decoding table counts upwards. Count 0
// has both lines high, as the pulled-up inputs read before the encoder
// lines are first driven, so the firmware's first reading agrees.
static const uint8_t QUAD[4] = {3, 1, 0, 2};

// Time steps, in CPU cycles and their reason.
#define MOTOR_PERIOD_CYCLES 800u  // 50 us: at the top speed a motor moves < 1 tick per step
#define IO_PERIOD_CYCLES 16000u   // 1 ms: pty polling and wall-clock pacing
#define MAX_LEAD_S 0.002          // sleep when the simulation runs this far ahead of the clock
#define MAX_SPEED 10000.0         // ticks/s: one encoder edge per motor step at most
#define OUT_BUF 65536             // replies the host has not read yet

typedef struct {
  int winches;
  double speed;      // top speed at full PWM, ticks/s
  double tau;        // mechanical time constant, s
  double deadzone;   // PWM fraction below which the gearmotor does not turn
  const char* firmware;
  const char* state_file;
  long state_interval_ms;
  long encoder_start;  // encoder count at power-up (test hook, see --help)
  int verbose;
} Options;

typedef struct {
  double x;       // true position, ticks
  double v;       // speed, ticks/s
  long count;     // encoder count the firmware has been shown
  double duty;    // last applied drive, -1..1
  int braked;     // IN1 = IN2 = HIGH
  double braked_at;  // simulated time the brake last engaged, s (-1: never)
  long min_count, max_count;        // extremes of the encoder count since power-up
  long window_min, window_max;      // ... since the last window reset (SIGUSR1)
  long closed_min, closed_max;      // ... of the window that reset closed
} Motor;

static volatile sig_atomic_t g_stop = 0;
static void on_signal(int sig) {
  (void)sig;
  g_stop = 1;
}
// SIGUSR1 closes the window of extremes (tests measure one move's overshoot).
static volatile sig_atomic_t g_window_request = 0;
static unsigned long g_windows = 0;
static void on_window(int sig) {
  (void)sig;
  g_window_request = 1;
}

static avr_t* g_avr;
static Options g_opt;
static Motor g_motor[MAX_MOTORS];
static avr_irq_t* g_enc_irq[MAX_MOTORS][2];
static avr_irq_t* g_uart_in;
static int g_master = -1;
static int g_connected = 0;
static int g_xon = 1;
static unsigned char g_in[4096];
static size_t g_in_len = 0;
static unsigned char g_out[OUT_BUF];
static size_t g_out_len = 0;
static unsigned long g_dropped = 0, g_rx = 0, g_tx = 0;
static double g_last_rx = 0.0;  // simulated time of the last byte given to the UART

static double now_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double sim_s(void) { return (double)g_avr->cycle / (double)MCU_HZ; }

static void usage(FILE* out) {
  fprintf(out,
          "usage: plush-board-sim --firmware ELF [options]\n"
          "\n"
          "Runs the winch board firmware on a simulated ATmega2560 (simavr) with\n"
          "simulated motors and encoders. Prints the pseudo-terminal of its serial\n"
          "port on the first line of stdout, then runs until SIGTERM or SIGINT.\n"
          "SIGUSR1 closes the window of position extremes in the state file.\n"
          "\n"
          "  --firmware ELF       the firmware (make -C hw firmware)\n"
          "  --winches N          motors connected to axes 0..N-1, 1..%d (default 4)\n"
          "  --speed TICKS_PER_S  motor speed at full PWM (default 3000)\n"
          "  --tau SECONDS        motor time constant (default 0.02)\n"
          "  --deadzone FRACTION  PWM fraction that does not turn the motor (default 0.06:\n"
          "                       the firmware's PWM_MIN of 25/255 just turns it)\n"
          "  --state-file PATH    write the true state as JSON to PATH (atomically)\n"
          "  --state-interval MS  how often to write it (default 20)\n"
          "  --encoder-start N    the encoders read N (a multiple of 4) once the firmware has\n"
          "                       started, as after a long travel (writes its enc_count)\n"
          "  --verbose            log the serial bytes on stderr\n"
          "  --version, --help\n",
          MAX_MOTORS);
}

static int parse_double(const char* s, double lo, double hi, double* out) {
  char* end = NULL;
  errno = 0;
  double v = strtod(s, &end);
  if (errno != 0 || end == s || *end != '\0' || !(v >= lo && v <= hi)) return 0;
  *out = v;
  return 1;
}

static int parse_long(const char* s, long lo, long hi, long* out) {
  char* end = NULL;
  errno = 0;
  long v = strtol(s, &end, 10);
  if (errno != 0 || end == s || *end != '\0' || v < lo || v > hi) return 0;
  *out = v;
  return 1;
}

// Returns 0 to run, -1 to exit 0 (--help), else the exit status.
static int parse_args(int argc, char** argv, Options* o) {
  for (int i = 1; i < argc; ++i) {
    const char* a = argv[i];
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      usage(stdout);
      return -1;
    }
    if (!strcmp(a, "--version")) {
      printf("plush-board-sim %s\n", VERSION);
      return -1;
    }
    if (!strcmp(a, "--verbose")) {
      o->verbose = 1;
      continue;
    }
    if (i + 1 >= argc) {
      fprintf(stderr, "plush-board-sim: %s needs a value (see --help)\n", a);
      return 2;
    }
    const char* v = argv[++i];
    long l = 0;
    int ok = 1;
    if (!strcmp(a, "--winches")) {
      ok = parse_long(v, 1, MAX_MOTORS, &l);
      o->winches = (int)l;
    } else if (!strcmp(a, "--speed")) {
      ok = parse_double(v, 1.0, MAX_SPEED, &o->speed);
    } else if (!strcmp(a, "--tau")) {
      ok = parse_double(v, 0.0, 10.0, &o->tau);
    } else if (!strcmp(a, "--deadzone")) {
      ok = parse_double(v, 0.0, 0.9, &o->deadzone);
    } else if (!strcmp(a, "--firmware")) {
      o->firmware = v;
    } else if (!strcmp(a, "--state-file")) {
      o->state_file = v;
    } else if (!strcmp(a, "--encoder-start")) {
      ok = parse_long(v, -1000000000L, 1000000000L, &o->encoder_start) && o->encoder_start % 4 == 0;
    } else if (!strcmp(a, "--state-interval")) {
      ok = parse_long(v, 1, 60000, &o->state_interval_ms);
    } else {
      fprintf(stderr, "plush-board-sim: unknown option %s (see --help)\n", a);
      return 2;
    }
    if (!ok) {
      fprintf(stderr, "plush-board-sim: bad value for %s: %s (see --help)\n", a, v);
      return 2;
    }
  }
  if (!o->firmware) {
    fprintf(stderr, "plush-board-sim: --firmware ELF is required (see --help)\n");
    return 2;
  }
  return 0;
}

// ------------------------------------------------------------- motors --

static int bit(uint16_t addr, uint8_t b) { return (g_avr->data[addr] >> b) & 1; }

// Signed drive of motor a from its pins, -1..1 (TB6612FNG truth table).
static double motor_drive(int a, int* braked) {
  const PwmPin* p = &PWM_PINS[a];
  double duty;
  if (bit(p->tccr, p->com_bit))
    duty = g_avr->data[p->ocr] / 255.0;
  else
    duty = bit(p->port, p->port_bit) ? 1.0 : 0.0;
  const int in1 = bit(REG_PORTC, (uint8_t)(7 - 2 * a));
  const int in2 = bit(REG_PORTC, (uint8_t)(6 - 2 * a));
  *braked = in1 && in2;
  if (in1 && !in2) return duty;
  if (!in1 && in2) return -duty;
  return 0.0;  // short brake or coast
}

static void set_encoder(int a, long count) {
  const uint8_t q = QUAD[count & 3];
  avr_raise_irq(g_enc_irq[a][0], q & 1);
  avr_raise_irq(g_enc_irq[a][1], (q >> 1) & 1);
  if (g_avr->data[REG_PCMSK2] & (3u << (2 * a))) avr_raise_interrupt(g_avr, &g_pcint2);
}

// Data-space address of the firmware's encoder counters (int32_t[4]),
// from the ELF's symbol table; 0 if absent.
#define ENC_SYMBOL "_ZL9enc_count"
#define AVR_DATA_BASE 0x800000u  // avr-gcc places RAM at this address in the ELF

static uint32_t find_enc_count(const char* path) {
  uint32_t addr = 0;
  elf_version(EV_CURRENT);
  int fd = open(path, O_RDONLY);
  if (fd < 0) return 0;
  Elf* e = elf_begin(fd, ELF_C_READ, NULL);
  Elf_Scn* scn = NULL;
  while (e && !addr && (scn = elf_nextscn(e, scn)) != NULL) {
    GElf_Shdr sh;
    if (!gelf_getshdr(scn, &sh) || sh.sh_type != SHT_SYMTAB) continue;
    Elf_Data* d = elf_getdata(scn, NULL);
    for (size_t i = 0; d && i < sh.sh_size / sh.sh_entsize; ++i) {
      GElf_Sym sym;
      if (!gelf_getsym(d, (int)i, &sym)) continue;
      const char* name = elf_strptr(e, sh.sh_link, sym.st_name);
      if (name && !strcmp(name, ENC_SYMBOL)) {
        addr = (uint32_t)sym.st_value - AVR_DATA_BASE;
        break;
      }
    }
  }
  if (e) elf_end(e);
  close(fd);
  return addr;
}

static uint32_t g_enc_addr = 0;
static int g_enc_preset = 0;

// Once setup() has enabled the encoder interrupt (and the C runtime has
// cleared the counters), make motors, encoder lines and the firmware's
// counters all read the start count.
static void preset_encoders(void) {
  if (g_enc_preset || !(g_avr->data[REG_PCICR] & (1u << BIT_PCIE2))) return;
  g_enc_preset = 1;
  for (int a = 0; a < g_opt.winches; ++a) {
    Motor* m = &g_motor[a];
    m->x = (double)g_opt.encoder_start;
    m->count = m->min_count = m->max_count = m->window_min = m->window_max = g_opt.encoder_start;
    const uint32_t v = (uint32_t)g_opt.encoder_start;
    for (int b = 0; b < 4; ++b) g_avr->data[g_enc_addr + 4u * (uint32_t)a + (uint32_t)b] = (uint8_t)(v >> (8 * b));
  }  // a multiple of 4 (see parse_args): the lines stay as the firmware last read them
}

static avr_cycle_count_t motor_step(avr_t* avr, avr_cycle_count_t when, void* param) {
  (void)avr;
  (void)param;
  const double dt = MOTOR_PERIOD_CYCLES / (double)MCU_HZ;
  const double relax = g_opt.tau > 0 ? 1.0 - exp(-dt / g_opt.tau) : 1.0;
  if (g_enc_addr) preset_encoders();
  for (int a = 0; a < g_opt.winches; ++a) {
    Motor* m = &g_motor[a];
    const int was_braked = m->braked;
    m->duty = motor_drive(a, &m->braked);
    if (m->braked && !was_braked) m->braked_at = sim_s();
    double goal = 0.0;  // speed the drive sustains
    if (fabs(m->duty) > g_opt.deadzone)
      goal = copysign((fabs(m->duty) - g_opt.deadzone) / (1.0 - g_opt.deadzone), m->duty) * g_opt.speed;
    if (m->braked)
      m->v = 0.0;  // short brake through a high-ratio gearbox: stops at once, holds
    else
      m->v += (goal - m->v) * relax;
    m->x += m->v * dt;
    // One quadrature edge per step at most, so the firmware's pin-change
    // interrupt sees every edge (as with a real encoder below its limit).
    const long want = lround(m->x);
    if (want != m->count) {
      m->count += want > m->count ? 1 : -1;
      set_encoder(a, m->count);
      if (m->count < m->min_count) m->min_count = m->count;
      if (m->count > m->max_count) m->max_count = m->count;
      if (m->count < m->window_min) m->window_min = m->count;
      if (m->count > m->window_max) m->window_max = m->count;
    }
  }
  return when + MOTOR_PERIOD_CYCLES;
}

// --------------------------------------------------------------- UART --

static void pump_input(void) {
  // Bytes before Serial.begin() would be dropped by the UART: keep them.
  if (!bit(REG_UCSR0B, BIT_RXEN0)) return;
  size_t i = 0;
  while (g_xon && i < g_in_len) {
    avr_raise_irq(g_uart_in, g_in[i++]);
    ++g_rx;
    g_last_rx = sim_s();
  }
  memmove(g_in, g_in + i, g_in_len - i);
  g_in_len -= i;
}

static void uart_xon(avr_irq_t* irq, uint32_t value, void* param) {
  (void)irq;
  (void)value;
  (void)param;
  g_xon = 1;
  pump_input();
}

static void uart_xoff(avr_irq_t* irq, uint32_t value, void* param) {
  (void)irq;
  (void)value;
  (void)param;
  g_xon = 0;
}

static void uart_output(avr_irq_t* irq, uint32_t value, void* param) {
  (void)irq;
  (void)param;
  ++g_tx;
  if (g_opt.verbose) fputc((int)(value & 0xff), stderr);
  if (g_out_len < OUT_BUF)
    g_out[g_out_len++] = (unsigned char)value;
  else
    ++g_dropped;  // nobody reads: a serial line would lose these bytes too
}

static void flush_output(void) {
  while (g_out_len > 0) {
    ssize_t w = write(g_master, g_out, g_out_len);
    if (w > 0) {
      memmove(g_out, g_out + w, g_out_len - (size_t)w);
      g_out_len -= (size_t)w;
    } else if (w < 0 && errno == EINTR) {
      continue;
    } else {
      if (w < 0 && errno == EIO) {  // no host: the bytes go nowhere
        g_dropped += g_out_len;
        g_out_len = 0;
      }
      return;  // EAGAIN: try again next millisecond
    }
  }
}

static void poll_pty(void) {
  struct pollfd p = {g_master, POLLIN, 0};
  if (poll(&p, 1, 0) > 0) {
    if (p.revents & POLLIN) {
      ssize_t r = read(g_master, g_in + g_in_len, sizeof g_in - g_in_len);
      if (r > 0) {
        g_connected = 1;
        g_in_len += (size_t)r;
      }
    } else if (p.revents & (POLLHUP | POLLERR)) {
      g_connected = 0;  // the firmware is not told: only its watchdog stops motors
    }
  } else {
    g_connected = 1;  // no POLLHUP: a host has the terminal open
  }
  pump_input();
  flush_output();
}

// -------------------------------------------------------------- state --

// Close the window of extremes: keep its extremes, start the next at the count now.
static void close_window(void) {
  g_window_request = 0;
  for (int a = 0; a < g_opt.winches; ++a) {
    Motor* m = &g_motor[a];
    m->closed_min = m->window_min;
    m->closed_max = m->window_max;
    m->window_min = m->window_max = m->count;
  }
  ++g_windows;
}

static void write_state(double wall) {
  if (!g_opt.state_file) return;
  char tmp[4096];
  snprintf(tmp, sizeof tmp, "%s.tmp", g_opt.state_file);
  FILE* f = fopen(tmp, "w");
  if (!f) return;
  fprintf(f, "{\"time\": %.4f, \"wall_time\": %.4f, \"winches\": %d, \"connected\": %s", sim_s(), wall,
          g_opt.winches, g_connected ? "true" : "false");
#define LIST(key, fmt, expr)                                    \
  fprintf(f, ", \"%s\": [", key);                               \
  for (int a = 0; a < g_opt.winches; ++a) {                     \
    const Motor* m = &g_motor[a];                               \
    fprintf(f, a ? ", " fmt : fmt, expr);                       \
  }                                                             \
  fputc(']', f);
  LIST("position", "%.3f", m->x)
  LIST("ticks", "%ld", m->count)
  LIST("speed", "%.1f", m->v)
  LIST("drive", "%.3f", m->duty)
  LIST("enabled", "%s", m->braked ? "false" : "true")
  LIST("braked_time", "%.6f", m->braked_at)
  LIST("min_ticks", "%ld", m->min_count)
  LIST("max_ticks", "%ld", m->max_count)
  LIST("window_min", "%ld", m->window_min)
  LIST("window_max", "%ld", m->window_max)
  LIST("closed_min", "%ld", m->closed_min)
  LIST("closed_max", "%ld", m->closed_max)
#undef LIST
  fprintf(f, ", \"windows\": %lu", g_windows);
  fprintf(f, ", \"last_rx_time\": %.4f", g_last_rx);
  fprintf(f, ", \"rx_bytes\": %lu, \"tx_bytes\": %lu, \"dropped_bytes\": %lu}\n", g_rx, g_tx, g_dropped);
  if (fclose(f) == 0) rename(tmp, g_opt.state_file);
}

// --------------------------------------------------------------- main --

// simavr logs to stdout, where only the terminal's path may appear.
static void log_to_stderr(avr_t* avr, const int level, const char* format, va_list ap) {
  if (level > (avr ? avr->log : LOG_ERROR)) return;
  vfprintf(stderr, format, ap);
}

// The pseudo-terminal the host opens, raw until the host configures it.
static int open_pty(void) {
  g_master = posix_openpt(O_RDWR | O_NOCTTY);
  if (g_master < 0 || grantpt(g_master) != 0 || unlockpt(g_master) != 0 || !ptsname(g_master)) {
    fprintf(stderr, "plush-board-sim: cannot create a pseudo-terminal: %s\n", strerror(errno));
    return 0;
  }
  fcntl(g_master, F_SETFL, fcntl(g_master, F_GETFL) | O_NONBLOCK);
  struct termios tio;
  if (tcgetattr(g_master, &tio) == 0) {  // raw until the host configures it
    cfmakeraw(&tio);
    tcsetattr(g_master, TCSANOW, &tio);
  }

  return 1;
}

int main(int argc, char** argv) {
  Options o = {4, 3000.0, 0.02, 0.06, NULL, NULL, 20, 0, 0};
  int rc = parse_args(argc, argv, &o);
  if (rc != 0) return rc < 0 ? 0 : rc;
  g_opt = o;
  for (int a = 0; a < MAX_MOTORS; ++a) g_motor[a].braked_at = -1.0;  // never braked yet

  avr_global_logger_set(log_to_stderr);
  elf_firmware_t fw;
  memset(&fw, 0, sizeof fw);
  if (access(o.firmware, R_OK) != 0 || elf_read_firmware(o.firmware, &fw) != 0) {
    fprintf(stderr, "plush-board-sim: cannot read firmware %s (build it with `make -C hw firmware`)\n",
            o.firmware);
    return 1;
  }
  // The ELF carries no MCU section: the board is a Mega 2560 at 16 MHz.
  strcpy(fw.mmcu, MCU_NAME);
  fw.frequency = MCU_HZ;
  g_avr = avr_make_mcu_by_name(fw.mmcu);
  if (!g_avr) {
    fprintf(stderr, "plush-board-sim: simavr does not know %s\n", MCU_NAME);
    return 1;
  }
  avr_init(g_avr);
  avr_load_firmware(g_avr, &fw);
  g_avr->log = o.verbose ? LOG_WARNING : LOG_ERROR;

  uint32_t flags = 0;  // no console echo, no sleeping in UART polls: keep real time
  avr_ioctl(g_avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
  flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
  avr_ioctl(g_avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
  g_uart_in = avr_io_getirq(g_avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
  avr_irq_register_notify(avr_io_getirq(g_avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_output, NULL);
  avr_irq_register_notify(avr_io_getirq(g_avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon, NULL);
  avr_irq_register_notify(avr_io_getirq(g_avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff, NULL);

  if (o.encoder_start != 0 && !(g_enc_addr = find_enc_count(o.firmware))) {
    fprintf(stderr, "plush-board-sim: --encoder-start: no symbol %s in %s\n", ENC_SYMBOL, o.firmware);
    return 1;
  }
  avr_register_vector(g_avr, &g_pcint2);
  for (int a = 0; a < o.winches; ++a) {
    g_enc_irq[a][0] = avr_io_getirq(g_avr, AVR_IOCTL_IOPORT_GETIRQ('K'), 2 * a);
    g_enc_irq[a][1] = avr_io_getirq(g_avr, AVR_IOCTL_IOPORT_GETIRQ('K'), 2 * a + 1);
    set_encoder(a, 0);
  }
  avr_cycle_timer_register(g_avr, MOTOR_PERIOD_CYCLES, motor_step, NULL);

  if (!open_pty()) return 1;

  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGTERM, &sa, NULL);
  sigaction(SIGINT, &sa, NULL);
  sa.sa_handler = on_window;
  sigaction(SIGUSR1, &sa, NULL);
  signal(SIGPIPE, SIG_IGN);
  signal(SIGHUP, SIG_IGN);

  printf("%s\n", ptsname(g_master));
  fflush(stdout);

  const double t0 = now_s();
  double t_state = -1.0;
  avr_cycle_count_t next_io = 0;
  int state = cpu_Running;
  while (!g_stop) {
    state = avr_run(g_avr);
    if (state == cpu_Done || state == cpu_Crashed) break;
    if (g_avr->cycle < next_io) continue;
    next_io = g_avr->cycle + IO_PERIOD_CYCLES;
    poll_pty();
    double wall = now_s() - t0;
    if (g_window_request) {
      close_window();
      t_state = -1.0;  // write the state now: the host waits for the new window
    }
    const double lead = sim_s() - wall;
    if (lead > MAX_LEAD_S) {
      struct timespec ts = {0, (long)(lead * 1e9)};
      nanosleep(&ts, NULL);
      wall = now_s() - t0;
    }
    if (o.state_file && (wall - t_state) * 1000.0 >= (double)o.state_interval_ms) {
      t_state = wall;
      write_state(wall);
    }
  }
  write_state(now_s() - t0);
  close(g_master);
  if (state == cpu_Crashed) {
    fprintf(stderr, "plush-board-sim: the firmware crashed at pc=0x%x\n", g_avr->pc);
    return 1;
  }
  return 0;
}
