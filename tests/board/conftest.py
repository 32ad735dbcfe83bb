"""Fixtures of the board tests: the emulator, the simulated firmware, a fast
calibration, fake boards.

The emulator binary is built by ``make -C hw``, the firmware and its
simulator by ``make -C hw firmware simavr`` (``make test`` does both
first). If one is missing, the tests that need it fail with that message;
they are never skipped.

The ``board`` fixture is parametrised over both boards: the protocol core
compiled for the host (``emulator``) and the AVR binary on simavr
(``simavr``), so one test checks both.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from board_helpers import FakeBoard, RawPort, fast_calibration_dict
from plush_opt.board.board_file import calibration_from_dict
from plush_opt.board.emulator import Emulator, emulator_binary
from plush_opt.board.simavr import SimavrBoard, firmware_elf, simavr_binary
from plush_opt.base.errors import HardwareError

BOARDS = ["emulator", "simavr"]
BOARD_AXES = 4        # both boards of the shared tests report 4 axes, as the firmware always does


@pytest.fixture
def calibration():
    return calibration_from_dict(fast_calibration_dict(), source="fast.yaml")


@pytest.fixture(scope="session")
def emu_binary() -> Path:
    try:
        return emulator_binary()
    except HardwareError as e:
        pytest.fail(f"{e} (make test builds it before running the tests)", pytrace=False)


@pytest.fixture
def make_emulator(emu_binary):
    """``make_emulator(winches=3, **options)`` -> started :class:`Emulator`, stopped after the test."""
    started = []

    def make(winches=3, **kw):
        kw.setdefault("speed", 20000.0)
        kw.setdefault("tau", 0.01)
        emu = Emulator(winches, binary=emu_binary, **kw)
        started.append(emu)
        emu.start()
        return emu

    yield make
    for emu in started:
        emu.close()


@pytest.fixture
def emulator(make_emulator):
    return make_emulator(3)


@pytest.fixture(scope="session")
def sim_binaries() -> tuple[Path, Path]:
    try:
        return simavr_binary(), firmware_elf()
    except HardwareError as e:
        pytest.fail(f"{e} (make test builds them before running the tests)", pytrace=False)


@pytest.fixture
def make_simavr(sim_binaries):
    """``make_simavr(winches=4, **options)`` -> started :class:`SimavrBoard`, stopped after the test."""
    started = []

    def make(winches=4, **kw):
        sim = SimavrBoard(winches, binary=sim_binaries[0], firmware=sim_binaries[1], **kw)
        started.append(sim)
        sim.start()
        return sim

    yield make
    for sim in started:
        sim.close()


@dataclass
class BoardUnderTest:
    """A started board and what the shared tests may expect of it."""

    kind: str            # "emulator" or "simavr"
    sim: object          # the Emulator or SimavrBoard
    name: str            # ID's board=
    deadband: int        # ticks
    stops_on_hangup: bool  # the emulator sees the host close the port; the firmware does not

    @property
    def port(self) -> str:
        return self.sim.port

    def coast(self, speed: float) -> float:
        """Ticks the motor may run on past a target reached at ``speed`` ticks/s.

        None, on both boards: the firmware's control law (which the emulator
        runs too) brakes before the target by what the motor would still
        travel at its measured speed (test_board_overshoot.py sweeps it).
        """
        return 0.0

    def read_state(self, fresh: bool = True) -> dict:
        return self.sim.read_state(fresh=fresh)


def start_board(kind, make_emulator, make_simavr) -> BoardUnderTest:
    if kind == "emulator":
        return BoardUnderTest(kind, make_emulator(BOARD_AXES, deadband=3), "plush-winch-emu", 3, True)
    return BoardUnderTest(kind, make_simavr(BOARD_AXES), "plush-winch", 3, False)


@pytest.fixture(params=BOARDS)
def board(request, make_emulator, make_simavr) -> BoardUnderTest:
    """A started 4-axis board of each kind (both with the firmware's 3-tick deadband)."""
    return start_board(request.param, make_emulator, make_simavr)


@pytest.fixture
def raw_port():
    """``raw_port(path)`` -> :class:`RawPort`, closed after the test."""
    opened = []

    def open_(path, timeout=1.0):
        p = RawPort(path, timeout)
        opened.append(p)
        return p

    yield open_
    for p in opened:
        p.close()


@pytest.fixture
def fake_board():
    """``fake_board(handler)`` -> :class:`FakeBoard`, closed after the test."""
    boards = []

    def make(handler=None):
        b = FakeBoard(handler)
        boards.append(b)
        return b

    yield make
    for b in boards:
        b.close()
