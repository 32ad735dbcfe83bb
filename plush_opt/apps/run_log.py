"""The log and the progress line of a scripted run (:mod:`plush_opt.apps.runs`)."""

from __future__ import annotations

import errno
import fcntl
import json
import math
import os
import shutil
import stat
import time
from pathlib import Path

import numpy as np

from ..base.errors import SceneError, one_line
from ..io.checker import Checker, at_index, parse_json

MAX_LOG_BYTES = 1 << 30   # a run log read back: a day at 1 kHz is well under; larger is not a log
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
            # not truncated before it is locked: a log in use stays whole
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
            self._f = os.fdopen(fd, "wb", buffering=0)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot write the run log: {exc.strerror or exc}", str(self.path)) from None
        # A pipe or /dev/null cannot be fsync'ed (nor truncated), and needs not be.
        self._sync = stat.S_ISREG(os.fstat(self._f.fileno()).st_mode)
        if self._sync:
            self._lock()
        self._end = 0            # bytes of complete lines
        self.lines = 0

    def _lock(self) -> None:
        """Hold the log for this run (a lock released when it is closed, or
        when the process dies), then empty it: a log another run holds is a
        :class:`SceneError`, and that run's log is left whole."""
        try:
            fcntl.flock(self._f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            self._f.close()
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise SceneError(f"{one_line(self.path)}: the run log is in use by another run "
                                 "(give this run another --log)") from None
            raise OSError(exc.errno, f"cannot lock the run log: {exc.strerror or exc}", str(self.path)) from None
        os.ftruncate(self._f.fileno(), 0)

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


def read_run_log(path, winches=None) -> list[dict]:
    """The lines of a run log, each checked as export reads them: a JSON
    object with a time ``t`` (a finite number >= 0), ``event`` and ``kind``
    (strings) and ``commanded`` (null, or ``winches`` mapped to finite
    numbers); the first line the start line, naming its problem file and
    its winches (the default ``winches``). Anything else is one
    :class:`SceneError` line naming the file, the line and the key; nothing
    is repaired."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_LOG_BYTES:
            raise SceneError(f"{path}: larger than {MAX_LOG_BYTES} bytes: not a run log of plush-opt run")
        raw = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"{path}: cannot read the run log: {exc.strerror or exc}") from None
    lines = raw.splitlines()
    if not lines:
        raise SceneError(f"{path}: empty: not a run log of plush-opt run")
    rows = []
    for n, line in enumerate(lines, start=1):
        ck = Checker(f"{path}: line {n}")
        row = parse_json(line, ck)
        if not isinstance(row, dict):
            ck.fail("", f"expected a JSON object (a line of a run log of plush-opt run), got "
                    f"{'a list' if isinstance(row, list) else type(row).__name__}")
        if n == 1:
            winches = _start_line(ck, row, winches)
        ck.mapping(row, "", tuple(row), required=("t", "event", "kind"))
        ck.number(row["t"], "t", ge=0)
        ck.string(row["event"], "event")
        ck.string(row["kind"], "kind")
        if row.get("commanded") is not None:
            ck.numbers(row["commanded"], "commanded", winches)
        rows.append(row)
    return rows


def _start_line(ck: Checker, row: dict, winches) -> tuple[str, ...]:
    """The winches a run log's start line names (and its problem file
    checked), or ``winches`` if given."""
    if row.get("kind") != "start":
        ck.fail("kind", "not the start line of a run log (plush-opt run writes it first)")
    if winches is not None:
        return tuple(winches)
    ck.name(row.get("problem"), "problem")
    names = ck.seq(row.get("winches"), "winches", min_len=1, what="list of winch names")
    return tuple(ck.name(w, at_index("winches", i)) for i, w in enumerate(names))


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
