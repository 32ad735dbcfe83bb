"""A calibration from several starting points at once: each start's fit
in its own worker (:func:`~plush_opt.batch.runner.run_batch`), the best
one fitted again here for the whole result (``plush-opt calibrate
--starts N``, docs/calibration.md)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..base.errors import SolverError
from ..fit.job import calibrate
from ..fit.parameters import Values, parse_fit
from ..fit.starts import fit_cost, starting_values
from .runner import run_batch

#: costs within this relative difference are one minimum found twice: the earliest start wins
COST_TIE = 1e-9


@dataclass(frozen=True)
class StartOutcome:
    """One start's fit: ``index``, its ``start`` values of the fitted
    parameters (name -> value), ``identifiable``, ``converged``,
    ``status``, ``cost`` (what the fit minimised; NaN when refused or
    failed), ``iterations`` and ``fitted`` (name -> value at its end)."""

    index: int
    start: dict
    identifiable: bool
    converged: bool
    status: str
    cost: float
    iterations: int
    fitted: dict


def _named(values: Values, params) -> dict:
    return {p.name: float(values.get(p)) for p in params}


def fit_from_start(job: tuple, meas, fit_spec, options, max_area) -> StartOutcome:
    """One input of the batch: ``job`` (index, start Values)."""
    k, start = job
    result = calibrate(meas, fit_spec, options, max_area=max_area, start=start)
    cost = fit_cost(meas, result, options.huber) if result.identifiable else math.nan
    return StartOutcome(k, _named(start, result.params), result.identifiable, result.converged,
                        result.status, float(cost), int(result.iterations),
                        _named(result.after.values, result.params))


def calibrate_from_starts(meas, fit_spec, options, n_starts: int, *, max_area: float | None = None,
                          jobs=None, scheduler=None, progress=None):
    """Fit from ``n_starts`` starting points
    (:func:`~plush_opt.fit.starts.starting_values`; the first is the
    scene's) and keep the lowest cost among the identifiable fits, the
    earliest start on a tie (:data:`COST_TIE`).

    Returns
    -------
    (FitResult, list of StartOutcome in start order, the best start's index).
    The FitResult is that start's fit made again in this process (the same
    computation, so the same numbers), its ``before`` at that start.
    A start that failed has status ``failed: ...``; if every start failed,
    a :class:`SolverError` says why the first did.
    """
    params = parse_fit(meas.scene, fit_spec)
    starts = starting_values(Values.of_scene(meas.scene), params, n_starts)
    batch = run_batch(functools.partial(fit_from_start, meas=meas, fit_spec=fit_spec, options=options,
                                        max_area=max_area), list(enumerate(starts)), jobs=jobs,
                      scheduler=scheduler, progress=progress)
    batch.raise_if_interrupted()
    outcomes = []
    for k, item in enumerate(batch.items):
        if item.ok:
            outcomes.append(item.value)
        else:
            outcomes.append(StartOutcome(k, _named(starts[k], params), False, False,
                                         f"{item.status}: {item.error}", math.nan, 0, {}))
    if all(not item.ok for item in batch.items):
        raise SolverError(f"calibration: every start failed; the first: {batch.items[0].error}")
    ranked = [o for o in outcomes if o.identifiable and math.isfinite(o.cost)]
    best = 0
    if ranked:
        low = min(o.cost for o in ranked)
        best = next(o.index for o in ranked if o.cost <= low + COST_TIE * abs(low))
    result = calibrate(meas, fit_spec, options, max_area=max_area, start=starts[best])
    return result, outcomes, best


def starts_table(outcomes, best: int) -> list[str]:
    """One line per start: its values, cost, status (the best marked)."""
    lines = []
    for o in outcomes:
        where = ", ".join(f"{n}={v:.4g}" + (f" -> {o.fitted[n]:.6g}" if n in o.fitted else "")
                          for n, v in o.start.items() if not n.startswith("assembly"))
        cost = "n/a" if not np.isfinite(o.cost) else f"{o.cost:.6g}"
        lines.append(f"{'*' if o.index == best else ' '} start {o.index}: {where or 'scene values'}; "
                     f"cost {cost}, {o.iterations} iterations, {o.status}")
    return lines
