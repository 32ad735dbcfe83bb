"""How far winches can go before the body folds through itself: the limit
``--accuracy`` sets on them when a control run's answer creases
(:mod:`plush_opt.apps.accuracy_run`).

A control run that drives a winch to its upper bound can leave the body
creased there on fine meshes (the crescent's lower arm at 12 mm: its inner
edge folds through itself, and a fold has no converged answer). Where the
winch is at its bound the objective was still falling towards it, so the
run would not have stopped short of the crease by itself; the limit found
here (the last contraction short of it at which the pose is free of
creases) becomes the winch's upper bound for a control run again. Where no
winch is at its bound, the winches the run moved are limited together.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..fem.model import Model
from ..io.scene import Scene
from .accuracy import CONTINUATION_STEPS, LEVEL_OPTIONS, equilibrium_at
from .accuracy_carry import branch_options
from .equilibrium import EquilibriumOptions, continuation, solve_equilibrium
from .result_file import crossing_of

#: A step of the scan whose Newton has not converged after this many
#: iterations and whose pose creases there counts as creased
#: (:func:`creased_or_solved`): a step across the fold onset walks to the
#: folded pose, which on a fine level can take a hundred iterations.
CREASE_WATCH = 20
#: Bisection steps on the segment from the held winches' lower bounds to the
#: answer's contractions (the limit to 1/64 of that segment).
FOLD_BISECTIONS = 6
#: The limit stays this fraction of the segment short of the last pose
#: found free of creases: finer meshes crease a little earlier than the one
#: scanned (the crescent's P2 meshes of 5,455, 6,447 and 14,151 nodes all
#: crease between 8 and 9 mm of `lower`'s 12, P1 meshes later).
FOLD_CLEARANCE = 0.05
#: A winch is at its upper bound within this fraction of its range (the
#: bilevel's ``HELD_FRACTION``; the reparametrised loop reaches a bound exactly).
AT_BOUND = 1e-4


@dataclasses.dataclass(frozen=True)
class FoldLimit:
    """Where winches stop short of a crease.

    ``bounds``: the new upper bound of each held winch, by name;
    ``fraction``: the last fraction of the segment (from the winches' lower
    bounds to the answer's contractions) found free of creases, on the
    level of ``element`` with ``nodes`` nodes; ``where``: the first crease
    beyond it, in words. With no ``bounds``: nothing creases on that
    segment, and ``start`` is the pose reached along it at the answer's
    contractions, (mesh, flat pose) of the first level scanned, to run
    control again from."""

    bounds: dict
    fraction: float
    element: str
    nodes: int
    where: str | None
    start: tuple | None = dataclasses.field(default=None, repr=False, compare=False)

    def row(self) -> dict:
        return {"bounds": dict(self.bounds), "fraction": self.fraction, "element": self.element,
                "nodes": self.nodes, "where": self.where, "from_rest": self.start is not None}

    def applied(self, scene: Scene) -> Scene:
        """``scene`` with these upper bounds (and its forward contractions
        clipped to them)."""
        winches = tuple(w if w.name not in self.bounds else dataclasses.replace(
            w, bounds=(w.bounds[0], self.bounds[w.name]), contraction=min(w.contraction, self.bounds[w.name]))
            for w in scene.winches)
        return scene.replace(winches=winches)


def crease_free_fraction(model: Model, contraction, held, options: EquilibriumOptions | None = None):
    """The largest fraction ``s`` of the segment from ``contraction``
    ((n_winches,)) with the winches ``held`` ((n_winches,) bool) at their
    lower bounds (s = 0) to ``contraction`` itself (s = 1) at which the
    pose of ``model`` does not crease, to 2**-:data:`FOLD_BISECTIONS`
    (each pose solved from the last one found free of creases, so the
    bisection walks the path from s = 0 in ever smaller steps; s = 1 last,
    where every step on the way was free of creases). A pose whose Newton
    creases on the way (:func:`creased_or_solved`) counts as creased.
    Returns (s, where the first crease beyond it lies, in words, the pose
    at s); (None, why, None) where the pose at s = 0 creases or has no
    certified equilibrium; (1.0, None, the pose there) where the pose at
    ``contraction`` reached so does not crease."""
    options = options or LEVEL_OPTIONS
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    held = np.asarray(held, dtype=bool)
    start = np.where(held, model.lower, c)

    def at(s, x0):
        eq = creased_or_solved(model, start + s * (c - start), x0, options)
        if isinstance(eq, str):
            return None, eq
        if not eq.converged:
            return None, f"no certified equilibrium ({eq.status})"
        return eq.x, crossing_of(model, eq.x, creases_only=True)

    x_lo, where = at(0.0, None)
    if x_lo is None or where is not None:
        return None, where, None
    lo, hi, where_hi = 0.0, 1.0, None
    for _ in range(FOLD_BISECTIONS):
        mid = 0.5 * (lo + hi)
        x, where = at(mid, x_lo)
        if x is not None and where is None:
            lo, x_lo = mid, x
        else:                         # creased (or no pose there): the limit lies below
            hi, where_hi = mid, where
    if hi == 1.0:                     # free of creases all the way so far: the last step
        x, where = at(1.0, x_lo)
        if x is not None and where is None:
            return 1.0, None, x
        where_hi = where
    return lo, where_hi, x_lo


def creased_or_solved(model: Model, contraction, x0, options: EquilibriumOptions):
    """The equilibrium at ``contraction`` from ``x0`` (None: rest; else a
    pose that does not crease) as :func:`~plush_opt.solve.accuracy.equilibrium_at`
    finds it, or where its Newton from ``x0`` creases after
    :data:`CREASE_WATCH` iterations short of converging (a str). (Newton
    that failed from ``x0`` within those iterations is not run again: the
    continuation from rest follows at once.)"""
    if x0 is None:
        return equilibrium_at(model, contraction, x0, options)
    first = solve_equilibrium(model, contraction, x0, branch_options(options, CREASE_WATCH))
    if first.converged:
        return first
    if first.iterations < CREASE_WATCH:        # (the same Newton from the same start fails the same way)
        return continuation(model, first, x0, dataclasses.replace(options, continuation=CONTINUATION_STEPS))
    where = crossing_of(model, first.x, creases_only=True)
    return where if where is not None else equilibrium_at(model, contraction, first.x, options)


def held_winches(model: Model, contraction, frozen) -> np.ndarray:
    """(n_winches,) bool: the winches a fold at ``contraction``
    ((n_winches,)) is laid to and whose bounds :func:`fold_limit` lowers:
    those not ``frozen`` (names) at their upper bound (to :data:`AT_BOUND`
    of their range: the run drove them there, the objective still falling
    towards it), or, where none is, every one not frozen above its lower
    bound (an answer inside the bounds whose pose folds on finer meshes:
    its optimum lies beyond the crease)."""
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    lo, hi = model.lower, model.upper
    free = np.array([n not in frozen for n in model.winch_names], dtype=bool)
    at_upper = free & (hi - c <= AT_BOUND * (hi - lo))
    return at_upper if at_upper.any() else free & (c - lo > AT_BOUND * (hi - lo))


def fold_limit(models, contraction, held, options: EquilibriumOptions | None = None):
    """The bounds of the ``held`` winches ((n_winches,) bool) that keep each
    of ``models`` (levels of one scene) free of creases on the way to
    ``contraction``: the least of their :func:`crease_free_fraction`, less
    :data:`FOLD_CLEARANCE`. Returns (:class:`FoldLimit`, None), or (None,
    why not, in words): a level creases (or has no pose) with the held
    winches at their lower bounds, none creases on the way (then the
    :class:`FoldLimit` has no ``bounds`` and its ``start`` is (mesh, pose)
    of the first of ``models`` reached there, free of creases: the pose
    that folded is on another branch than the path from the lower bounds
    reaches), or there is no room short of the crease."""
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    held = np.asarray(held, dtype=bool)
    found, first = None, None
    for model in models:
        s, where, x = crease_free_fraction(model, c, held, options)
        if s is None:
            return None, (f"the {model.element} level of {model.n_nodes:,} nodes has no pose free of creases "
                          f"with those winches at their lower bounds ({where})")
        first = (model.mesh, x) if first is None else first
        if s < 1.0 and (found is None or s < found[0]):
            found = (s, where, model)
    if found is None:
        return FoldLimit({}, 1.0, str(models[0].element), models[0].n_nodes, None, start=first), \
            "no level scanned creases on the way there from those winches' lower bounds"
    s, where, model = found
    keep = s - FOLD_CLEARANCE
    if keep <= 0.0:
        return None, (f"the {model.element} level of {model.n_nodes:,} nodes creases within "
                      f"{FOLD_CLEARANCE:g} of the way from those winches' lower bounds")
    lower = model.lower
    bounds = {model.winch_names[i]: float(lower[i] + keep * (c[i] - lower[i])) for i in np.flatnonzero(held)}
    return FoldLimit(bounds, s, str(model.element), model.n_nodes, where), None
