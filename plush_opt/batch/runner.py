"""Map a function over inputs in worker processes, each input with its
own result and status, in input order.

Backends: ``serial`` (this process, one input after the other: ``jobs=1``),
``loky`` (joblib's process pool on this machine: ``jobs > 1``) and
``dask`` (a ``distributed`` scheduler: ``scheduler=`` an address or a
``Client``). Every backend calls the same wrapper around the function, with
BLAS and OpenMP limited to one thread inside it, so a result does not
depend on the backend, the number of workers or the order in which the
inputs finish: parallel results equal the serial run's bit for bit, as long
as the function depends on its input alone (no state kept between calls).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from ..base.errors import PlushError, one_line

log = logging.getLogger(__name__)

OK, FAILED, INTERRUPTED = "ok", "failed", "interrupted"
#: BLAS and OpenMP threads per worker: one solve per process, the processes fill the cores
WORKER_THREADS = 1


@dataclass(frozen=True)
class ItemResult:
    """The outcome of one input.

    Attributes
    ----------
    index : its position among the inputs.
    status : ``"ok"``, ``"failed"`` (the function raised; ``error`` says
        what) or ``"interrupted"`` (the batch was stopped before it finished).
    value : what the function returned (None unless ok).
    error : one line: the exception's message (a plush_opt error) or its type
        and message (anything else); empty when ok.
    details : the traceback of a failure (for a log), else empty.
    t_wall : seconds the function ran (in its worker).
    """

    index: int
    status: str
    value: Any = None
    error: str = ""
    details: str = field(default="", repr=False)
    t_wall: float = 0.0

    @property
    def ok(self) -> bool:
        return self.status == OK


@dataclass(frozen=True)
class BatchResult:
    """Every input's :class:`ItemResult`, in input order.

    Attributes
    ----------
    items : tuple of ItemResult, ``items[i]`` for input i.
    backend : ``"serial"``, ``"loky"`` or ``"dask"``.
    jobs : worker processes (Dask: the workers' threads, each one process
        slot when the workers run with ``--nthreads 1``).
    t_wall : seconds from the first submission to the last result.
    interruption : the KeyboardInterrupt (or plush_opt ``Interrupted``)
        that stopped the batch, None if it ran to the end; the items not
        finished then have status ``"interrupted"``.
    """

    items: tuple[ItemResult, ...]
    backend: str
    jobs: int
    t_wall: float
    interruption: BaseException | None = field(default=None, compare=False)

    @property
    def interrupted(self) -> bool:
        return self.interruption is not None

    @property
    def values(self) -> list:
        """The values, in input order (None where an input did not succeed)."""
        return [r.value for r in self.items]

    @property
    def failed(self) -> list[ItemResult]:
        return [r for r in self.items if r.status == FAILED]

    @property
    def finished(self) -> list[ItemResult]:
        return [r for r in self.items if r.status != INTERRUPTED]

    def raise_if_interrupted(self) -> None:
        """Re-raise the interruption (after the caller wrote what finished)."""
        if self.interruption is not None:
            raise self.interruption


def default_jobs() -> int:
    """The number of cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:       # not on Linux
        return max(1, os.cpu_count() or 1)


def check_jobs(jobs) -> int:
    """``jobs`` as an int >= 1 (None: :func:`default_jobs`); ValueError otherwise."""
    if jobs is None:
        return default_jobs()
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs: expected an integer >= 1, got {jobs!r}")
    return jobs


def call_item(fn: Callable, index: int, item) -> ItemResult:
    """Run ``fn(item)`` with one BLAS/OpenMP thread and turn what it
    returns or raises into an :class:`ItemResult` (the one wrapper of every
    backend). An interruption is not caught: it stops the batch."""
    from threadpoolctl import threadpool_limits
    t0 = time.perf_counter()
    with threadpool_limits(limits=WORKER_THREADS):
        try:
            value = fn(item)
        except Exception as exc:  # noqa: BLE001 - one failing input never stops the others
            message = str(exc) if isinstance(exc, PlushError) else f"{type(exc).__name__}: {exc}"
            return ItemResult(index, FAILED, None, one_line(message), traceback.format_exc(),
                              time.perf_counter() - t0)
    return ItemResult(index, OK, value, "", "", time.perf_counter() - t0)


def run_batch(fn: Callable, inputs: Iterable, *, jobs: int | None = None, scheduler=None,
              progress=None) -> BatchResult:
    """Call ``fn`` on every input in worker processes.

    Parameters
    ----------
    fn : a picklable function of one input (a module-level function, or a
        ``functools.partial`` of one) that depends on its input alone.
    inputs : the inputs (each picklable).
    jobs : worker processes on this machine (default: the number of cores;
        1 runs the inputs one after the other in this process). Ignored with
        ``scheduler``.
    scheduler : a ``distributed`` scheduler address (``"tcp://host:8786"``)
        or ``distributed.Client``: run on its workers instead.
    progress : an object with ``start(total, backend, jobs)``,
        ``update(item_result, done)`` and ``close()`` (see
        :class:`~plush_opt.batch.progress.Progress`), or None.

    Returns
    -------
    BatchResult, its items in input order. A failing input is an item with
    status ``"failed"``; Ctrl-C (or SIGTERM/SIGHUP under the command line)
    ends the workers and returns what finished, with ``interruption`` set:
    write it, then :meth:`BatchResult.raise_if_interrupted`.
    """
    inputs = list(inputs)
    if scheduler is not None:
        backend, workers = "dask", None
    else:
        workers = check_jobs(jobs)
        backend = "serial" if workers == 1 or len(inputs) <= 1 else "loky"
    slots: list[ItemResult | None] = [None] * len(inputs)
    t0 = time.perf_counter()
    interruption = None
    lost = ""          # the backend broke (a worker died): the inputs not finished failed
    done = 0

    def record(result: ItemResult) -> None:
        nonlocal done
        slots[result.index] = result
        done += 1
        if progress is not None:
            progress.update(result, done)

    run = {"serial": _serial, "loky": _loky, "dask": _dask}[backend]
    try:
        workers = run(fn, inputs, workers if scheduler is None else scheduler, record, progress)
    except KeyboardInterrupt as exc:      # plush_opt's Interrupted (SIGTERM, SIGHUP) is one too
        interruption = exc
        log.info("batch: interrupted after %d of %d inputs", done, len(inputs))
    except Exception as exc:  # noqa: BLE001 - a lost worker fails its inputs, not the batch's record
        lost = one_line(f"the {backend} backend failed: {type(exc).__name__}: {exc}")
        log.warning("batch: %s", lost)
    finally:
        if progress is not None:
            progress.close()
    missing = ItemResult(0, FAILED, error=lost) if lost else ItemResult(0, INTERRUPTED)
    items = tuple(r if r is not None else dataclasses.replace(missing, index=i)
                  for i, r in enumerate(slots))
    return BatchResult(items, backend, workers or 0, time.perf_counter() - t0, interruption)


def _serial(fn, inputs, jobs, record, progress) -> int:
    if progress is not None:
        progress.start(len(inputs), "serial", 1)
    for i, item in enumerate(inputs):
        record(call_item(fn, i, item))
    return 1


def _loky(fn, inputs, jobs, record, progress) -> int:
    from joblib import Parallel, delayed, parallel_config
    jobs = min(jobs, len(inputs))
    if progress is not None:
        progress.start(len(inputs), "loky", jobs)
    # one input per task (solves are long: balance beats batching); no
    # memory-mapping of arguments (read-only arrays would surprise fn)
    with parallel_config(backend="loky", inner_max_num_threads=WORKER_THREADS):
        results = Parallel(n_jobs=jobs, return_as="generator_unordered", batch_size=1,
                           pre_dispatch="n_jobs", max_nbytes=None)(
            delayed(call_item)(fn, i, item) for i, item in enumerate(inputs))
        try:
            for result in results:
                record(result)
        except KeyboardInterrupt:
            results.close()          # joblib aborts the tasks not started
            _kill_loky_workers()
            raise
    return jobs


def _kill_loky_workers() -> None:
    """End the pool's workers now (a solve in C++ would not see an interrupt)."""
    from joblib.externals.loky import get_reusable_executor
    try:
        get_reusable_executor().shutdown(wait=False, kill_workers=True)
    except Exception as exc:  # noqa: BLE001 - ending workers is best effort on the way out
        log.warning("batch: could not end the workers: %s", exc)


def _dask(fn, inputs, scheduler, record, progress) -> int:
    from distributed import Client, as_completed
    own = not isinstance(scheduler, Client)
    client = Client(scheduler) if own else scheduler
    futures = []
    try:
        slots = sum(client.nthreads().values())
        if progress is not None:
            progress.start(len(inputs), "dask", slots)
        futures = client.map(call_item, [fn] * len(inputs), range(len(inputs)), inputs, pure=False)
        index = {future.key: i for i, future in enumerate(futures)}
        for future in as_completed(futures):
            try:
                record(future.result())
            except Exception as exc:  # noqa: BLE001 - a lost worker (KilledWorker) fails its input alone
                record(ItemResult(index[future.key], FAILED,
                                  error=one_line(f"the dask worker failed: {type(exc).__name__}: {exc}")))
        return slots
    except KeyboardInterrupt:
        client.cancel(futures)
        raise
    finally:
        if own:
            client.close()
