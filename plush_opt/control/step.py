"""The gradient loop's step on the free winches, as functions of explicit state.

:func:`search_direction` is the projected Levenberg-Marquardt step on the
target residuals (Gauss-Newton) or the steepest-descent step with
Barzilai-Borwein lengths, on xi (the reparametrised contractions, c = f(xi))
or on c itself (clipping); :func:`trial_point` turns a step into the
line-search trial and :func:`line_search` backtracks until a trial's
certified equilibrium lowers O. What the step remembers between iterates
(the damping mu, the Barzilai-Borwein step) is passed in and returned,
never kept here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..solve.branch import branch_ended

# A winch whose xi is within this fraction of its range from where xi stops
# counts as on that edge (round-off of f's inverse at a bound).
EDGE_TOLERANCE = 1e-12
# Keeps the first steepest-descent step finite where the gradient vanishes.
TINY_GRADIENT = 1e-300
# Steepest descent multiplies its step by this after each rejected trial
# (its step length has no damping to raise).
BACKTRACK = 0.5


def search_direction(gradient, J, xi, frozen, bounds, span, options, mu: float,
                     bb_step: float | None) -> tuple[np.ndarray, float | None]:
    """A step on xi for the free winches; (step, Barzilai-Borwein step).

    Parameters
    ----------
    gradient : (n_winches,) dO/dc at the iterate.
    J : (2 k, n_winches) the residual Jacobian dr/dc (Gauss-Newton), or None.
    xi : (n_winches,) the iterate's xi; ``frozen`` (n_winches,) bool.
    bounds : the bounds strategy (:mod:`.bounds`: ``slope``, ``edges``).
    span : (n_winches,) upper - lower (length).
    options : :class:`~plush_opt.control.gradient.ControlOptions`
        (direction, slope_floor, damping, initial_gradient_step, max_step).
    mu : the Levenberg-Marquardt damping (Gauss-Newton).
    bb_step : the Barzilai-Borwein step (steepest descent); None before the
        first step, which then takes ``initial_gradient_step``.

    Winches sitting on a bound whose step would push them further out are
    held (projected Gauss-Newton): otherwise a winch that cannot move would
    still take the length of the step from the others. No winch's xi moves
    by more than ``max_step`` of its range.
    """
    slope = bounds.slope(xi, options.slope_floor)
    g = gradient * slope
    lo_edge, hi_edge = bounds.edges()
    at_lower = xi <= lo_edge + EDGE_TOLERANCE * span
    at_upper = xi >= hi_edge - EDGE_TOLERANCE * span
    held = np.array(frozen, dtype=bool)
    for _ in range(len(xi) + 1):             # each pass holds one more winch at least
        step = np.zeros_like(xi)
        move = ~held
        if not move.any():
            break
        if options.direction == "gauss-newton":
            Jm = J[:, move] * slope[move][None, :]
            A = Jm.T @ Jm
            damp = mu * options.damping.scale(np.diag(A))
            step[move] = -np.linalg.solve(A + damp * np.eye(A.shape[0]), g[move])
        else:
            if bb_step is None:
                bb_step = (options.initial_gradient_step * float(np.mean(span))
                           / max(np.linalg.norm(g[move]), TINY_GRADIENT))
            step[move] = -bb_step * g[move]
        outward = move & ((at_lower & (step < 0)) | (at_upper & (step > 0)))
        if not outward.any():
            break
        held |= outward
    limit = options.max_step * span
    ratio = np.max(np.abs(step) / limit)
    return (step / ratio if ratio > 1 else step), bb_step


def trial_point(bounds, xi, contraction, step, frozen, floor: float | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """(xi, c) of the trial ``xi + step``, kept where xi stops; with a slope
    ``floor``, the trial whose contraction is the step's linear prediction
    instead (``bounds.predicted``: they differ in the reparametrisation's
    blend zones only). A frozen winch keeps its xi and its contraction bit
    for bit."""
    xi_t = bounds.clamp(xi + step) if floor is None else bounds.predicted(xi, step, floor)
    xi_t[frozen] = xi[frozen]
    c_t = bounds.f(xi_t)
    c_t[frozen] = contraction[frozen]
    return xi_t, c_t


@dataclass(frozen=True)
class Outcome:
    """What :func:`line_search` found: ``kind`` 'accepted' (``xi`` and
    ``equilibrium`` of the accepted trial), 'stationary' (the step moves no
    contraction), 'vanished' (after rejected trials the damped or halved
    step moved no contraction: no decrease found), 'below_roundoff' (no trial lowered O, and
    none could lower it by more than its round-off: ``predicted``, the
    largest first-order decrease of the trials) or 'no_decrease' (no trial
    lowered O); ``mu`` the Levenberg-Marquardt damping after the search."""

    kind: str
    mu: float
    xi: np.ndarray | None = None
    equilibrium: Any = None
    predicted: float | None = None
    branch_ends: bool = False       # no trial certified: each left the stable branch (a limit point ahead)


def line_search(xi, contraction, frozen, bounds, objective: float, options, mu: float,
                direction: Callable[[float], np.ndarray], trial: Callable[[np.ndarray], Any],
                value: Callable[[Any], float], linear_trials: bool = False, gradient=None,
                roundoff: float = 0.0) -> Outcome:
    """Backtrack from the iterate (xi, ``contraction``, O = ``objective``).

    ``direction(mu)`` is the step for damping mu, ``trial(c)`` the trial's
    equilibrium at contractions c, ``value(eq)`` its O. Gauss-Newton
    recomputes the step with the damping raised after each rejected trial
    (:class:`~.policy.Damping`) and lowers it after the accepted one;
    steepest descent halves its step. A trial is accepted only if its
    equilibrium is certified and O decreased; at most
    ``options.max_backtracks`` trials. ``linear_trials``: each trial is
    the contraction the step's linear model predicts (:func:`trial_point`
    with ``options.slope_floor``). Where none is accepted, every trial's
    equilibrium was certified and none was predicted to lower O by more
    than ``roundoff`` (O's round-off at the iterate, length^2) to first
    order along ``gradient`` (dO/dc at the iterate, (n_winches,); the
    Gauss-Newton model's decrease is at most that), the comparisons could
    not have seen a decrease: 'below_roundoff', not 'no_decrease'. The
    same after the first trial alone where it was certified and rejected
    and changes O by no more than ``roundoff`` to first order either way
    (the damped or halved trials after it are smaller still: the round-off
    steps at the end of a run, where a comparison of O decides nothing).
    """
    gn = options.direction == "gauss-newton"
    predicted, judged = -np.inf, gradient is not None    # (judged: every trial certified, judged by O)
    vanished, solved, ended = False, 0, True               # (ended: every trial solved left the branch)
    for attempt in range(options.max_backtracks):
        step = direction(mu)
        if not gn:
            step = step * BACKTRACK ** attempt
        xi_t, c_t = trial_point(bounds, xi, contraction, step, frozen,
                                options.slope_floor if linear_trials else None)
        if np.array_equal(c_t, contraction):
            if attempt == 0:
                return Outcome("stationary", mu)
            vanished = True
            break
        eq = trial(c_t)
        if eq.converged and value(eq) < objective:
            return Outcome("accepted", options.damping.accepted(mu) if gn else mu, xi_t, eq)
        solved, ended = solved + 1, ended and not eq.converged and branch_ended(eq.status)
        if judged:
            change = -float(gradient @ (c_t - contraction))
            predicted, judged = max(predicted, change), eq.converged
            if judged and attempt == 0 and abs(change) <= roundoff:
                # a first trial whose O changes by less than its round-off to first order either
                # way: the smaller trials after it cannot show a decrease either
                return Outcome("below_roundoff", options.damping.rejected(mu) if gn else mu, predicted=predicted)
        if gn:
            mu = options.damping.rejected(mu)
    if judged and predicted <= roundoff:
        return Outcome("below_roundoff", mu, predicted=predicted)
    return Outcome("vanished" if vanished else "no_decrease", mu, branch_ends=bool(solved) and ended)
