"""A body that falls onto what holds it: one rigid move before Newton.

A body without pins that nothing holds yet (it rests a barrier distance
above the floor, or hangs above it) has a rigid translation along which
the Hessian is flat while a net force (its weight) acts: the evaluation
says so in ``unbalanced`` (plush_opt/fem/model.py). Newton cannot factor
that Hessian; a regularised step along the near-null direction is huge,
and its line search backtracks from the first time of impact down to a
pose that happens to pass. Instead, :func:`free_fall` moves the body
rigidly along the net force to where the force along that translation
vanishes (what holds it carries the load), bounded by the first time of
impact (:meth:`~plush_opt.fem.model.Model.max_step`), so that no move
passes through anything. Along a rigid translation the elastic and tendon
energies do not change; only the other terms (gravity, contact, friction,
pins) are evaluated along it, which costs a fraction of one evaluation,
and the evaluation at its end takes their parts from the one at rest.

The move is taken only where the full evaluation at its end is admissible
and has a lower energy; Newton then goes on from there and the pose it
reaches is certified as any other.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.optimize import brentq

from ..fem.free_motion import rigid_motions

log = logging.getLogger("plush_opt.solve.equilibrium")   # one channel for every backend

#: a translation counts as one of the unbalanced flat motions when it lies in
#: their span to this fraction of its length (round-off of an orthonormal basis)
IN_SPAN = 1e-6
#: each move stops at the first time of impact less a share of the gap (the
#: model's step bound): from far above, a fall approaches what is below by
#: at most this many such moves before the body touches it
MAX_APPROACHES = 20
#: the fall's end is found to this fraction of the body's size: far below
#: any contact's barrier distance, a few root-finding steps more than a
#: rough answer (each costs a contact evaluation, not a model's)
FALL_XTOL = 1e-12


def free_fall(model, c, x: np.ndarray, ev):
    """Move a falling body rigidly onto what holds it.

    ``model``: a :class:`~plush_opt.fem.model.Model` (or
    :class:`~plush_opt.fem.model.HeldTerms`); ``c`` (n_winches,); ``x``
    (n_dofs,) an admissible pose and ``ev`` its order-2 evaluation. Returns
    ``(x, ev)`` unchanged unless ``ev.unbalanced`` holds a rigid
    translation with a net force along it and something ahead along that
    force to stop the body; then the pose translated to where the force
    along the translation vanishes (or as far as the step bound allows)
    and its order-2 evaluation.
    """
    if ev.unbalanced is None or ev.gradient is None:
        return x, ev
    d = _fall_direction(x, ev.gradient, ev.unbalanced)
    if d is None:
        return x, ev
    t = _fall_length(model, c, x, d)
    if t is None or t <= 0.0:
        return x, ev
    x_new = x + t * d
    moved = getattr(model, "evaluate_moved", None)    # the elastic and tendon parts as they are
    ev_new = moved(x_new, c, ev) if moved is not None else model.evaluate(x_new, c, order=2)
    if not (ev_new.admissible and np.isfinite(ev_new.energy) and ev_new.energy < ev.energy):
        return x, ev
    log.debug("newton: the body falls %.3e along (%.3f, %.3f)", t, d[0], d[1])
    return x_new, ev_new


def _fall_direction(x: np.ndarray, g: np.ndarray, U: np.ndarray) -> np.ndarray | None:
    """(n_dofs,) the translation by one length unit along the net force,
    if it is one of the flat unbalanced motions ``U``; else None."""
    push = -(U @ (U.T @ g))                    # downhill within the flat motions
    T = rigid_motions(x)[:, :2]                # unit translations in x and y
    u = T.T @ push
    norm = float(np.linalg.norm(u))
    if norm == 0.0:
        return None
    w = T @ (u / norm)                         # unit translation
    if np.linalg.norm(w - U @ (U.T @ w)) > IN_SPAN:
        return None
    return np.tile(u / norm, len(x) // 2)


def _fall_length(model, c, x: np.ndarray, d: np.ndarray) -> float | None:
    """How far to translate ``x`` along ``d`` (a unit translation of every
    node): to the first root of the force along ``d``, within the step
    bound; None when nothing lies ahead within the body's size."""
    moving = [term for term in model.terms if not term.translation_invariant]
    # a term linear in x (gravity) has the same slope everywhere along d
    constant = sum(float(term.evaluate(x, c, 1).gradient @ d) for term in moving if term.linear)
    slopes = [_slope_along(term, c, x, d) for term in moving if not term.linear]

    def slope(t: float) -> float:
        return constant + sum(s(t) for s in slopes)

    P = x.reshape(-1, 2)
    reach = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    t, s = 0.0, slope(0.0)
    for _ in range(MAX_APPROACHES):
        bound = model.max_step(x + t * d, reach * d)
        if bound >= 1.0 or s >= 0.0:          # nothing ahead within reach, or no force along d
            return None if t == 0.0 else t
        end = t + bound * reach
        s_end = slope(end)
        if not np.isfinite(s_end):
            return None if t == 0.0 else t
        if s_end >= 0.0:
            return _root(slope, t, s, end, s_end, FALL_XTOL * reach)
        t, s = end, s_end
    return t


def _slope_along(term, c, x: np.ndarray, d: np.ndarray):
    """t -> d/dt of ``term``'s energy at x + t d (``d`` a unit translation
    of every node): the term's own ``translation_slope`` where it has one
    (a floor: no evaluation), else through its gradient."""
    fast = getattr(term, "translation_slope", None)
    along = fast(x, d[:2]) if fast is not None else None
    if along is not None:
        return along
    return lambda t: float(term.evaluate(x + t * d, c, 1).gradient @ d)


def _root(slope, start: float, s_start: float, end: float, s_end: float, xtol: float) -> float:
    """The root of ``slope`` in [start, end] (``s_start`` < 0 at start,
    ``s_end`` not negative at end), found on the square root of the force
    taken up since ``start``: a barrier's force grows with the square of the
    penetration where it engages, so that root is near linear in the fall
    and a few secant steps find it (on the slope itself, a dozen or more).
    The slope is not evaluated again at the ends."""
    need = np.sqrt(-s_start)
    known = {start: s_start, end: s_end}

    def f(t: float) -> float:
        s = known[t] if t in known else slope(t)
        return np.sqrt(max(s - s_start, 0.0)) - need

    return brentq(f, start, end, xtol=xtol)
