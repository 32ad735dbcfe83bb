"""Many independent solves at once (docs/study.md): :func:`run_batch`
maps a function over inputs in worker processes (joblib/loky on this
machine, Dask across machines), one solve per process at a time with BLAS
and OpenMP threads at 1, and returns every input's own result and status
in input order, the same bit for bit as a serial run; a failing input
never stops the others and an interruption keeps what finished.
:mod:`.study` builds on it: one problem file solved at every combination
of varied parameters (``plush-opt study``); :mod:`.multistart` fits a
calibration from several starting points (``plush-opt calibrate --starts``).

Sits above the problem facade (its items build problems) and below the
apps, which draw and print what it returns. CasADi and IPOPT are never
driven from threads here: only processes.
"""

from .runner import BatchResult, ItemResult, default_jobs, run_batch

__all__ = ["BatchResult", "ItemResult", "default_jobs", "run_batch"]
