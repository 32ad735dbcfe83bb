"""The log and the progress line of a scripted run (:mod:`plush_opt.apps.runs`)."""

from __future__ import annotations

import errno
import json
import math
import os
import shutil
import stat
import time
from pathlib import Path

import numpy as np

PROGRESS_INTERVAL = 0.1   # s between progress line updates: readable, and cheap on a slow terminal


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None  # strict JSON has no NaN
    if x is None or isinstance(x, str):
        return x
    return str(x)


class RunLog:
    """JSON-lines file; every line is written whole, flushed and fsync'ed,
    so a crash or Ctrl-C leaves only complete lines.

    A line that cannot be written whole (a full disk, a signal between two
    partial writes) is cut off again: the file is truncated back to its
    last complete line, and the error (an :class:`OSError` whose
    ``filename`` is the log's path) or the interruption goes on.
    """

    def __init__(self, path):
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = open(self.path, "wb", buffering=0)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot write the run log: {exc.strerror or exc}", str(self.path)) from None
        # A pipe or /dev/null cannot be fsync'ed (nor truncated), and needs not be.
        self._sync = stat.S_ISREG(os.fstat(self._f.fileno()).st_mode)
        self._end = 0            # bytes of complete lines
        self.lines = 0

    def write(self, obj: dict) -> None:
        data = memoryview((json.dumps(_jsonable(obj), allow_nan=False, separators=(",", ":"))
                           + "\n").encode())
        try:
            while data:   # an unbuffered write may take only part of the line
                written = os.write(self._f.fileno(), data)
                if not written:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                data = data[written:]
            if self._sync:
                os.fsync(self._f.fileno())
        except BaseException as exc:
            self._cut()
            if isinstance(exc, OSError):
                raise OSError(exc.errno, f"cannot write the run log: {exc.strerror or exc} "
                              f"(it ends with its last complete line)", str(self.path)) from None
            raise
        self._end = os.lseek(self._f.fileno(), 0, os.SEEK_CUR) if self._sync else self._end
        self.lines += 1

    def _cut(self) -> None:
        """Truncate a partly written line (a regular file only)."""
        if not self._sync:
            return
        try:
            os.ftruncate(self._f.fileno(), self._end)
            os.lseek(self._f.fileno(), self._end, os.SEEK_SET)
        except OSError:
            pass     # the error being raised says more than this one

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class ProgressLine:
    """One updating status line on a terminal (the CLI's progress display)."""

    def __init__(self, stream, enabled: bool):
        self.stream = stream
        self.enabled = enabled
        self._shown = False
        self._last = 0.0

    def update(self, text: str) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < PROGRESS_INTERVAL:
            return
        self._last = now
        width = max(20, shutil.get_terminal_size((100, 20)).columns - 1)
        self.stream.write("\r" + text[:width] + "\x1b[K")
        self.stream.flush()
        self._shown = True

    def finish(self) -> None:
        if self._shown:
            self.stream.write("\n")
            self.stream.flush()
            self._shown = False
