"""Fixtures of the board tests: the emulator, a fast calibration, fake boards.

The emulator binary is built by ``make -C hw`` (``make test`` does it
first). If it is missing, the tests that need it fail with that message;
they are never skipped.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from board_helpers import FakeBoard, RawPort, fast_calibration_dict
from plush_opt.board.calibration import calibration_from_dict
from plush_opt.board.emulator import Emulator, emulator_binary
from plush_opt.errors import HardwareError


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
