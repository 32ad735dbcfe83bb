"""Timings for the benchmarks: the median of repeated calls, the CPU time
of a function's calls inside a larger one, and a model's factorisations
counted."""

from __future__ import annotations

import time

import numpy as np


def median_time(fn, repeats: int) -> tuple[float, object]:
    """(median wall seconds of ``repeats`` calls of ``fn``, its last result)."""
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def timed_into(parts: dict, fn, seconds: str, count: str | None = None):
    """``fn`` wrapped to add the CPU seconds of each call to
    ``parts[seconds]`` (and 1 to ``parts[count]``, if named), raised or not."""
    def call(*args, **kwargs):
        t = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            parts[seconds] += time.process_time() - t
            if count is not None:
                parts[count] += 1
    return call


def counting_factorisations(model) -> dict:
    """Wrap ``model``'s factoriser so that each factorisation adds 1 to the
    returned ``{"n": ..., "s": ...}`` and its CPU seconds to ``"s"``;
    ``del model.factorizer.factor`` restores it."""
    count = {"n": 0, "s": 0.0}
    model.factorizer.factor = timed_into(count, model.factorizer.factor, "s", "n")
    return count
