"""``solve --accuracy TOL``: a tolerance that holds at the returned pose.

The mesh is chosen at the sweep's probe contractions
(:func:`~plush_opt.solve.accuracy.choose_levels`); the solve (forward or
control) then runs on it, and the error is estimated again at the
contractions it returned (:func:`~plush_opt.solve.accuracy_check.bounds_at`).
Where the mesh used does not meet TOL there, the cheapest level of the
sweep that does is taken and the problem solved again on it, starting at
those contractions; then the estimate is made again at the new answer. The
result's ``accuracy.at_result`` says what was estimated at the returned
contractions, and whether TOL is met there (docs/accuracy.md).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from ..io import load_scene
from ..problem import Problem, from_scene, load
from ..solve.accuracy import choose_levels, summary
from ..solve.accuracy_check import bounds_at, cheapest_meeting

log = logging.getLogger("plush_opt")

#: Re-solves on another level at most: each starts at the previous answer,
#: whose contractions the new level was chosen for, so one normally suffices.
MAX_RESOLVES = 2


class AccurateSolve:
    """The mesh levels of one problem file for a tolerance, and the level in
    use (``problem``: the :class:`~plush_opt.problem.Problem` on it, its
    ``mesh_report`` the sweep's report for that level). ``progress(line)``
    hears what is being solved (default: the log, at info level)."""

    def __init__(self, path, tol: float, progress=None):
        self.progress = progress or (lambda line: log.info("%s", line))
        self.scene = load_scene(path)
        self.tol = float(tol)
        # the levels' estimate solves each mesh's pose at fixed contractions: a history-free plant only
        load(path).plant.require_history_free("--accuracy", "solve without --accuracy (the file's max_area "
                                              "sets the mesh)")
        if self.scene.outline is None:        # an explicit mesh: nothing to choose, nothing to check
            self.levels = None
            self.problem = load(path, accuracy=tol)
            return
        self.progress(f"accuracy: choosing the element and mesh for tolerance {tol:g} (a sweep of mesh levels)")
        best, self.levels, self.report = choose_levels(self.scene, tol, progress=self.progress)
        self.problem = self._problem(self.levels.index(best))

    def _problem(self, k: int) -> Problem:
        self.index = k
        lv = self.levels[k]
        p = from_scene(dataclasses.replace(self.scene, element=lv.element), lv.mesh)
        return Problem(p.scene, p.mesh, p.model, p.targets, repick(self.report, self.levels, k))

    def check(self, solved, resolve):
        """``solved`` = (problem, equilibrium, result document, history) of
        a solve on :attr:`problem`; ``resolve(problem, contraction by winch
        name)`` solves again on another level from there. Returns the same
        four of the last solve, its document's ``accuracy`` with
        ``at_result`` (and ``mesh_accuracy`` with each check's levels)."""
        if self.levels is None:
            return solved
        rounds, resolves = [], 0
        for attempt in range(MAX_RESOLVES + 1):
            p, eq, doc, history = solved
            if not eq.converged:            # no certified pose: nothing to estimate at, and nothing claimed
                lv = self.levels[self.index]
                rounds.append({"contraction": dict(zip(p.winch_names, eq.contraction.tolist())),
                               "element": lv.element, "nodes": lv.mesh.n_nodes, "estimated_error": None,
                               "met": False, "levels": []})
                break
            self.progress(f"accuracy: estimating the error at the returned contractions on the "
                          f"{len(self.levels)} levels")
            at = bounds_at(self.scene, self.levels, self.report["contractions"], eq.contraction,
                           self.report["point_coordinates"], start=(p.mesh, eq.x))
            used = at[self.index]
            rounds.append({"contraction": dict(zip(p.winch_names, eq.contraction.tolist())),
                           "element": used.element, "nodes": used.mesh.n_nodes,
                           "estimated_error": _number(used.bound), "met": used.meets(self.tol),
                           "levels": [lv.row() for lv in at]})
            if used.meets(self.tol) or attempt == MAX_RESOLVES:
                break
            k, extended = cheapest_meeting(at, self.tol), False
            if k is None:             # no level solved so far meets it there: the sweep goes on, there too
                k, extended = self._extend(at, eq.contraction), True
            if k is None:
                break
            if (self.levels[k].element, self.levels[k].resolution) == (used.element, used.resolution):
                if extended:          # the same level: estimate again on the sweep's levels, no new solve
                    continue
                break
            resolves += 1
            est = "no estimate" if used.bound is None else f"estimated {used.bound:.3g}"
            self.progress(f"accuracy: the {used.element} level of {used.mesh.n_nodes:,} nodes is {est} > "
                          f"{self.tol:g} at the returned contractions: solving again on the {self.levels[k].element} "
                          f"level of {self.levels[k].mesh.n_nodes:,} nodes")
            solved = resolve(self._problem(k), dict(zip(p.winch_names, eq.contraction.tolist())))
        p, eq, doc, history = solved
        if rounds:
            last = rounds[-1]
            at_result = {k: last[k] for k in ("contraction", "element", "nodes", "estimated_error", "met")}
            at_result["resolves"] = resolves
            at_result["summary"] = at_result_summary(at_result, self.tol)
            doc["accuracy"]["at_result"] = at_result
            doc["mesh_accuracy"]["at_result"] = rounds
        return p, eq, doc, history

    def _extend(self, at, contraction) -> int | None:
        """No level of the sweep meets the tolerance at ``contraction``
        (``at``: the levels solved there): the sweep continues at that
        contraction alone, each level solved so far kept with its pose
        there, and finer levels solved until one meets the tolerance there.
        (At the probe contractions and ``contraction`` together the largest
        differences can shrink where those at ``contraction`` alone do not:
        the estimate that matters is the one at the returned pose.) Its
        levels and report replace the sweep's; returns the index of the
        cheapest level meeting the tolerance there, or None."""
        c = np.asarray(contraction, dtype=np.float64).reshape(1, -1)
        seeds = {(here.element, here.resolution): here for here in at}
        self.progress(f"accuracy: no level solved meets {self.tol:g} at the returned contractions: "
                      "the sweep goes on there")
        best, self.levels, self.report = choose_levels(self.scene, self.tol, contractions=c, solved=seeds,
                                                       progress=self.progress)
        return self.levels.index(best) if self.report["reached"] else None


def repick(report: dict, levels, k: int) -> dict:
    """The sweep's ``report`` with level ``k`` of ``levels`` in use (its
    ``estimated_error`` the bound of that level at the probe contractions)."""
    if k == report["picked"]:
        return report
    lv = levels[k]
    reached = lv.meets(report["tolerance"])
    out = dict(report)
    out.update(element=lv.element, nodes=lv.mesh.n_nodes, max_area=lv.max_area,
               refinements=lv.resolution.refinements, n_elems=lv.mesh.n_elems, t_solve_s=lv.t_solve,
               picked=k, bound_via=lv.bound_via if reached else None, estimated_error=_number(lv.bound),
               reached=reached, status="met" if reached else "tolerance_not_met")
    out["summary"] = summary(out)
    return out


def at_result_summary(at_result: dict, tol: float) -> str:
    """One line: the estimate at the returned contractions, honestly."""
    est = at_result["estimated_error"]
    where = f"{at_result['element']} elements, {at_result['nodes']} nodes"
    again = f" (solved again on it {at_result['resolves']}x)" if at_result["resolves"] else ""
    if at_result["met"]:
        return (f"at the returned contractions: estimated error {est:.3g} <= tolerance {tol:.3g} "
                f"on {where}{again}")
    value = "no estimate" if est is None else f"estimated error {est:.3g}"
    return f"at the returned contractions: tolerance {tol:.3g} NOT met: {value} on {where}{again}"


def _number(v):
    import math
    return None if v is None or not math.isfinite(v) else float(v)
