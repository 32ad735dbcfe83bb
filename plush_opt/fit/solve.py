"""Levenberg-Marquardt on the weighted marker residuals.

Residuals r = (y(theta) - y_measured) / sigma over the seen markers of the
fitted poses (held-out poses are predicted, never fitted). Optionally a
Huber loss per marker (threshold ``huber`` in sigma units) down-weights
outliers by iteratively reweighted least squares. The covariance of theta
is the Gauss-Newton (J^T W J)^-1, absolute because r is already in sigma
units; values' standard errors follow by the delta method.

Before fitting, the Jacobian at the start is checked: if its columns,
each scaled to unit length, are nearly dependent, the set of parameters is
not identifiable from these poses and markers, and the fit is refused with
the dependent combination named, rather than fitted to noise.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..base.errors import SolverError
from .parameters import Parameter, dvalue_dtheta, to_theta
from .predict import Prediction, Predictor

#: scaled Jacobian with s_min / s_max below this: not identifiable (a
#: direction in parameter space the markers cannot see beyond round-off
#: of the sensitivities and the noise)
IDENTIFIABLE_RCOND = 1e-5
#: a combination's members: entries of the null vector at least this
#: fraction of its largest entry
COMBINATION_SHARE = 0.2
#: fitted parameters correlated beyond this get a warning
HIGH_CORRELATION = 0.995


@dataclass(frozen=True)
class FitOptions:
    """Levenberg-Marquardt options.

    max_iterations : accepted or rejected steps, at most.
    damping : initial Marquardt factor lambda (times diag(J^T J)).
    ftol : stop when a step lowers the cost by less than ftol * cost.
    step_tol : stop when the step changes chi^2 (along J) by less than this:
        1e-4 moves theta by about 1 % of a standard error.
    max_damping : give up when lambda grows beyond this (no descent found).
    huber : Huber threshold in sigma units (None: least squares).
    holdout : pose indices predicted but not fitted.
    """

    max_iterations: int = 40
    damping: float = 1e-3
    ftol: float = 1e-10
    step_tol: float = 1e-4
    max_damping: float = 1e10
    huber: float | None = None
    holdout: tuple[int, ...] = ()


@dataclass(frozen=True)
class FitResult:
    """What a calibration found.

    identifiable : False when refused (then ``after`` is ``before``).
    combination : the dependent parameter combination when not identifiable
        (or the weakest one of a near-singular fit), as text.
    theta, values : fitted internal coordinates and values.
    covariance : (n_params, n_params) of theta (None if not identifiable).
    before, after : predictions at the start and at the fit.
    """

    params: tuple[Parameter, ...]
    identifiable: bool
    converged: bool
    status: str
    before: Prediction
    after: Prediction
    covariance: np.ndarray | None
    iterations: int
    solves: int
    t_wall: float
    combination: str = ""
    warnings: tuple[str, ...] = ()
    fitted_poses: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @property
    def standard_errors(self) -> np.ndarray:
        """Of the values (natural units), by the delta method."""
        if self.covariance is None:
            return np.full(len(self.params), np.nan)
        se = np.sqrt(np.maximum(np.diag(self.covariance), 0))
        return np.array([s * dvalue_dtheta(p, self.after.values.get(p))
                         for p, s in zip(self.params, se)])

    @property
    def correlation(self) -> np.ndarray | None:
        return None if self.covariance is None else _correlation(self.covariance)


def _correlation(cov: np.ndarray) -> np.ndarray:
    s = np.sqrt(np.maximum(np.diag(cov), np.finfo(float).tiny))
    return cov / np.outer(s, s)


class _Residuals:
    """Normalised residuals of the fitted poses' seen markers."""

    def __init__(self, meas, fitted: np.ndarray, huber: float | None):
        self.sigma = meas.sigma
        self.measured = meas.positions
        mask = meas.seen & fitted[:, None]                       # (n_poses, n_markers)
        self.rows = np.repeat(mask.reshape(-1), 2)               # flat over (pose, marker, xy)
        self.huber = huber

    def __call__(self, pred: Prediction):
        """(cost, weighted residual, weighted Jacobian or None)."""
        r = ((pred.y - self.measured) / self.sigma).reshape(-1)[self.rows]
        norms = np.hypot(r[0::2], r[1::2])
        if self.huber is None:
            w, cost = np.ones_like(norms), 0.5 * float(r @ r)
        else:
            k = self.huber
            w = np.where(norms <= k, 1.0, k / np.maximum(norms, k))
            cost = float(np.sum(np.where(norms <= k, 0.5 * norms**2, k * norms - 0.5 * k * k)))
        sw = np.repeat(np.sqrt(w), 2)
        J = None
        if pred.jacobian is not None:
            J = (pred.jacobian.reshape(-1, pred.jacobian.shape[2]) / self.sigma)[self.rows] * sw[:, None]
        return cost, r * sw, J


def check_identifiable(J: np.ndarray, params) -> tuple[bool, str, float]:
    """(identifiable, the weakest combination as text, its relative singular value)."""
    norms = np.linalg.norm(J, axis=0)
    dead = np.flatnonzero(norms == 0)
    if dead.size:
        return False, f"{params[dead[0]].name} (moves no marker in any fitted pose)", 0.0
    _, s, vt = np.linalg.svd(J / norms, full_matrices=False)
    v = vt[-1] / norms          # back to theta units
    v = v / np.max(np.abs(v))
    if v[np.argmax(np.abs(v))] < 0:
        v = -v
    terms = [f"{'+' if c > 0 else '-'} {abs(c):.3g} {p.name}"
             for p, c in zip(params, v) if abs(c) >= COMBINATION_SHARE]
    text = " ".join(terms).lstrip("+ ")
    rcond = float(s[-1] / s[0])
    return rcond >= IDENTIFIABLE_RCOND, text, rcond


def fit(predictor: Predictor, options: FitOptions | None = None) -> FitResult:
    """Fit ``predictor.params`` to ``predictor.meas`` from the base values."""
    options = options or FitOptions()
    t0 = time.perf_counter()
    meas, params = predictor.meas, predictor.params
    fitted = np.ones(meas.n_poses, bool)
    fitted[list(options.holdout)] = False
    res = _Residuals(meas, fitted, options.huber)
    theta = np.array([to_theta(p, predictor.base.get(p)) for p in params])
    before = predictor(theta)
    predictor.accept(before)
    cost, r, J = res(before)
    if J.shape[0] < len(params):
        raise SolverError(f"{meas.source}: {J.shape[0]} measured coordinates cannot fit "
                          f"{len(params)} parameters")
    ok, combination, rcond = check_identifiable(J, params)
    if not ok:
        return FitResult(params, False, False, f"not identifiable: {combination}", before, before,
                         None, 0, predictor.solves, time.perf_counter() - t0, combination,
                         (f"not identifiable from these poses and markers (relative singular "
                          f"value {rcond:.2g}): {combination}; not fitted",), fitted)
    current, cost, r, J, it, converged, status = _levenberg_marquardt(
        predictor, res, before, cost, r, J, options)
    ok, combination, rcond = check_identifiable(J, params)
    warnings = []
    if not ok:
        warnings.append(f"near-singular at the fit (relative singular value {rcond:.2g}): "
                        f"{combination}")
    cov = np.linalg.pinv(J.T @ J)
    corr = _correlation(cov)
    for a in range(len(params)):
        for b in range(a + 1, len(params)):
            if abs(corr[a, b]) > HIGH_CORRELATION:
                warnings.append(f"{params[a].name} and {params[b].name} are correlated "
                                f"({corr[a, b]:+.4f}): the data barely tell them apart")
    return FitResult(params, True, converged, status, before, current, cov, it,
                     predictor.solves, time.perf_counter() - t0,
                     combination if not ok else "", tuple(warnings), fitted)


def _levenberg_marquardt(predictor: Predictor, res: _Residuals, current: Prediction, cost, r, J,
                         options: FitOptions):
    """Marquardt-scaled damping with Nielsen's update (the damping follows
    how well the Gauss-Newton model predicted the decrease).

    Returns (prediction, cost, r, J, iterations, converged, status)."""
    lam, grow = options.damping, 2.0
    for it in range(1, options.max_iterations + 1):
        A, g = J.T @ J, J.T @ r
        d = np.maximum(np.diag(A), np.finfo(float).tiny)
        step = np.linalg.solve(A + lam * np.diag(d), -g)
        length = float(step @ A @ step)
        predicted = -float(g @ step) - 0.5 * length
        try:
            trial = predictor(current.theta + step)
            t_cost, t_r, t_J = res(trial)
        except SolverError:
            t_cost = np.inf
        if t_cost < cost:
            predictor.accept(trial)
            small = (cost - t_cost) <= options.ftol * cost or length <= options.step_tol
            rho = (cost - t_cost) / predicted if predicted > 0 else 0.0
            current, cost, r, J = trial, t_cost, t_r, t_J
            lam *= max(1 / 3, 1 - (2 * rho - 1) ** 3)
            grow = 2.0
            if small:
                return current, cost, r, J, it, True, "converged"
        else:
            lam *= grow
            grow *= 2
            if length <= options.step_tol:
                return current, cost, r, J, it, True, "converged (no step lowers the cost further)"
            if lam > options.max_damping:
                return current, cost, r, J, it, False, "stalled: no step lowers the cost"
    return current, cost, r, J, options.max_iterations, False, "iteration limit"
