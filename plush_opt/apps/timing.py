"""Timings for the benchmarks: the median of repeated calls."""

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
