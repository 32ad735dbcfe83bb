"""The winch board: its serial protocol (protocol.py), the board file
(board_file.py: axes, ticks per length, limits, port), the allowed
contractions (limits.py), the serial driver (driver.py), the simulated
boards (emulator.py, simavr.py), the :class:`BoardLink` protocol the apps
hold (link.py) and its implementations over a serial port, a simulator or
a dry run (transports.py).

Only this package talks to hardware (serial ports, simulator processes);
nothing upstream imports it. Apps reach a board only through a
:class:`BoardLink` made by :func:`open_board` (a serial board, a simulator,
or a dry run), never through a :class:`Driver` or a simulator of their own.
See hw/PROTOCOL.md and docs/hardware.md.
"""

from plush_opt.board.board_file import (BoardCalibration, PortSettings, WinchCalibration,
                                         calibration_from_dict, load_calibration)
from plush_opt.board.driver import Driver
from plush_opt.board.emulator import Emulator, emulator_binary
from plush_opt.board.limits import allowed_ranges, check_contractions
from plush_opt.board.link import BoardLink
from plush_opt.board.transports import DryRunLink, SerialLink, SimulatorLink, open_board
from plush_opt.board.protocol import BoardInfo, BoardState

__all__ = [
    "BoardCalibration", "BoardInfo", "BoardLink", "BoardState", "Driver", "DryRunLink", "Emulator", "PortSettings",
    "SerialLink", "SimulatorLink", "WinchCalibration", "allowed_ranges", "calibration_from_dict",
    "check_contractions", "emulator_binary", "load_calibration", "open_board",
]
