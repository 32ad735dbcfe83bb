"""Run the real board firmware on a simulated ATmega2560 (hw/simavr) as a subprocess.

``plush-board-sim`` loads the firmware binary (``make -C hw firmware``)
into simavr, serves its serial port on a pseudo-terminal whose path it
prints first, and simulates each winch's motor and encoder from the
firmware's own pins. :class:`SimavrBoard` is used exactly like
:class:`~plush_opt.board.emulator.Emulator`; the difference is what
answers: the compiled AVR binary, at about real time, rather than the
protocol core compiled for the host.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from plush_opt.board import emulator as _emulator
from plush_opt.base.errors import HardwareError

log = logging.getLogger(__name__)

BINARY_ENV = "PLUSH_BOARD_SIM"
"""Environment variable that overrides the simulator binary's path."""
FIRMWARE_ENV = "PLUSH_BOARD_FIRMWARE"
"""Environment variable that overrides the firmware ELF's path."""

_HW = Path(__file__).resolve().parents[2] / "hw"
_REPO_BINARY = _HW / "simavr" / "build" / "plush-board-sim"
_REPO_FIRMWARE = _HW / "firmware" / "build" / "plush_winch.elf"

MAX_MOTORS = 4
"""Motors the firmware drives (plush_winch.ino); its ``ID`` always reports 4 axes."""
MAX_SPEED = 10_000.0
"""ticks/s: above this the harness could not show the firmware every encoder edge."""
DEADBAND = 3
"""ticks: the firmware's arrival deadband (plush_winch.ino, DEADBAND)."""


def _existing(path, env: str, default: Path, what: str, executable: bool) -> Path:
    chosen = Path(path) if path is not None else Path(os.environ[env]) if os.environ.get(env) else default
    ok = chosen.is_file() and (not executable or os.access(chosen, os.X_OK))
    if not ok:
        raise HardwareError(
            f"{what} not built: {chosen} does not exist{' or is not executable' if executable else ''}; build it "
            f"with `make -C hw firmware simavr` in the plush_opt source tree (needs gcc-avr, avr-libc, "
            f"arduino-core-avr, libsimavr-dev, libelf-dev; `make firmware-deps` installs them), or point {env} at it")
    return chosen


def simavr_binary(path: str | os.PathLike | None = None) -> Path:
    """Path of the simulator: ``path``, else ``$PLUSH_BOARD_SIM``, else
    ``hw/simavr/build/plush-board-sim``. Raises :class:`HardwareError` saying how to build it."""
    return _existing(path, BINARY_ENV, _REPO_BINARY, "simulated board", executable=True)


def firmware_elf(path: str | os.PathLike | None = None) -> Path:
    """Path of the firmware ELF: ``path``, else ``$PLUSH_BOARD_FIRMWARE``, else
    ``hw/firmware/build/plush_winch.elf``. Raises :class:`HardwareError` saying how to build it."""
    return _existing(path, FIRMWARE_ENV, _REPO_FIRMWARE, "board firmware", executable=False)


class SimavrBoard(_emulator.Emulator):
    """The board firmware on a simulated Mega 2560, on a pseudo-terminal.

    Parameters
    ----------
    winches : int
        Motors connected to axes ``0 .. winches-1`` (1..4). The firmware
        itself always reports 4 axes; an axis without a motor never moves.
    speed : float
        Motor speed at full PWM, ticks/s (at most :data:`MAX_SPEED`; higher
        values are clipped, since the board's SPEED limits it anyway).
    tau : float
        Mechanical time constant of the motors, s.
    watchdog_ms, deadband : None
        Accepted for the :class:`~plush_opt.board.emulator.Emulator`
        interface; the firmware has its own (1000 ms, 3 ticks), so any
        other value is refused.
    state_file : path, optional
        Where the simulator writes the true motor state (JSON); a temporary
        file by default. See :meth:`read_state`.
    binary, firmware : path, optional
        The simulator (:func:`simavr_binary`) and the firmware ELF (:func:`firmware_elf`).

    :meth:`start`, :meth:`stop`, :meth:`close`, :attr:`running`,
    :attr:`pid` and the context manager are those of ``Emulator``.
    :meth:`read_state` returns what the simulator can see from outside
    the chip: ``time`` (simulated s), ``wall_time``, ``position`` (true
    motor positions, float ticks from power-up), ``ticks`` (encoder
    counts shown to the firmware), ``speed``, ``drive`` (PWM duty from
    -1 to 1), ``enabled`` (not braked), ``braked_time`` (simulated s at
    which each motor's brake last engaged, -1 if never),
    ``min_ticks``/``max_ticks``,
    ``last_rx_time`` (simulated time of the last byte from the host),
    ``rx_bytes``/``tx_bytes``/``dropped_bytes``. The firmware's internal
    state (targets, limits, stop counts) is only read through the protocol.
    """

    def __init__(self, winches: int = 4, *, speed: float = 3000.0, tau: float = 0.02,
                 watchdog_ms: int | None = None, deadband: int | None = None,
                 state_file: str | os.PathLike | None = None, state_interval_ms: int = 10,
                 binary: str | os.PathLike | None = None, firmware: str | os.PathLike | None = None,
                 extra_args=(), start_timeout: float = 5.0):
        if not 1 <= int(winches) <= MAX_MOTORS:
            raise HardwareError(f"simulated board: winches must be 1..{MAX_MOTORS} "
                                f"(motors the firmware drives), got {winches}")
        if watchdog_ms is not None or deadband is not None:
            raise HardwareError("simulated board: the firmware's watchdog (1000 ms at power-up, WDOG changes it) "
                                "and deadband (3 ticks) are built in; watchdog_ms and deadband cannot be set")
        sim = simavr_binary(binary)
        elf = firmware_elf(firmware)
        super().__init__(winches, speed=min(float(speed), MAX_SPEED), tau=tau, state_file=state_file,
                         state_interval_ms=state_interval_ms, binary=sim,
                         extra_args=["--firmware", str(elf), *extra_args], start_timeout=start_timeout)
        self.firmware = elf
        self.tau_s = float(tau)

    def __enter__(self) -> "SimavrBoard":
        self.start()
        return self
