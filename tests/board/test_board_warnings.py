"""A board that babbles does not flood the terminal: the same warning is
printed at most once a second, with the count of the ones held back."""

import logging

from plush_opt.board import driver


class BabblingPort:
    """A serial port whose board answers every command after ``noise`` lines."""

    def __init__(self, noise: bytes):
        self.noise, self.rx = noise, bytearray()

    @property
    def in_waiting(self):
        return len(self.rx)

    def reset_input_buffer(self):
        self.rx.clear()

    def write(self, data):
        seq = data.split()[0]
        self.rx += self.noise + seq + b" OK\n"

    def read(self, n):
        chunk = bytes(self.rx[:n])
        del self.rx[:n]
        return chunk


def _warnings(caplog):
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_a_babbling_board_gives_one_warning_a_second(caplog):
    caplog.set_level(logging.WARNING, logger=driver.__name__)
    io = driver._Transport("fake", 115200, timeout=5.0, retries=0)
    now = [0.0]
    io._warnings.clock = lambda: now[0]      # the test's clock: a loaded machine takes any time to read
    io.attach(BabblingPort(b"* ERR 1 bad line\n" * 20000))
    assert io.transact("PING").ok
    lines = _warnings(caplog)
    assert len(lines) == 1 and "board could not read a line: ERR 1" in lines[0], lines[:3]
    # held back until the port closes: said then, with the count
    caplog.clear()
    io._warnings.flush()
    lines = _warnings(caplog)
    assert len(lines) == 1 and "the last of 19999 held back" in lines[0], lines
    io._warnings.flush()
    assert len(_warnings(caplog)) == 1
    io.attach(BabblingPort(b"* ERR 1 bad line\n" * 20000))
    assert io.transact("PING").ok
    # a second later, the next one says how many were held back
    caplog.clear()
    now[0] += 1.0
    io.attach(BabblingPort(b"* ERR 1 bad line\n"))
    assert io.transact("PING").ok
    lines = _warnings(caplog)
    assert len(lines) == 1 and "20000 more like it held back" in lines[0], lines


def test_garbled_lines_are_limited_too(caplog):
    caplog.set_level(logging.WARNING, logger=driver.__name__)
    io = driver._Transport("fake", 115200, timeout=5.0, retries=0)
    io.attach(BabblingPort(b"?? garbage\n" * 5000))
    assert io.transact("PING").ok
    lines = _warnings(caplog)
    assert len(lines) == 1 and "garbled" in lines[0], lines[:3]
