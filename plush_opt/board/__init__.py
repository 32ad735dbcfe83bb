"""The winch board: protocol, calibration, serial driver and emulator.

Only this package (and :mod:`plush_opt.runs`, which uses it) talks to
hardware; nothing upstream imports it. See hw/PROTOCOL.md and
docs/hardware.md.
"""

from plush_opt.board.calibration import (BoardCalibration, PortSettings, WinchCalibration,
                                         calibration_from_dict, load_calibration)
from plush_opt.board.driver import Driver
from plush_opt.board.emulator import Emulator, emulator_binary
from plush_opt.board.protocol import BoardInfo, BoardState

__all__ = [
    "BoardCalibration", "BoardInfo", "BoardState", "Driver", "Emulator", "PortSettings", "WinchCalibration",
    "calibration_from_dict", "emulator_binary", "load_calibration",
]
