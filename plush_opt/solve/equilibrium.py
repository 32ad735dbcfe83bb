"""Quasi-static equilibria: local minimisers of E(x; c), by one call,
:func:`solve_equilibrium`.

Two backends on the same energy:

* ``newton`` (default, :mod:`plush_opt.solve.newton`): Newton on the exact
  sparse Hessian, CHOLMOD factorisation (symbolic analysis once per model),
  backtracking line search that never accepts a non-admissible pose (some
  J <= 0) or a non-finite energy, a multiple of the identity added when the
  Hessian is not positive definite, and an escape along the most negative
  curvature direction when the gradient vanishes at a saddle.
* ``ipopt`` (:mod:`plush_opt.solve.ipopt_equilibrium`): IPOPT minimising the
  CasADi expression of E, for cross-checks (:class:`IpoptEquilibrium`,
  which keeps the NLPs it builds for its model; no module holds state).

Both return an :class:`Equilibrium` that is *certified* by the same test
(:mod:`plush_opt.solve.certificate`): ``converged`` only if the residual
|grad_x E| is within tolerance relative to the force scale and the
Hessian is positive definite (Cholesky succeeds). A positive definite pose
whose residual stalled above the tolerance but within its round-off floor
(:func:`~plush_opt.solve.certificate.roundoff_floor`: no float64 pose is
closer) is converged too, and its status says so. With
``EquilibriumOptions.continuation``, a solve that fails from its start
tries again by continuation in the contraction (:func:`continuation`) and
says so (``continuation_steps``, the status); Newton from the start then
hands over early where it makes no progress (:data:`HANDOVER_WINDOW`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..base.errors import SolverError
from ..fem.model import Model
from .certificate import (BACKENDS, LEFT_BRANCH, Equilibrium, EquilibriumOptions, at_roundoff_floor, certify,
                          residual, roundoff_floor)
from .ipopt_equilibrium import IpoptEquilibrium
from .newton import NO_PROGRESS, solve_newton

__all__ = ["BACKENDS", "LEFT_BRANCH", "Equilibrium", "EquilibriumOptions", "IpoptEquilibrium", "certify",
           "continuation", "residual", "roundoff_floor", "solve_equilibrium"]

#: A continuation step that fails is halved, at most this many times in a
#: row (then the continuation fails): 2^-6 of the first step is far below
#: any step a smooth path of equilibria needs.
CONTINUATION_HALVINGS = 6
#: After a step that converged, the next is this much longer (up to the
#: first step): the path is often steep only at its start.
CONTINUATION_GROWTH = 1.5
#: Where continuation can take over, Newton from the start hands over once
#: its best residual has not halved in this many iterations (at any
#: residual): a start that far off wanders, while every problem file's
#: solve from rest that converges halves it within 30 (at most 61
#: iterations in all: tools/newton_from_rest.py). Where continuation
#: fails too, Newton resumes.
HANDOVER_WINDOW = 30


def solve_equilibrium(model: Model, contraction, x0=None, options: EquilibriumOptions | None = None,
                      ipopt: IpoptEquilibrium | None = None, chord=None) -> Equilibrium:
    """Equilibrium of ``model`` at ``contraction`` (n_winches,), from ``x0``
    (flat or (n_nodes, 2); default the rest pose). ``x0`` must be admissible.

    ``ipopt`` : the IPOPT backend's solver of this model, which keeps the
    NLPs it built (default: a new one, built for this solve alone).
    ``chord`` : the factor of a nearby certified equilibrium (Newton's
    first steps reuse it while they converge fast: :func:`solve_newton`)."""
    options = options or EquilibriumOptions()
    handover = HANDOVER_WINDOW if options.continuation else 0
    eq = _solve_once(model, contraction, x0, options, ipopt, chord, handover)
    if eq.converged or options.continuation == 0:
        return eq
    found = continuation(model, eq, x0, options, ipopt)
    if found.converged or not eq.status.startswith(NO_PROGRESS):
        return found
    return _resumed(model, eq, found, options, ipopt)


def _resumed(model: Model, handed: Equilibrium, found: Equilibrium, options: EquilibriumOptions,
             ipopt) -> Equilibrium:
    """Newton from where ``handed`` handed over, with the iterations it had
    left, after the continuation ``found`` failed too: the hand-over costs
    time, never an equilibrium the solve alone would have found."""
    rest = replace(options, continuation=0, max_iterations=max(options.max_iterations - handed.iterations, 1))
    eq = _solve_once(model, handed.contraction, handed.x, rest, ipopt, None)
    why = f"resumed after {handed.iterations} iterations ({found.status})"
    return replace(eq, status=f"{eq.status}, {why}", iterations=handed.iterations + eq.iterations,
                   continuation_steps=found.continuation_steps)


def _solve_once(model: Model, contraction, x0, options: EquilibriumOptions, ipopt, chord,
                handover: int = 0) -> Equilibrium:
    c = np.array(contraction, dtype=np.float64).reshape(-1)
    if c.shape != (model.n_winches,):
        raise SolverError(f"contraction: expected {model.n_winches} values, got {c.size}")
    x = model.X.copy() if x0 is None else np.array(x0, dtype=np.float64).reshape(-1)
    if x.shape != (model.n_dofs,):
        raise SolverError(f"x0: expected {model.n_dofs} coordinates, got {x.size}")
    if options.backend == "ipopt":
        if ipopt is None:
            ipopt = IpoptEquilibrium(model)
        elif ipopt.model is not model:
            raise ValueError("ipopt: an IpoptEquilibrium of another model")
        return at_roundoff_floor(model, ipopt.solve(c, x, options), options)
    return at_roundoff_floor(model, solve_newton(model, c, x, options, chord, handover), options)


def continuation(model: Model, failed: Equilibrium, x0=None, options: EquilibriumOptions | None = None,
                 ipopt: IpoptEquilibrium | None = None) -> Equilibrium:
    """After ``failed`` (a solve at ``failed.contraction`` from ``x0``, default
    the rest pose, that did not converge): the equilibrium there by
    continuation in the contraction from the rest contraction c0 (0 clipped
    to the bounds), in ``options.continuation`` equal steps, each from the
    last certified pose moved by the sensitivity's predictor dx/dc dc (the
    last pose where that is not admissible). A step that fails is halved
    (at most :data:`CONTINUATION_HALVINGS` times in a row); after one that
    converges the next grows by :data:`CONTINUATION_GROWTH`, up to the first.

    Returns the certified equilibrium with ``continuation_steps`` (steps
    solved) and a status that says it was reached by continuation, or a
    failed :class:`Equilibrium` (``converged`` False) whose status gives
    both failures: the solve from the start and where the continuation
    stopped."""
    options = options or EquilibriumOptions()
    once = replace(options, continuation=0)
    c = np.asarray(failed.contraction, dtype=np.float64)
    c0 = np.clip(np.zeros_like(c), model.lower, model.upper)
    eq = _solve_once(model, c0, x0, once, ipopt, None)
    first = 1.0 / max(options.continuation, 1)
    s, ds, halvings, steps = 0.0, first, 0, 0
    while eq.converged and s < 1.0:
        ds = min(ds, 1.0 - s)
        target = c0 + min(s + ds, 1.0) * (c - c0)
        trial = _solve_once(model, target, _predicted(model, eq, target), once, ipopt, None)
        if trial.converged:
            s, eq, steps, halvings = s + ds, trial, steps + 1, 0
            ds = min(first, CONTINUATION_GROWTH * ds)
        elif halvings < CONTINUATION_HALVINGS:
            ds, halvings = 0.5 * ds, halvings + 1
        else:
            eq = trial
    if eq.converged:
        status = (f"{eq.status} by continuation in the contraction: {steps} steps from {c0.tolist()} "
                  f"(from the start: {failed.status})")
        return replace(eq, status=status, continuation_steps=steps)
    status = (f"{failed.status}; continuation in the contraction from {c0.tolist()} failed at "
              f"{np.asarray(eq.contraction).tolist()} after {steps} steps: {eq.status}")
    return replace(failed, status=status, continuation_steps=steps)


def _predicted(model: Model, eq: Equilibrium, target) -> np.ndarray:
    """The pose at ``target`` predicted from the certified ``eq``:
    x + dx/dc (target - c), dx/dc = -H^-1 d2E/dxdc; ``eq.x`` where there
    is no factor or the prediction is not admissible."""
    if eq.factor is None:
        return eq.x
    try:
        dx = -eq.factor.solve(model.mixed(eq.x, eq.contraction) @ (np.asarray(target) - eq.contraction))
    except SolverError:
        return eq.x
    x = eq.x + dx
    return x if np.all(np.isfinite(x)) and model.admissible(x) else eq.x
