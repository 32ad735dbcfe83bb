"""The implementations of the :class:`~plush_opt.board.link.BoardLink`
protocol (one per way of reaching a board), and :func:`open_board`, which
picks one.

- :class:`SerialLink`: a winch board on a serial port, through a
  :class:`~plush_opt.board.driver.Driver`.
- :class:`SimulatorLink`: the same over a simulated board (the host
  emulator, or the firmware under simavr) that the link starts, and stops
  when it closes. The one place a simulator is started for an app.
- :class:`DryRunLink`: checks and records every command, moves nothing.

Every link checks a command with
:func:`~plush_opt.board.limits.check_contractions` against the same
allowed ranges (the board file's limits within the scene's bounds,
intersected once when the link is made) before anything is sent.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from pathlib import Path

from plush_opt.board.board_file import BoardCalibration, load_calibration
from plush_opt.board.driver import Driver
from plush_opt.board.emulator import Emulator
from plush_opt.board.limits import allowed_ranges, check_contractions
from plush_opt.board.link import BoardLink
from plush_opt.board.protocol import BoardState
from plush_opt.base.errors import HardwareError

log = logging.getLogger(__name__)

SIMULATORS = ("emulator", "simavr")

EMULATOR_SPEED_FACTOR = 2
"""The emulated motors' top speed, as a multiple of the fastest calibrated
speed limit: the board's SPEED limit, not the motor, must be what limits."""

Bounds = Mapping[str, tuple[float, float]]


class SerialLink:
    """A :class:`BoardLink` over a winch board on a serial port.

    Opens the port and configures the board on construction (see
    :meth:`Driver.open`); :meth:`close` stops the winches and closes it.
    Besides positions, every read checks that the board has not stopped
    on its own: a watchdog trip or a commanded winch disabled is a
    :class:`HardwareError`.

    Parameters
    ----------
    port : serial device path.
    calibration : the board's calibration.
    bounds : the scene's winch bounds ``{name: (lower, upper)}``, optional.
    driver_options : passed to :class:`Driver` (``timeout``, ``retries``, ...).
    """

    def __init__(self, port: str, calibration: BoardCalibration, *, bounds: Bounds | None = None,
                 **driver_options):
        self.calibration = calibration
        self.driver = Driver(port, calibration, bounds=bounds, **driver_options)
        self.driver.open()
        try:
            self._watchdog_trips = self.driver.read_state().watchdog_trips
        except BaseException:
            self.driver.close()
            raise
        self._commanded: dict[str, float] = {}   # since the last stop: {winch: contraction}

    @property
    def port(self) -> str:
        return self.driver.port

    @property
    def winch_names(self) -> tuple[str, ...]:
        return self.calibration.winch_names

    @property
    def allowed(self) -> dict[str, tuple[float, float]]:
        """Allowed contraction per winch: calibration limits within the scene's bounds."""
        return self.driver.allowed

    def send(self, contraction: Mapping[str, float]) -> None:
        self.driver.set_contractions(contraction)
        self._commanded.update({n: float(v) for n, v in contraction.items()})

    def _state(self) -> BoardState:
        """The board's state, after checking it did not stop by itself."""
        state = self.driver.read_state()
        if state.watchdog_trips > self._watchdog_trips:
            self._watchdog_trips = state.watchdog_trips
            self._commanded.clear()
            raise HardwareError(f"{self.port}: the board's watchdog stopped the motors (no command for "
                                f"{self.driver.watchdog_ms} ms while moving); the host stalled")
        for name, target in self._commanded.items():
            if not state.enabled[self.calibration.winch(name).axis]:
                self._commanded.clear()
                raise HardwareError(f"{self.port}: the board stopped winch {name!r} before it reached "
                                    f"its commanded contraction {target:.2f}")
        return state

    def positions(self) -> dict[str, float]:
        return self.driver.positions_mm(self._state())

    def moving(self) -> bool:
        state = self._state()
        return any(state.moving[w.axis] for w in self.calibration.winches)

    def stop(self) -> None:
        self.driver.halt()
        self._commanded.clear()

    def clock(self) -> float:
        """The board's time, s: what a wait for a move should be measured in."""
        return time.monotonic()

    def close(self) -> None:
        self._commanded.clear()
        self.driver.close()

    def __enter__(self) -> "SerialLink":
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _simulator(kind: str, calibration: BoardCalibration):
    """An unstarted simulated board with every calibrated axis."""
    top = EMULATOR_SPEED_FACTOR * max(w.speed_ticks for w in calibration.winches)
    if kind == "emulator":
        return Emulator(winches=calibration.n_axes_required, speed=top)
    if kind == "simavr":
        from plush_opt.board.simavr import SimavrBoard   # needs simavr; only when asked for
        return SimavrBoard(calibration.n_axes_required, speed=top)   # capped at the harness's limit
    raise HardwareError(f"simulator: must be one of {', '.join(map(repr, SIMULATORS))}, got {kind!r}")


class SimulatorLink(SerialLink):
    """A :class:`BoardLink` over a simulated board that the link runs.

    Starts the simulator (``"emulator"``: hw/emulator's host build;
    ``"simavr"``: the firmware on simulated AVR), then a :class:`Driver` on
    its pseudo-terminal. The simulator runs in its own session, so a Ctrl-C
    reaches the host, which stops the board first; on Linux it is killed if
    the host dies. :meth:`close` stops the winches, then the simulator.
    ``simulator_process`` is the simulator object (the emulator's
    ``read_state`` shows the true motor positions).
    """

    def __init__(self, calibration: BoardCalibration, simulator: str = "emulator", *,
                 bounds: Bounds | None = None, **driver_options):
        self.kind = simulator
        self.simulator_process = _simulator(simulator, calibration)
        try:
            port = self.simulator_process.start()
            super().__init__(port, calibration, bounds=bounds, **driver_options)
        except BaseException:
            self.simulator_process.close()
            raise

    def clock(self) -> float:
        """The simulator's own time, s: on a loaded machine simavr runs slower
        than the wall clock, and its motors with it."""
        return float(self.simulator_process.read_state(fresh=False)["time"])

    def close(self) -> None:
        try:
            super().close()
        finally:
            self.simulator_process.close()


class DryRunLink:
    """A :class:`BoardLink` that checks and records commands and moves nothing.

    ``sent`` lists every accepted command as ``(contraction, ticks)``;
    ``commanded`` is the last contraction of every winch commanded so far.
    It cannot measure: :meth:`positions` is None and nothing is ever moving.
    """

    def __init__(self, calibration: BoardCalibration, *, bounds: Bounds | None = None):
        self.calibration = calibration
        self._allowed = allowed_ranges(calibration, bounds)
        self.sent: list[tuple[dict[str, float], dict[str, int]]] = []
        self.commanded: dict[str, float] = {}
        self.stops = 0
        self.closed = False

    @property
    def winch_names(self) -> tuple[str, ...]:
        return self.calibration.winch_names

    @property
    def allowed(self) -> dict[str, tuple[float, float]]:
        return dict(self._allowed)

    def send(self, contraction: Mapping[str, float]) -> None:
        ticks = check_contractions(contraction, self._allowed, self.calibration)
        values = {n: float(v) for n, v in contraction.items()}
        self.sent.append((values, ticks))
        self.commanded.update(values)

    def positions(self) -> None:
        return None

    def moving(self) -> bool:
        return False

    def stop(self) -> None:
        self.stops += 1

    def clock(self) -> float:
        return time.monotonic()

    def close(self) -> None:
        self.closed = True

    def __enter__(self) -> "DryRunLink":
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def open_board(calibration: BoardCalibration | str | os.PathLike, *, port: str | None = None,
               simulator: str | None = None, bounds: Bounds | None = None) -> BoardLink:
    """Open the board an app asked for.

    Parameters
    ----------
    calibration : a :class:`BoardCalibration` or the path of a calibration file.
    port : serial device of a real board.
    simulator : None, ``"emulator"`` (the host emulator) or ``"simavr"``
        (the firmware on simulated AVR).
    bounds : the scene's winch bounds ``{name: (lower, upper)}``, optional;
        intersected with the calibration's limits, once, here.

    With neither ``port`` nor ``simulator``: a :class:`DryRunLink`. The
    link is open; close it (or use it as a context manager) to stop the
    winches and release the port and any simulator.
    """
    if not isinstance(calibration, BoardCalibration):
        calibration = load_calibration(Path(calibration))
    if port is not None and simulator is not None:
        raise HardwareError(f"give a serial port or a simulator, not both (port {port!r}, simulator {simulator!r})")
    if simulator is not None:
        return SimulatorLink(calibration, simulator, bounds=bounds)
    if port is not None:
        return SerialLink(os.fspath(port), calibration, bounds=bounds)
    return DryRunLink(calibration, bounds=bounds)
