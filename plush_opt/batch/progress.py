"""What a batch shows while it runs: a progress bar on a terminal, one
line per finished input otherwise (a log file, a pipe, a batch job)."""

from __future__ import annotations

import sys
from collections.abc import Callable

from .runner import OK


class Progress:
    """Progress of a batch on ``stream`` (default stderr).

    Parameters
    ----------
    label : what runs, at the start of every line (``"study"``).
    describe : index -> a short text naming that input (default ``#i``).
    stream : where to write (default ``sys.stderr``).
    bar : a tqdm bar (True), lines (False), or bar on a terminal only (None).

    A failure is always written as its own line, with the input and the error.
    """

    def __init__(self, label: str, describe: Callable[[int], str] | None = None, stream=None,
                 bar: bool | None = None):
        self.label = label
        self.describe = describe or (lambda i: f"#{i}")
        self.stream = stream if stream is not None else sys.stderr
        self.bar = bar
        self.total = 0
        self._tqdm = None

    def start(self, total: int, backend: str, jobs: int) -> None:
        self.total = total
        use_bar = self.bar if self.bar is not None else bool(getattr(self.stream, "isatty", lambda: False)())
        where = "in this process" if backend == "serial" else f"on {jobs} {backend} worker(s)"
        self.write(f"{self.label}: {total} input(s) {where}")
        if use_bar:
            from tqdm import tqdm
            self._tqdm = tqdm(total=total, desc=self.label, file=self.stream, unit="item",
                              dynamic_ncols=True)

    def write(self, line: str) -> None:
        if self._tqdm is not None:
            self._tqdm.write(line, file=self.stream)
        else:
            print(line, file=self.stream, flush=True)

    def update(self, result, done: int) -> None:
        what = f"{self.label}: [{done}/{self.total}] {self.describe(result.index)}"
        if self._tqdm is not None:
            self._tqdm.update(1)
            if not result.ok:
                self.write(f"{what}: {result.status}: {result.error}")
            return
        tail = f"ok ({result.t_wall:.1f} s)" if result.status == OK else f"{result.status}: {result.error}"
        self.write(f"{what}: {tail}")

    def close(self) -> None:
        if self._tqdm is not None:
            self._tqdm.close()
            self._tqdm = None
