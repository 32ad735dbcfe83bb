"""Helpers of the board tests (imported by the test modules and conftest)."""

from __future__ import annotations

import os
import select
import signal
import threading
import time

import serial


def fast_calibration_dict(**port):
    """Three winches like the gripper's, but fast, so tests finish quickly.

    ``right`` runs backwards (direction -1) and ``grip`` has another gear,
    so conversions are exercised both ways.
    """
    def winch(name, axis, direction=1, gear=100, radius=6.0):
        return {"name": name, "axis": axis, "spool_radius": radius, "ticks_per_rev": 12, "gear_ratio": gear,
                "direction": direction, "limits": [0.0, 25.0], "max_speed": 200.0}
    return {"format": "plush-board/1", "name": "fast", "port": {"timeout": 0.3, "retries": 1, **port},
            "winches": [winch("left", 0), winch("right", 1, direction=-1), winch("grip", 2, gear=150, radius=4.0)]}


class RawPort:
    """A pyserial port with line helpers, for talking protocol by hand."""

    def __init__(self, path, timeout=1.0):
        self.ser = serial.Serial(path, 115200, timeout=timeout)
        self.ser.reset_input_buffer()

    def ask(self, line: str) -> str:
        self.ser.write(line.encode("latin-1") + b"\n")
        reply = self.ser.readline()
        if not reply.endswith(b"\n"):
            raise AssertionError(f"no reply to {line!r} (got {reply!r})")
        return reply.decode().rstrip("\n")

    def close(self):
        self.ser.close()


class FakeBoard:
    """A bare pseudo-terminal pair; a thread answers each line the host
    writes with ``handler(line) -> list of bytes`` (None: answer nothing)."""

    def __init__(self, handler=None):
        self.master, self._slave = os.openpty()
        self.port = os.ttyname(self._slave)
        self.handler = handler
        self.received = []
        self._stop = threading.Event()
        self._thread = None
        if handler is not None:
            self._thread = threading.Thread(target=self._serve, daemon=True)
            self._thread.start()

    def _serve(self):
        buf = b""
        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.01)
            if not r:
                continue
            try:
                buf += os.read(self.master, 1024)
            except OSError:
                return
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                if not line.strip():
                    continue                 # a blank line is ignored, as by the board
                self.received.append(line.decode())
                for out in self.handler(line.decode()) or ():
                    os.write(self.master, out)

    def close(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1)
        for fd in (self.master, self._slave):
            os.close(fd)


def default_sigint():
    """``preexec_fn`` for a child the test interrupts: SIGINT back to its
    default disposition, so that Python turns it into KeyboardInterrupt even
    when the suite itself was started with SIGINT ignored (as a background
    job of a non-interactive shell is)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def wait_until(predicate, timeout=3.0, interval=0.01):
    """Poll ``predicate()`` until true; return its last value."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value or time.monotonic() > deadline:
            return value
        time.sleep(interval)
