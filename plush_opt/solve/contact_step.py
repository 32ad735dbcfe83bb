"""A Newton step corrected for the contact barrier's curvature, after a fall.

A body that fell onto the floor (plush_opt/solve/free_fall.py) reaches it
rigidly: every node that touches sits at the same depth, while the load
each carries is uneven (a corner, whose barrier weight counts its side
too, needs about a third less penetration). The IPC barrier pressed a
small fraction of d_hat deep is far from quadratic over the step that
settles them: its force grows with the square of the penetration, so such
a node keeps a residual that the elastic terms, nearly linear over the
same step, do not. Newton corrects the steps of a solve whose body fell
(only those: elsewhere a step starts from a nearby pose and the solver's
path stays as it was). :func:`corrected_step` adds to the step
dx = -F^-1 g what undoes the barrier's part of that residual to first
order: -F^-1 r with r = g_c(x + dx) - g_c(x) - H_c(x) dx, the contact
term's gradient at the step's end less its linearisation (one contact
evaluation at each end and one solve with the factor in hand, no model
evaluation). The step is taken through the same line search as any other
(admissibility, step bound, energy), so the correction can make a step
fail but never make a pose pass that would not.
"""

from __future__ import annotations

import numpy as np

from ..fem.contact import ContactTerm

#: the correction is dropped where it is this large against the step itself
#: (then the barrier is not near its linearisation over the step: the
#: first-order correction would not be either)
CORRECTION_MAX = 0.5


def corrected_step(model, c, x: np.ndarray, g: np.ndarray, dx: np.ndarray, factor) -> np.ndarray:
    """``dx`` (n_dofs,), the Newton step -F^-1 ``g`` at ``x`` with ``factor``
    F, plus its correction for the curvature of the model's contact terms
    (:func:`remainder`) where one applies; ``dx`` itself where the model has
    no contact term, nothing is in contact, the step's end is not
    admissible for contact, or the corrected step is not a descent
    direction or its correction exceeds ``CORRECTION_MAX`` of the step.
    (The line search bounds the corrected step as any other.)"""
    terms = [term for term in getattr(model, "terms", ()) if isinstance(term, ContactTerm)]
    if not terms:
        return dx
    r = None
    for term in terms:
        part = remainder(term, x, c, dx)
        if part is not None:
            r = part if r is None else r + part
    if r is None:
        return dx
    fix = -factor.solve(r)
    step = dx + fix
    if not (np.all(np.isfinite(step)) and float(g @ step) < 0.0
            and np.linalg.norm(fix) <= CORRECTION_MAX * np.linalg.norm(dx)):
        return dx
    return step


def remainder(term: ContactTerm, x: np.ndarray, c: np.ndarray, dx: np.ndarray) -> np.ndarray | None:
    """(n_dofs,) what the contact ``term``'s gradient at x + dx differs by
    from its linearisation at ``x`` (g(x + dx) - g(x) - H(x) dx): the part
    of a Newton step's residual that the barrier's curvature leaves. None
    where nothing is in contact at either pose or x + dx is not admissible."""
    xt = x + dx
    if not term.admissible(xt):
        return None
    at, to = term.evaluate(x, c, 2), term.evaluate(xt, c, 1)
    h = at.hessian["contact_hess"]
    if h.nnz == 0 and not to.gradient.any():
        return None
    linear = np.bincount(h.row, weights=h.data * dx[h.col], minlength=term.n_dofs)
    return to.gradient - at.gradient - linear
