"""Inverse control: winch contractions that bring the body to its targets.

Two methods, one result (:class:`~plush_opt.control.result.ControlResult`):

* the gradient loop (:mod:`.gradient`) with the bounds as a strategy,
  reparametrised (``reparam``, the robot's method) or clipped (``clip``,
  the baseline); it drives the scene's plant
  (:class:`~plush_opt.solve.plant.Plant`) from iterate to iterate, so
  where a pose depends on the path the iterates are the states the robot
  passes through;
* the bilevel KKT formulation solved by IPOPT (:mod:`.bilevel`), which
  solves for the final pose alone (a path-dependent plant is refused).
"""

from __future__ import annotations

import dataclasses

from .bilevel import BilevelOptions, BilevelSolver
from .gradient import ControlOptions, Controller
from .result import (CONVERGED_REASONS, METHODS, REASONS, ControlIterate, ControlResult,
                     ControlStats)

__all__ = ["BilevelOptions", "BilevelSolver", "CONVERGED_REASONS", "ControlIterate", "ControlOptions",
           "ControlResult", "ControlStats", "Controller", "METHODS", "REASONS", "run_control"]


def run_control(model, targets, method: str = "reparam", contraction=None, frozen=None, x0=None,
                options=None, *, bilevel: BilevelSolver | None = None, plant=None) -> ControlResult:
    """Run control method ``method`` to the end.

    ``options`` is a :class:`ControlOptions` for 'reparam' and 'clip' (its
    ``bounds`` is set from the method) or a :class:`BilevelOptions` for
    'bilevel'; ``bilevel`` is a solver whose built NLPs are reused.
    ``plant`` is the :class:`~plush_opt.solve.plant.Plant` of ``model`` the
    gradient loop drives, starting from its committed state and committing
    every accepted iterate (default: a fresh one,
    :func:`~plush_opt.solve.plant.make_plant`); the bilevel method refuses a
    path-dependent scene."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    if method == "bilevel":            # BilevelSolver refuses a path-dependent scene itself
        if options is not None and not isinstance(options, BilevelOptions):
            raise TypeError(f"options: the bilevel method takes BilevelOptions, got {type(options).__name__}")
        return (bilevel or BilevelSolver(model)).solve(targets, contraction, frozen, x0, options)
    if options is not None and not isinstance(options, ControlOptions):
        raise TypeError(f"options: the gradient loop takes ControlOptions, got {type(options).__name__}")
    options = dataclasses.replace(options or ControlOptions(), bounds=method)
    return Controller(model, targets, contraction, frozen, x0, options, plant=plant).result()
