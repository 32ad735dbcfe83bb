"""The error estimate of an accuracy sweep's mesh levels: per nested family
(or explicit sequence) the estimate from the differences of consecutive
levels and their observed ratio, and the bounds of every level through the
estimates of others (the reasoning: :mod:`plush_opt.solve.accuracy` and
docs/accuracy.md). Pure arithmetic on the levels' predicted points; the
sweep that solves them is :mod:`plush_opt.solve.accuracy`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import NamedTuple

import numpy as np

from ..fem.elements import ELEMENTS
from ..fem.mesh import Mesh

log = logging.getLogger("plush_opt.solve.accuracy")     # the sweep's channel

#: Best convergence order (in the mesh size h) of point displacements
#: expected of each element (h^(k+1) for degree k): the estimate never
#: assumes faster convergence than this, whatever two levels happened to show.
EXPECTED_ORDER = {e.name: e.degree + 1.0 for e in ELEMENTS}
#: Differences shrinking by less than this per level are not converging
#: (pre-asymptotic, or a point load's logarithmic growth): no estimate.
MAX_RATIO = 0.8
#: A nested level's estimate is withdrawn (not an anchor of bounds) where a
#: nested level of the same element with at least its nodes moved to its
#: next level by more than it moved from its previous one, and by at least
#: this share of the estimate: differences that grow again at that size say
#: the levels are not yet asymptotic there, whatever the coarser ratio showed
#: (a smaller growth, at round-off or far below the estimate, says nothing).
GROWTH_SHARE = 0.25
#: The geometric tail times this: on unstructured, non-nested meshes the
#: differences of consecutive levels scatter about their trend; Roache's
#: grid convergence index uses 1.25 with three or more grids (3 for two).
SAFETY = 1.25


class Resolution(NamedTuple):
    """One level of a sweep: the graded mesh at ``max_area``, refined
    uniformly ``refinements`` times. ``family`` is the coarse mesh's
    max_area for a nested family (the estimate compares a level only with
    its own family), None for an explicit sequence of independent meshes."""

    max_area: float
    refinements: int = 0
    family: float | None = None


@dataclasses.dataclass
class Level:
    """One mesh level of one element type: its mesh, cost and predictions
    (``t_mesh`` wall seconds; ``t_solve`` CPU seconds of one Newton solve
    from rest at the scene's own contractions, after the factorisation's
    symbolic analysis; ``work`` the same solve's counted work,
    :mod:`plush_opt.solve.work`)."""

    element: str
    resolution: Resolution
    mesh: Mesh
    t_mesh: float
    t_solve: float
    newton_iterations: int
    poses: list                      # certified equilibria, one per contraction
    y: np.ndarray                    # (m contractions, k points, 2) predicted positions
    difference_to_next: float | None = None
    ratio: float | None = None
    estimate: float | None = None    # error bound of y (None: not enough levels; inf: not converging)
    confirmed: bool = False          # usable as an anchor of bounds (see estimate_errors)
    withdrawn: bool = False          # confirmed, then withdrawn: finer levels grow (GROWTH_SHARE)
    bound: float | None = None       # error bound the pick uses (see bound_errors)
    bound_via: int | None = None     # the level (index among those bounded together) it comes from
    model: object = dataclasses.field(default=None, repr=False, compare=False)   # kept to be solved again (or None)
    # the path its one pose ends (plush_opt.solve.accuracy_path.path_key), or None
    along: bytes | None = dataclasses.field(default=None, repr=False, compare=False)
    # per contraction, where its pose creases (contact_boundary.CREASE_SPAN; no contact.self), or None; () unchecked
    crossing: tuple = ()
    # the contractions (rows of y) the estimates and bounds leave out (plush_opt.solve.accuracy.planned_sweep)
    left_out: tuple = ()
    work: float | None = None

    @property
    def cost(self) -> float:
        """What choosing between levels compares: the counted ``work`` (the
        same on every run), else the measured ``t_solve``."""
        return self.t_solve if self.work is None else self.work

    @property
    def max_area(self) -> float:
        return self.resolution.max_area

    def meets(self, tol: float) -> bool:
        return self.bound is not None and self.bound <= tol

    @property
    def compared(self) -> np.ndarray:
        """``y`` without the contractions left out: what the estimates and bounds compare."""
        return np.delete(self.y, list(self.left_out), axis=0) if self.left_out else self.y

    @property
    def on_branch(self) -> bool:
        """Whether the level has its poses (``y`` finite): False for a level
        that has no equilibrium near the pose it was to follow (see
        :func:`~plush_opt.solve.accuracy_check.bounds_at`), which takes no
        part in the estimates and bounds."""
        return bool(np.all(np.isfinite(self.compared)))

    def row(self) -> dict:
        return {"element": self.element, "max_area": self.max_area,
                "refinements": self.resolution.refinements, "nested": self.resolution.family is not None,
                "n_nodes": self.mesh.n_nodes,
                "n_elems": self.mesh.n_elems, "t_mesh_s": self.t_mesh, "t_solve_s": self.t_solve,
                "work_s": self.work, "newton_iterations": self.newton_iterations,
                "difference_to_next": self.difference_to_next, "ratio": self.ratio,
                "estimated_error": _json_number(self.estimate), "confirmed": self.confirmed,
                "withdrawn": self.withdrawn,
                "error_bound": _json_number(self.bound), "bound_via": self.bound_via}


def _json_number(v):
    return None if v is None or not math.isfinite(v) else float(v)


def estimate_errors(ys, nodes, element: str, nested: bool = False) -> list[dict]:
    """Error estimates of a sequence of levels of one element, coarse to fine.

    Parameters
    ----------
    ys : per level, the predicted point positions (any shape ending in 2).
    nodes : per level, its number of nodes.
    element : "P1" or "P2" (sets the expected order).
    nested : the levels are one family of nested meshes (each the one
        before refined uniformly). Their differences shrink smoothly, so
        the ratio is the one observed on the coarse side (levels k - 1,
        k, k + 1) and the estimate stands on its own. Independent meshes
        scatter: the ratio is the larger of both sides (level k + 2 too)
        and the estimate must be confirmed by the next level's.

    Returns
    -------
    per level a dict: ``difference`` (max distance to the next level, None
    for the last), ``ratio`` (the ratio used, None without a previous
    difference), ``estimate`` (d / (1 - ratio) x SAFETY; None where it needs
    a level that is missing, inf where the differences do not shrink by
    MAX_RATIO per level) and ``confirmed``.
    """
    n = len(ys)
    d = [float(np.max(np.linalg.norm(np.asarray(ys[k]) - np.asarray(ys[k + 1]), axis=-1), initial=0.0))
         for k in range(n - 1)] + [None]
    out = []
    for k in range(n):
        ratio = estimate = None
        if 0 < k < n - 1:
            theory = (nodes[k] / nodes[k + 1]) ** (EXPECTED_ORDER[element] / 2)
            sides = (k - 1,) if nested else (k - 1, k)
            observed = [d[j + 1] / d[j] if d[j] > 0 else 0.0 for j in sides if j + 1 < n - 1]
            ratio = max(observed + [theory])
            estimate = math.inf if ratio >= MAX_RATIO else SAFETY * d[k] / (1.0 - ratio)
        out.append({"difference": d[k], "ratio": ratio, "estimate": estimate, "confirmed": False})
    for k in range(n - 1):
        here, nxt = out[k]["estimate"], out[k + 1]["estimate"]
        usable = here is not None and math.isfinite(here)
        out[k]["confirmed"] = usable and (nested or (nxt is not None and math.isfinite(nxt)
                                                     and nxt <= here))
    return out


def bound_errors(levels: list[Level]) -> None:
    """Set each level's error bound: the least, over the levels M whose
    estimate is confirmed (the level itself included), of

        max |y - y_M| + estimate_M

    (the triangle inequality: the distance of y to the converged answer is
    at most its distance to y_M plus y_M's). A coarse level whose own
    differences scatter too much to be estimated is then still shown within
    a tolerance by a finer level solved anyway to confirm that one, and a
    level of one element by a level of the other (a coarse P1 level
    through a finer P2 level). Never below the
    estimate of the level it comes from, so no optimism is added."""
    anchors = [(j, m) for j, m in enumerate(levels)
               if m.on_branch and m.confirmed and m.estimate is not None and math.isfinite(m.estimate)]
    for lv in levels:
        lv.bound = lv.bound_via = None
        for j, m in anchors if lv.on_branch else ():
            b = m.estimate + (0.0 if m is lv else float(np.max(np.linalg.norm(lv.compared - m.compared, axis=-1))))
            if lv.bound is None or b < lv.bound:
                lv.bound, lv.bound_via = b, j


def estimate_levels(levels: list[Level]) -> None:
    """Set the estimates of levels of one element (coarse to fine): each
    nested family on its own, an explicit sequence as one; then the
    bounds (:func:`bound_errors`). Levels not on the branch
    (:attr:`Level.on_branch`) get no estimate, and neither do the levels of
    their family coarser than them: the differences are taken over the
    unbroken run of finer levels only (a gap would pass for a step).
    A nested level's estimate is withdrawn where nested levels of at least
    its nodes grow again (:data:`GROWTH_SHARE`)."""
    for lv in levels:
        lv.difference_to_next = lv.ratio = lv.estimate = None
        lv.confirmed = lv.withdrawn = False
    grown = []                       # (nodes, difference) of nested levels whose difference grew
    for family in dict.fromkeys(lv.resolution.family for lv in levels):
        group = [lv for lv in levels if lv.resolution.family == family]
        off = [i for i, lv in enumerate(group) if not lv.on_branch]
        group = group[off[-1] + 1:] if off else group
        if not group:
            continue
        est = estimate_errors([lv.compared for lv in group], [lv.mesh.n_nodes for lv in group],
                              group[0].element, nested=family is not None)
        for lv, e in zip(group, est):
            lv.difference_to_next, lv.ratio, lv.estimate = e["difference"], e["ratio"], e["estimate"]
            lv.confirmed = e["confirmed"]
        if family is not None:
            d = [e["difference"] for e in est]        # d[k]: level k to k + 1; None for the last
            grown += [(lv.mesh.n_nodes, b) for lv, a, b in zip(group[1:], d, d[1:])
                      if a is not None and b is not None and b > a]
    for lv in (lv for lv in levels if lv.confirmed and lv.resolution.family is not None):
        grew = [(n, d) for n, d in grown if n >= lv.mesh.n_nodes and d >= GROWTH_SHARE * lv.estimate]
        if grew:
            lv.confirmed, lv.withdrawn = False, True
            log.debug("accuracy: the estimate %.3g of the %s level of %d nodes is withdrawn: the level of %d nodes "
                     "moved %.3g to its next, more than to its previous", lv.estimate, lv.element, lv.mesh.n_nodes,
                     *grew[0])
    bound_errors(levels)


def estimate_each_element(levels: list[Level]) -> list[Level]:
    """Set the estimates of ``levels`` of several elements: each element's
    levels on their own (:func:`estimate_levels`), then the bounds across
    them (:func:`bound_errors`). Returns ``levels``."""
    for element in dict.fromkeys(lv.element for lv in levels):
        estimate_levels([lv for lv in levels if lv.element == element])
    bound_errors(levels)
    return levels


def cheapest_meeting(levels: list, tol: float, elements=None) -> int | None:
    """The index of the level of least cost (:attr:`Level.cost`) whose bound
    is within ``tol`` (of ``elements`` alone where given; None entries
    skipped), or None."""
    meeting = [i for i, lv in enumerate(levels) if lv is not None and lv.meets(tol)
               and (elements is None or lv.element in elements)]
    return min(meeting, key=lambda i: levels[i].cost) if meeting else None


def one_pose(lv: Level, pose, y) -> Level:
    """``lv`` with one pose (None off the branch) and its ``y``, estimates cleared."""
    return dataclasses.replace(lv, poses=[pose], y=y, difference_to_next=None, ratio=None, estimate=None,
                               confirmed=False, withdrawn=False, bound=None, bound_via=None, along=None, crossing=(),
                               left_out=())


def leave_out_creases(computed: list[Level], cs, left_out: list[dict], progress=None) -> None:
    """Leave out of every level's estimates the contractions where some
    level's pose creases (a body folded through itself, which a scene
    without self-contact allows: a crease has no length scale, so its
    levels do not converge and say nothing of the mesh the other
    contractions need; ``Level.crossing`` holds creases only, see
    :data:`~plush_opt.fem.contact_boundary.CREASE_SPAN`), unless that is
    every contraction. ``left_out`` gets a row per contraction left out
    (its first crease), and ``progress`` hears of each once."""
    first = {}
    for lv in computed:
        for j, where in enumerate(lv.crossing):
            if where is not None and j not in first:
                first[j] = (lv, where)
    out = () if len(first) == len(cs) else tuple(sorted(first))
    for lv in computed:
        lv.left_out = out
    for j in out:
        if any(row["contraction_index"] == j for row in left_out):
            continue
        lv, where = first[j]
        left_out.append({"contraction_index": j, "contraction": np.asarray(cs[j]).tolist(), "element": lv.element,
                         "nodes": lv.mesh.n_nodes, "where": where})
        if progress is not None:
            progress(f"accuracy: at contraction {np.asarray(cs[j]).tolist()} the body creases through itself on the "
                     f"{lv.element} level of {lv.mesh.n_nodes:,} nodes ({where}; the scene has no contact.self): "
                     "that contraction is left out of the mesh choice")
