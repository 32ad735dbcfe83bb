"""Inverse control: winch contractions that bring the body to its targets.

Two methods, one result (:class:`~plush_opt.control.result.ControlResult`):

* the gradient loop (:mod:`.gradient`) with the bounds as a strategy,
  reparametrised (``reparam``, the robot's method) or clipped (``clip``,
  the baseline);
* the bilevel KKT formulation solved by IPOPT (:mod:`.bilevel`).
"""

from __future__ import annotations

import dataclasses

from .bilevel import BilevelOptions, BilevelSolver
from .friction_control import FrictionController, gradient_controller
from .gradient import ControlOptions, Controller
from .result import (CONVERGED_REASONS, METHODS, REASONS, ControlIterate, ControlResult,
                     ControlStats)

__all__ = ["BilevelOptions", "BilevelSolver", "CONVERGED_REASONS", "ControlIterate", "ControlOptions",
           "ControlResult", "ControlStats", "Controller", "FrictionController", "METHODS", "REASONS",
           "gradient_controller", "run_control"]


def run_control(model, targets, method: str = "reparam", contraction=None, frozen=None, x0=None,
                options=None, *, bilevel: BilevelSolver | None = None, friction=None,
                start=None) -> ControlResult:
    """Run control method ``method`` to the end.

    ``options`` is a :class:`ControlOptions` for 'reparam' and 'clip' (its
    ``bounds`` is set from the method) or a :class:`BilevelOptions` for
    'bilevel'; ``bilevel`` is a solver whose built NLPs are reused. On a
    scene with friction at via points the gradient loop follows the robot's
    path (:mod:`.friction_control`; ``friction`` its model if built,
    ``start`` the robot's friction state) and the bilevel method refuses."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    if method == "bilevel":            # BilevelSolver refuses a friction scene itself
        if options is not None and not isinstance(options, BilevelOptions):
            raise TypeError(f"options: the bilevel method takes BilevelOptions, got {type(options).__name__}")
        return (bilevel or BilevelSolver(model)).solve(targets, contraction, frozen, x0, options)
    if options is not None and not isinstance(options, ControlOptions):
        raise TypeError(f"options: the gradient loop takes ControlOptions, got {type(options).__name__}")
    options = dataclasses.replace(options or ControlOptions(), bounds=method)
    return gradient_controller(model, targets, contraction, frozen, x0, options, friction=friction,
                               start=start).result()
