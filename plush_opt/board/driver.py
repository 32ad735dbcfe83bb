"""Serial driver of the winch board (hw/PROTOCOL.md) with pyserial.

:class:`Driver` opens the port, checks the board against a calibration,
sets its soft limits, speed limits and watchdog, and then converts
contractions (mm, by winch name) to targets (ticks, by axis) and
positions back. Every exchange is bounded in time: each command waits at
most ``timeout`` seconds for its reply and is sent at most ``1 + retries``
times, so no call hangs on a silent board.

Safety: contractions outside the calibration limits or the scene's winch
bounds are refused before anything is sent; opening and closing the driver
stop all motors, and so does leaving its ``with`` block for any reason,
including KeyboardInterrupt.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import signal
import threading
import time
from collections.abc import Mapping

import serial

from plush_opt.board import protocol as P
from plush_opt.board.board_file import BoardCalibration
from plush_opt.board.limits import allowed_ranges, check_contractions
from plush_opt.base.errors import HardwareError

log = logging.getLogger(__name__)

_READ_SLICE = 0.02   # s: pyserial read timeout; deadlines are kept by us
_MAX_PENDING = 4096  # bytes without a newline: noise, dropped
_RECENT = 64         # abandoned sequence numbers remembered: far more than retries within one wait
_WARNING_INTERVAL = 1.0  # s: the same board warning at most this often; a babbling board stays readable


@contextlib.contextmanager
def _sigint_deferred(reraise: bool):
    """Hold back Ctrl-C while the board is being stopped.

    A second Ctrl-C must not cut the STOP short. The interrupt is
    re-raised afterwards if ``reraise`` (nothing else is propagating).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received = []
    try:
        previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    except ValueError:  # not in the main interpreter
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received and reraise:
            raise KeyboardInterrupt


class Driver:
    """One winch board on one serial port.

    Parameters
    ----------
    port : str
        Serial device (``/dev/ttyACM0``, ``COM3``, a pseudo-terminal path).
    calibration : BoardCalibration
        Which axis is which winch, ticks per mm, limits, speeds.
    bounds : mapping of str to (float, float), optional
        The scene's winch bounds ``{name: (lower, upper)}`` (mm); contractions
        outside them are refused, like those outside the calibration limits.
    baudrate, timeout, retries, watchdog_ms, boot_time : optional
        Override the calibration's ``port`` settings. ``timeout`` is the
        time in seconds to wait for one reply, ``retries`` the number of
        further attempts after a timeout, ``boot_time`` how long the first
        ``ID`` keeps being retried after opening (an Arduino resets when
        its port opens and answers only after its bootloader).
    serial_factory : callable, optional
        Opens the port; ``serial.Serial`` by default (tests pass their own).

    Use as a context manager::

        with Driver("/dev/ttyACM0", load_calibration("hw/boards/gripper.yaml")) as board:
            board.set_contractions({"grip": 12.0})
            print(board.read_positions())
    """

    def __init__(self, port: str, calibration: BoardCalibration, *,
                 bounds: Mapping[str, tuple[float, float]] | None = None,
                 baudrate: int | None = None, timeout: float | None = None, retries: int | None = None,
                 watchdog_ms: int | None = None, boot_time: float | None = None, serial_factory=None):
        settings = calibration.port
        self.port = str(port)
        self.calibration = calibration
        self.baudrate = baudrate or settings.baudrate
        self.timeout = float(timeout if timeout is not None else settings.timeout)
        self.retries = int(retries if retries is not None else settings.retries)
        self.watchdog_ms = int(watchdog_ms if watchdog_ms is not None else settings.watchdog_ms)
        self.boot_time = float(boot_time if boot_time is not None else settings.boot_time)
        if self.timeout <= 0 or self.retries < 0:
            raise ValueError(f"timeout must be > 0 and retries >= 0, got {self.timeout}, {self.retries}")
        if not P.MIN_WATCHDOG_MS <= self.watchdog_ms <= P.MAX_WATCHDOG_MS:
            raise ValueError(f"watchdog_ms must be in {P.MIN_WATCHDOG_MS}..{P.MAX_WATCHDOG_MS}, "
                             f"got {self.watchdog_ms}")
        self._allowed = allowed_ranges(calibration, bounds)
        self._serial_factory = serial_factory
        self._io = _Transport(self.port, self.baudrate, self.timeout, self.retries)
        self.info: P.BoardInfo | None = None

    @property
    def allowed(self) -> dict[str, tuple[float, float]]:
        """Allowed contraction per calibrated winch (mm): calibration limits within scene bounds."""
        return dict(self._allowed)

    # ---------------------------------------------------------- open/close --
    @property
    def is_open(self) -> bool:
        return self._io.ser is not None

    @property
    def n_axes(self) -> int:
        """Number of axes of the connected board."""
        if self.info is None:
            raise HardwareError(f"{self.port}: board not open")
        return self.info.winches

    def open(self) -> "Driver":
        """Open the port and configure the board. Stops all motors.

        Identifies the board, checks protocol version and number of axes
        against the calibration, then sets the watchdog and, per calibrated
        winch, the soft limits and speed limit.
        """
        if self.is_open:
            return self
        factory = self._serial_factory or serial.Serial
        try:
            ser = factory(port=self.port, baudrate=self.baudrate, bytesize=8, parity="N", stopbits=1,
                          timeout=_READ_SLICE, write_timeout=self.timeout, exclusive=True)
        except Exception as e:  # serial.SerialException, OSError, ValueError
            raise HardwareError(f"cannot open serial port {self.port}: {e}") from None
        try:
            self._io.attach(ser)
            self._handshake()
        except BaseException:
            self._close_port()
            raise
        return self

    def _handshake(self):
        cal = self.calibration
        reply = self._transact("ID", patience=self.boot_time)
        try:
            info = P.parse_info(reply.payload)
        except P.ProtocolError as e:
            raise HardwareError(f"{self.port}: unexpected ID reply: {e}") from None
        if info.protocol != P.PROTOCOL_VERSION:
            raise HardwareError(f"{self.port}: board {info.board} speaks protocol {info.protocol}, "
                                f"this plush_opt speaks {P.PROTOCOL_VERSION}; update the firmware or plush_opt")
        if info.winches < cal.n_axes_required:
            raise HardwareError(f"{self.port}: board {info.board} has {info.winches} winch axes, calibration "
                                f"{cal.source} needs {cal.n_axes_required} "
                                f"({', '.join(f'{w.name}=axis {w.axis}' for w in cal.winches)})")
        if info.winches > len(cal.winches):
            log.info("%s: board has %d axes, calibration %s uses %d; the others stay stopped",
                     self.port, info.winches, cal.source, len(cal.winches))
        self.info = info
        self._transact("STOP")
        self._transact("WDOG", self.watchdog_ms)
        for w in cal.winches:
            lo, hi = w.tick_limits
            self._transact("LIMIT", w.axis, lo, hi)
            self._transact("SPEED", w.axis, w.speed_ticks)
        log.info("%s: %s firmware %s, %d axes, calibration %s", self.port, info.board, info.firmware,
                 info.winches, cal.name)

    def _close_port(self):
        ser, self._io.ser = self._io.ser, None
        self._io._warnings.flush()
        self.info = None
        if ser is not None:
            try:
                ser.close()
            except Exception as e:  # closing must not mask what went wrong before
                log.warning("%s: error closing port: %s", self.port, e)

    def close(self) -> None:
        """Stop all motors (best effort) and close the port."""
        if not self.is_open:
            return
        try:
            self.halt()
        except HardwareError as e:
            log.error("%s: could not stop the board before closing: %s", self.port, e)
        finally:
            self._close_port()

    def __enter__(self) -> "Driver":
        return self.open()

    def __exit__(self, exc_type, exc, tb):
        try:
            self._stop_on_exit(exc_type)
        finally:
            self._close_port()
        return False

    @contextlib.contextmanager
    def stop_on_exit(self):
        """Context manager: stop all motors when the block exits, keep the port open."""
        try:
            yield self
        except BaseException as e:
            self._stop_on_exit(type(e))
            raise
        else:
            self._stop_on_exit(None)

    def _stop_on_exit(self, exc_type):
        if not self.is_open:
            return
        with _sigint_deferred(reraise=exc_type is None):
            try:
                self._end_partial_line()
                self.stop()
            except HardwareError as e:
                if exc_type is None:
                    raise
                log.error("%s: could not stop the board after %s: %s", self.port, exc_type.__name__, e)

    def _end_partial_line(self) -> None:
        """A bare newline: if a write was cut off half-way, the board would
        otherwise glue STOP onto the fragment and refuse the whole line. The
        board ignores blank lines."""
        try:
            self._io.write(b"\n")
        except HardwareError as e:
            log.warning("%s: could not end a partial line: %s", self.port, e)

    # ------------------------------------------------------------ commands --
    def identify(self) -> P.BoardInfo:
        """Ask the board who it is (``ID``)."""
        return P.parse_info(self._transact("ID").payload)

    def ping(self) -> None:
        """Round trip that only keeps the watchdog fed."""
        self._transact("PING")

    def stop(self) -> None:
        """Stop all motors: hold where they are, drives braked."""
        self._transact("STOP")

    def halt(self) -> None:
        """Stop all motors like :meth:`stop`, but end a partial line first
        and hold back Ctrl-C until the board has answered (re-raised then)."""
        with _sigint_deferred(reraise=True):
            self._end_partial_line()
            self.stop()

    def zero(self, name: str | None = None) -> None:
        """Declare the current position of one winch (or all) contraction 0."""
        if name is None:
            self._transact("ZERO")
        else:
            self._transact("ZERO", self.calibration.winch(name).axis)

    def read_state(self) -> P.BoardState:
        """Positions, targets, moving/enabled flags of every board axis (ticks)."""
        reply = self._transact("GET")
        try:
            return P.parse_state(reply.payload, self.n_axes)
        except P.ProtocolError as e:
            raise HardwareError(f"{self.port}: unexpected GET reply: {e}") from None

    def positions_mm(self, state: P.BoardState) -> dict[str, float]:
        """Contraction (mm) of every calibrated winch in ``state``."""
        return {w.name: w.to_mm(state.position[w.axis]) for w in self.calibration.winches}

    def read_positions(self) -> dict[str, float]:
        """Measured contraction of every calibrated winch, ``{name: mm}``."""
        return self.positions_mm(self.read_state())

    def set_contractions(self, contraction: Mapping[str, float]) -> dict[str, int]:
        """Command contractions ``{winch: mm}``; other winches keep their targets.

        Validates every value first (see
        :func:`~plush_opt.board.limits.check_contractions`), then sends one
        ``SET`` or ``SETALL``, so the winches start together. Returns the
        commanded ``{winch: ticks}``.
        """
        try:
            ticks = check_contractions(contraction, self._allowed, self.calibration)
        except HardwareError as e:
            raise HardwareError(f"{self.port}: refused, nothing sent: {e}") from None
        if not ticks:
            return ticks
        if len(ticks) == 1:
            (name, t), = ticks.items()
            self._transact("SET", self.calibration.winch(name).axis, t)
        else:
            args = [P.KEEP] * self.n_axes
            for name, t in ticks.items():
                args[self.calibration.winch(name).axis] = t
            self._transact("SETALL", *args)
        return ticks

    def _transact(self, command: str, *args, patience: float = 0.0) -> P.Reply:
        return self._io.transact(command, *args, patience=patience)


class _LimitedWarnings:
    """Board warnings, each kind (its format) at most once per
    ``_WARNING_INTERVAL``; the next one printed says how many like it
    were held back."""

    def __init__(self, clock=time.monotonic):
        self.clock = clock
        self._last: dict[str, float] = {}
        self._held: dict[str, tuple[int, tuple]] = {}     # format -> (count, the last one's args)

    def warn(self, fmt: str, *args) -> None:
        now = self.clock()
        last = self._last.get(fmt)
        if last is not None and now - last < _WARNING_INTERVAL:
            self._held[fmt] = (self._held.get(fmt, (0, ()))[0] + 1, args)
            return
        self._last[fmt] = now
        held = self._held.pop(fmt, (0, ()))[0]
        if held:
            log.warning(fmt + " (%d more like it held back)", *args, held)
        else:
            log.warning(fmt, *args)

    def flush(self) -> None:
        """Say what is still held back (the port closes): the last one, with the count."""
        for fmt, (held, args) in self._held.items():
            log.warning(fmt + " (the last of %d held back)", *args, held)
        self._held.clear()


class _Transport:
    """Command/reply exchanges on one serial line (hw/PROTOCOL.md).

    Keeps the sequence numbers and the receive buffer across reopenings of
    the port, so that a late reply to a command given up on is recognised.
    ``ser`` is the open pyserial port, or None while closed.
    """

    def __init__(self, port: str, baudrate: int, timeout: float, retries: int):
        self.port, self.baudrate, self.timeout, self.retries = port, baudrate, timeout, retries
        self.ser = None
        self._rx = bytearray()
        self._seq = 0
        self._recent = collections.deque(maxlen=_RECENT)  # sequence numbers given up on
        self._warnings = _LimitedWarnings()

    def attach(self, ser) -> None:
        """Use this freshly opened port; replies a previous session never read are dropped."""
        self.ser = ser
        ser.reset_input_buffer()
        self._rx.clear()

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) % (P.MAX_SEQ + 1)
        return self._seq

    def write(self, data: bytes):
        try:
            self.ser.write(data)
        except Exception as e:  # SerialTimeoutException, SerialException, OSError
            raise HardwareError(f"{self.port}: cannot write to the board: {e}") from None

    def _readline(self, deadline: float) -> bytes | None:
        """One line from the board, or None when ``deadline`` passes."""
        while True:
            i = self._rx.find(b"\n")
            if i >= 0:
                line = bytes(self._rx[:i + 1])
                del self._rx[:i + 1]
                return line
            if len(self._rx) > _MAX_PENDING:
                self._warnings.warn("%s: dropping %d bytes of line noise", self.port, len(self._rx))
                self._rx.clear()
            if time.monotonic() >= deadline:
                return None
            try:
                chunk = self.ser.read(max(1, self.ser.in_waiting))
            except Exception as e:  # SerialException, OSError: unplugged, port gone
                raise HardwareError(f"{self.port}: cannot read from the board: {e}") from None
            self._rx += chunk

    def transact(self, command: str, *args, patience: float = 0.0) -> P.Reply:
        """Send a command, return its OK reply.

        Retries after a timeout with a new sequence number, ``retries``
        times and for at least ``patience`` seconds; replies carrying the
        number of an abandoned attempt are dropped. An ERR reply raises at
        once (a refusal is not a transport problem).
        """
        if self.ser is None:
            raise HardwareError(f"{self.port}: board not open")
        attempts = self.retries + 1
        if patience > 0:
            attempts = max(attempts, math.ceil(patience / self.timeout) + 1)
        started = time.monotonic()
        for attempt in range(1, attempts + 1):
            seq = self._next_seq()
            line = P.format_command(seq, command, *args)
            log.debug("%s > %s", self.port, line.decode().rstrip())
            self.write(line)
            # remembered at once: if this wait is interrupted (Ctrl-C), the
            # late reply must not look like a stranger's to the next command
            self._recent.append(seq)
            deadline = time.monotonic() + self.timeout
            while True:
                raw = self._readline(deadline)
                if raw is None:
                    break
                log.debug("%s < %r", self.port, raw)
                try:
                    reply = P.parse_reply(raw)
                except P.ProtocolError as e:
                    self._warnings.warn("%s: ignoring garbled line from board: %s", self.port, e)
                    continue
                if reply.seq == seq:
                    if reply.ok:
                        return reply
                    raise HardwareError(
                        f"{self.port}: board refused '{line.decode().strip()}': ERR {reply.code} "
                        f"{reply.error_name} ({reply.message})")
                if reply.seq is None:
                    # Some line reached the board garbled; ours may still be answered.
                    self._warnings.warn("%s: board could not read a line: ERR %s %s", self.port, reply.code, reply.message)
                    continue
                if reply.seq in self._recent:
                    log.debug("%s: dropping late reply to abandoned command %d", self.port, reply.seq)
                    continue
                raise HardwareError(
                    f"{self.port}: reply sequence mismatch: sent {command} with sequence number {seq}, "
                    f"got a reply for {reply.seq} ({raw.decode('ascii', 'replace').strip()!r}); "
                    "is another program using the port?")
            if attempt < attempts:
                # Silence while the board boots is expected, not worth a warning.
                level = logging.DEBUG if time.monotonic() - started < patience else logging.WARNING
                log.log(level, "%s: no reply to %s within %.2f s, retrying (%d/%d)", self.port, command,
                        self.timeout, attempt, attempts - 1)
        raise HardwareError(
            f"{self.port}: no reply from the board to {command} after {attempts} attempt(s) of "
            f"{self.timeout:.2f} s each; check that the board is powered and flashed, the port is right "
            f"and the baud rate is {self.baudrate}")
