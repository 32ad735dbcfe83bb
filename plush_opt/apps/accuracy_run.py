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
from ..base.errors import SceneError
from ..solve.accuracy import (ELEMENT_ORDER, Resolution, cheapest_meeting, choose_levels, default_levels,
                              level_mesh, level_model, summary)
from ..solve.accuracy_check import CHECK_ELEMENT, bound_through, bounds_at, finer, fold_at, seed_level
from ..solve.accuracy_carry import carried_start
from ..solve.accuracy_path import extend_along, levels_along
from ..solve.fold_limit import FoldLimit, fold_limit, held_winches
from ..solve.plant import path_dependent

log = logging.getLogger("plush_opt")

#: Re-solves on another level at most: each starts at the previous answer,
#: whose contractions the new level was chosen for, so one normally suffices.
MAX_RESOLVES = 2
#: Control runs again with winches held short of a fold (or from the pose
#: the path from rest reaches, where the answer's own pose folded) at most
#: this many times: a finer level can fold earlier than the one that set the
#: limit, and a run can land on a folded branch again (the crescent at 1
#: took a limit, a new start, a limit and a new start).
MAX_FOLD_LIMITS = 5


class AccurateSolve:
    """The mesh levels of one problem file for a tolerance, and the level in
    use (``problem``: the :class:`~plush_opt.problem.Problem` on it, its
    ``mesh_report`` the sweep's report for that level). ``progress(line)``
    hears what is being solved (default: the log, at info level)."""

    def __init__(self, path, tol: float, progress=None):
        self.progress = progress or (lambda line: log.info("%s", line))
        self.scene = load_scene(path)
        self.tol = float(tol)
        self.refuted = False      # a P1 claim disagreed with P2 at a returned pose: P2 levels alone from then on
        # friction: each level's pose is the end of a path (the sweep's: fresh paths from the start
        # state; at the returned pose: the returned path replayed), and P2 levels alone (the check of
        # P1 claims against P2 solves at fixed contractions)
        self.path_dependent = path_dependent(self.scene)
        if self.scene.outline is None:        # an explicit mesh: nothing to choose, nothing to check
            self.levels = None
            self.problem = load(path, accuracy=tol)
            return
        self.progress(f"accuracy: choosing the element and mesh for tolerance {tol:g} (a sweep of mesh levels)")
        elements = (CHECK_ELEMENT,) if self.path_dependent else ELEMENT_ORDER
        best, self.levels, self.report = choose_levels(self.scene, tol, elements=elements, progress=self.progress)
        self.problem = self._problem(self.levels.index(best))

    def _problem(self, k: int) -> Problem:
        self.index = k
        lv = self.levels[k]
        p = from_scene(dataclasses.replace(self.scene, element=lv.element), lv.mesh)
        return Problem(p.scene, p.mesh, p.model, p.targets, repick(self.report, self.levels, k))

    def check(self, solved, resolve, start=None, frozen=()):
        """``solved`` = (problem, equilibrium, result document, history) of
        a solve on :attr:`problem`; ``resolve(problem, contraction by winch
        name, x0)`` solves again on another level from there (``x0``: a
        first pose on its mesh, or None). ``start``: the
        contractions by winch name the first solve started from (default:
        the file's); a P1 answer that no P2 level can follow (every P2 level
        solved has no equilibrium near it) is left for a solve on a P2 level
        from there. ``frozen``: the winches held besides the scene's (by
        name; a fold limit never lowers theirs). Returns the same four of
        the last solve, its document's ``accuracy`` with ``at_result`` (and
        ``mesh_accuracy`` with each check's levels)."""
        if self.levels is None:
            return solved
        rounds, resolves, moves, limits = [], 0, 0, []
        for attempt in range(MAX_RESOLVES + MAX_FOLD_LIMITS + 1):
            p, eq, doc, history = solved
            here = dict(zip(p.winch_names, eq.contraction.tolist()))
            if not eq.converged:            # no certified pose: nothing to estimate at, and nothing claimed
                lv = self.levels[self.index]
                rounds.append({"contraction": here, "element": lv.element, "nodes": lv.mesh.n_nodes,
                               "estimated_error": None, "met": False, "levels": []})
                break
            found = self._estimate_at(p, eq, doc.get("method"), history)
            rounds.append(found["round"])
            if found["round"]["met"]:
                break
            if "crosses_itself" in found["round"]:
                # a fold there: finer levels fold further, and no level resolves the answer; control
                # again with the winches that led there held short of the fold (or from the pose the
                # path from rest reaches, where that does not fold)
                limit = None if len(limits) == MAX_FOLD_LIMITS or doc.get("method", "forward") == "forward" else \
                    limit_short_of_fold(self.scene, self.report, p, eq, frozen, found, self.progress)
                if limit is None:
                    break
                limits.append(limit)
                resolves += 1
                self.scene = limit.applied(self.scene)
                # (with bounds: from rest, a path the scan found free of creases to them)
                solved = self._again(resolve, self.index, _clipped(here, limit.bounds), limit.start)
                continue
            if moves == MAX_RESOLVES:
                break
            k, again, extended, why = self._next_level(found, here, start)
            if k is None:
                break
            used = found["used"]
            if (self.levels[k].element, self.levels[k].resolution) == (used.element, used.resolution):
                if extended:          # the same level: estimate again on the sweep's levels, no new solve
                    self.index = k    # (its place among them: the sweep's levels replaced the ones before)
                    continue
                break
            resolves, moves = resolves + 1, moves + 1
            self.progress(f"accuracy: the {used.element} level of {used.mesh.n_nodes:,} nodes {why}: solving again "
                          f"on the {self.levels[k].element} level of {self.levels[k].mesh.n_nodes:,} nodes"
                          + (" from the start" if again is not here else ""))
            answer = (p.mesh, eq.x) if again is here else None
            limit = None if answer is None or len(limits) == MAX_FOLD_LIMITS or \
                doc.get("method", "forward") == "forward" else \
                limit_before_solving(self.scene, self.report, p, self.levels if extended else found["at"], k,
                                     eq.contraction, frozen, self.progress)
            if limit is not None:        # the run would start on a folded branch there
                limits.append(limit)
                self.scene = limit.applied(self.scene)
                again, answer = _clipped(again, limit.bounds), limit.start
            solved = self._again(resolve, k, again, answer)
        p, eq, doc, history = solved
        if rounds:
            doc["accuracy"]["at_result"] = at_result_of(rounds[-1], resolves, limits, self.tol)
            doc["mesh_accuracy"]["at_result"] = rounds
        return p, eq, doc, history

    def _again(self, resolve, k: int, contraction: dict, answer):
        """``resolve`` on level ``k`` from ``contraction`` (by winch name),
        its first pose the ``answer`` (mesh, flat pose) carried to the
        level's mesh where it is given and carries over admissibly: Newton
        from rest can land on another branch of the same contractions (a
        body that may pass through itself has creased ones)."""
        problem = self._problem(k)
        x0 = None if answer is None else carried_start(problem.model, [answer])
        return resolve(problem, contraction, x0)

    def _estimate_at(self, p, eq, method: str, history) -> dict:
        """The levels solved at the contractions of the answer ``eq`` (on
        ``p``; by ``method``, through the control iterates ``history``), the
        estimate there and, for a claim resting on a P1 level's
        estimate, its check against P2 levels: ``round`` (what the result
        keeps), ``at`` (the levels there), ``used`` (the answer's level
        there), ``lost`` (the cheapest level finer than it that has no
        equilibrium near the answer, or None), ``cross`` and ``p2`` (of
        :meth:`_cross_check`, or None), ``waypoints`` (the path replayed, see
        :meth:`_levels_at`)."""
        self.progress(f"accuracy: estimating the error at the returned contractions on the "
                      f"{len(self.levels)} levels")
        at, waypoints = self._levels_at(p, eq, method, history)
        used = at[self.index]
        # (bounds_at solves the levels cheapest first and none after one that is lost or folded)
        fold = fold_at(self.scene, at, used)
        lost = None if fold is not None else \
            min((lv for lv in at if not lv.on_branch and finer(lv, used)), key=lambda lv: lv.cost, default=None)
        clean = lost is None and fold is None        # (a level off the branch, or a fold: nothing estimated)
        met, estimate = (used.meets(self.tol), _number(used.bound)) if clean else (False, None)
        cross = p2 = None
        via = used if used.bound_via is None else at[used.bound_via]
        if met and (used.element, via.element) != (CHECK_ELEMENT, CHECK_ELEMENT):
            # a claim resting on a P1 level's estimate (a P1 answer, or a P2 one
            # bounded through P1): never without P2 levels agreeing, nor where they crease
            cross, p2 = self._cross_check(at, eq.contraction)
            met = cross["agrees"]
            estimate = max(estimate, cross["bound"]) if met else None
            fold = None if p2 is None else fold_at(self.scene, p2[1], used)
        if fold is not None:
            met, estimate = False, None
            self.progress(fold_said(fold))
        found = {"contraction": dict(zip(p.winch_names, eq.contraction.tolist())), "element": used.element,
                 "nodes": used.mesh.n_nodes, "estimated_error": estimate, "met": met,
                 "levels": [lv.row() for lv in at]}
        if cross is not None:
            found["cross_check"] = cross
        if fold is not None:
            found["crosses_itself"] = fold
        if lost is not None:
            found["branch_lost"] = {"element": lost.element, "nodes": lost.mesh.n_nodes}
        if self.path_dependent:
            found["path"] = "the plant's fresh path from the start state" if waypoints is None else \
                f"the returned path replayed ({len(waypoints)} waypoints)"
        return {"round": found, "at": at, "used": used, "lost": lost, "cross": cross, "p2": p2,
                "waypoints": waypoints}

    def _next_level(self, found: dict, here: dict, start) -> tuple[int | None, dict, bool, str]:
        """Where to go on after an estimate at the returned contractions
        ``here`` (by winch name) that does not meet the tolerance (``found``:
        :meth:`_estimate_at`): (the index of the level to solve again on, or
        None; the contractions to solve again from; whether the sweep went
        on; why, in words)."""
        at, lost, p2 = found["at"], found["lost"], found["p2"]
        estimate = found["round"]["estimated_error"]
        if lost is not None:         # the answer's branch ends before it on a finer level: a coarse mesh's artefact
            why = (f"has an answer the {lost.element} level of {lost.mesh.n_nodes:,} nodes has no equilibrium "
                   "near (its branch does not survive refinement)")
            return self._beyond(lost), dict(start or {}), False, why
        why = f"is {'no estimate' if estimate is None else f'estimated {estimate:.3g}'} > {self.tol:g} there"
        if p2 is not None:           # the P1 claim refuted: the P2 levels solved there go on
            best, self.levels, self.report = p2
            return (self.levels.index(best) if self.report["reached"] else None), here, True, why
        if found["cross"] is not None and self.refuted:
            # no P2 pose near the P1 answer: its branch is one only P1's locking has; control
            # again on the P2 level the sweep picks at its probes, from where the first solve started
            return cheapest_meeting(self.levels, self.tol, (CHECK_ELEMENT,)), dict(start or {}), False, why
        k = cheapest_meeting(at, self.tol)
        if k is None and self.path_dependent:     # finer levels, the path replayed on each
            return self._extend_along(at, found["waypoints"], list(here.values())), here, True, why
        if k is None:                # no level solved so far meets it there: the sweep goes on, there too
            return self._extend(at, list(here.values())), here, True, why
        return k, here, False, why

    def _cross_check(self, at, contraction) -> tuple[dict, tuple | None]:
        """The level in use meets the tolerance at ``contraction`` (``at``:
        the levels solved there), and its bound rests on a P1 level's
        estimate (it is P1, or a P2 level bounded through a P1 level). P1
        levels can agree with each other long before they are right
        (locking in the bending of thin parts, near a fold), so the claim
        needs P2 estimates alone: the P2 levels are swept at
        ``contraction`` (the first from the answer carried over, those
        already solved there reused) until one meets the tolerance, and the
        answer's bound through them (its distance to a P2 level plus that
        level's estimate, :func:`~plush_opt.solve.accuracy_check.bound_through`;
        a P2 level's own bound among them) must meet it too. Returns (what the check found, for the result:
        ``element``, ``nodes`` and ``estimated_error`` of the P2 level the
        bound goes through, ``distance`` to it, ``bound``, ``agrees``,
        ``levels`` (the rows of the P2 levels solved)); the P2 sweep
        (best, levels, report), the levels to go on with when the claim is
        refuted (``self.refuted``), or None if it could not be made)."""
        used = at[self.index]
        seeds = {(lv.element, lv.resolution): lv for lv in at if lv.element == CHECK_ELEMENT and lv.on_branch}
        first = check_resolution(self.scene, self.report)
        self.progress(f"accuracy: checking the {used.element} level of {used.mesh.n_nodes:,} nodes against "
                      f"{CHECK_ELEMENT} levels at the returned contractions")
        c = np.asarray(contraction, dtype=np.float64)
        found = {"element": CHECK_ELEMENT, "nodes": None, "estimated_error": None, "distance": None,
                 "bound": None, "agrees": False, "levels": []}
        try:
            if not seeds:                # the first P2 level from the answer: the same branch of equilibria
                lv = seed_level(self.scene, used, c, first, self.report["point_coordinates"])
                seeds[(CHECK_ELEMENT, first)] = lv
                self.progress(f"accuracy: {CHECK_ELEMENT} level of {lv.mesh.n_nodes:,} nodes solved from the answer "
                              f"(one solve {lv.t_solve:.2f} CPU s)")
            # (the other element's poses there serve as starts where no P2 pose carries over admissibly)
            starts = {(lv.element, lv.resolution): lv for lv in at if lv.element != CHECK_ELEMENT and lv.on_branch}
            sweep = choose_levels(self.scene, self.tol, contractions=c[None], solved={**starts, **seeds},
                                  elements=(CHECK_ELEMENT,), progress=self.progress, follow=True)
        except SceneError as exc:      # no certified P2 pose there: no agreement shown, nothing claimed
            self.refuted = True
            return {**found, "note": str(exc)}, None
        same = [lv for lv in sweep[1] if (lv.element, lv.resolution) == (used.element, used.resolution)]
        bound, via = (same[0].bound, sweep[1][same[0].bound_via]) if same and same[0].bound is not None \
            else bound_through(used, sweep[1])
        agrees = bound is not None and bound <= self.tol
        self.refuted = self.refuted or not agrees
        found.update(agrees=agrees, bound=bound, levels=[lv.row() for lv in sweep[1]])
        if via is not None:
            found.update(nodes=via.mesh.n_nodes, estimated_error=via.estimate,
                         distance=float(np.max(np.linalg.norm(used.y[-1] - via.y[-1], axis=-1))))
        said = "not checked: no P2 level has an estimate there" if via is None else (
            f"{found['distance']:.3g} from the {CHECK_ELEMENT} level of {via.mesh.n_nodes:,} nodes (its estimate "
            f"{via.estimate:.3g}): bound {bound:.3g}")
        self.progress(f"accuracy: the {used.element} answer is {said}" + (
            "" if agrees else f"; {used.element} is not trusted here, the {CHECK_ELEMENT} levels go on"))
        return found, sweep

    def _levels_at(self, p, eq, method: str, history):
        """The sweep's levels solved at the returned pose (``eq`` on ``p``)
        and estimated there, and the path replayed on them (None: none, or
        a forward solve's fresh path): where the pose depends on the path,
        each level replays the one ``eq`` was reached by (the control run's
        iterates ``history``), else each is solved at its contractions."""
        points = self.report["point_coordinates"]
        if not self.path_dependent:
            return bounds_at(self.scene, self.levels, self.report["contractions"], eq.contraction, points,
                             start=(p.mesh, eq.x), progress=self.progress, used=self.index), None
        waypoints = None if method == "forward" else np.array([it.contraction for it in history])
        return levels_along(self.scene, self.levels, waypoints, eq.contraction, points, answer=(p.mesh, eq.x),
                            progress=self.progress), waypoints

    def _extend_along(self, at, waypoints, contraction) -> int | None:
        """:meth:`_extend` where the pose depends on the path: the default
        levels not solved yet, the returned path replayed on each
        (:func:`~plush_opt.solve.accuracy_path.extend_along`); they replace
        the sweep's levels. Returns the index of the cheapest level meeting
        the tolerance along the path, or None."""
        self.progress(f"accuracy: no level solved meets {self.tol:g} at the end of the returned path: "
                      "finer levels, the path replayed on each")
        self.levels, k = extend_along(self.scene, at, waypoints, contraction, self.report["point_coordinates"],
                                      self.tol, CHECK_ELEMENT, progress=self.progress)
        self.report = {**self.report, "picked": None}      # indices of the sweep's levels no longer hold
        return k
    def _beyond(self, lost) -> int | None:
        """The level to solve again on when the level ``lost`` (as solved at
        a returned contraction) has no equilibrium near the answer: the one
        of least cost among ``lost`` and the levels finer than
        it that meets the tolerance at the probe contractions (P2 alone after
        a refuted P1 claim), or None."""
        elements = (CHECK_ELEMENT,) if self.refuted else ELEMENT_ORDER
        ok = [i for i, lv in enumerate(self.levels) if (lv.element, lv.resolution) == (lost.element, lost.resolution)
              or finer(lv, lost)]
        return cheapest_meeting([lv if i in ok else None for i, lv in enumerate(self.levels)], self.tol, elements)

    def _extend(self, at, contraction) -> int | None:
        """No level of the sweep meets the tolerance at ``contraction``
        (``at``: the levels solved there): the sweep continues at that
        contraction alone, each level solved so far kept with its pose
        there, and finer levels solved until one meets the tolerance there
        (of P2 alone after a refuted P1 claim).
        (At the probe contractions and ``contraction`` together the largest
        differences can shrink where those at ``contraction`` alone do not:
        the estimate that matters is the one at the returned pose.) Its
        levels and report replace the sweep's; returns the index of the
        cheapest level meeting the tolerance there, or None."""
        c = np.asarray(contraction, dtype=np.float64).reshape(1, -1)
        kept = {(here.element, here.resolution): here for here in at}
        elements = (CHECK_ELEMENT,) if self.refuted else ELEMENT_ORDER
        self.progress(f"accuracy: no level solved meets {self.tol:g} at the returned contractions: "
                      "the sweep goes on there" + (f" ({CHECK_ELEMENT} levels)" if self.refuted else ""))
        best, self.levels, self.report = choose_levels(self.scene, self.tol, contractions=c, solved=kept,
                                                       elements=elements, progress=self.progress, follow=True)
        return self.levels.index(best) if self.report["reached"] else None

def repick(report: dict, levels, k: int) -> dict:
    """The sweep's ``report`` with level ``k`` of ``levels`` in use (its
    ``estimated_error`` the bound of that level at the probe contractions;
    ``solved_again``: chosen at the returned contractions, not the probes)."""
    if k == report["picked"]:
        return report
    lv = levels[k]
    reached = lv.meets(report["tolerance"])
    out = dict(report)
    out.update(element=lv.element, nodes=lv.mesh.n_nodes, max_area=lv.max_area,
               refinements=lv.resolution.refinements, n_elems=lv.mesh.n_elems, t_solve_s=lv.t_solve,
               work_s=lv.work, picked=k, bound_via=lv.bound_via if reached else None,
               estimated_error=_number(lv.bound), reached=reached, solved_again=True,
               status="met" if reached else "tolerance_not_met")
    out["summary"] = summary(out)
    return out


def at_result_of(last: dict, resolves: int, limits, tol: float) -> dict:
    """The result's ``accuracy.at_result`` from the ``last`` round of the
    check (:meth:`AccurateSolve._estimate_at`), after ``resolves`` solves
    again and the fold ``limits`` laid (:class:`FoldLimit`)."""
    at_result = {k: last[k] for k in ("contraction", "element", "nodes", "estimated_error", "met")}
    at_result["resolves"] = resolves
    if limits:
        at_result["fold_limits"] = [limit.row() for limit in limits]
    for key in ("path", "crosses_itself"):
        if key in last:
            at_result[key] = last[key]
    if "cross_check" in last:
        at_result["cross_check"] = {k: last["cross_check"][k] for k in ("element", "nodes", "distance", "bound",
                                                                        "agrees")}
    at_result["summary"] = at_result_summary(at_result, tol)
    return at_result


def at_result_summary(at_result: dict, tol: float) -> str:
    """One line: the estimate at the returned contractions, honestly."""
    est = at_result["estimated_error"]
    where = f"{at_result['element']} elements, {at_result['nodes']} nodes"
    again = f" (solved again on it {at_result['resolves']}x)" if at_result["resolves"] else ""
    cross = at_result.get("cross_check")
    if cross is not None:
        again += (f"; no {cross['element']} level with an estimate to check it against" if cross["bound"] is None
                  else f"; {cross['distance']:.3g} from a {cross['element']} level of {cross['nodes']:,} nodes, "
                  f"bound through it {cross['bound']:.3g}")
    for limit in at_result.get("fold_limits", ()):
        level = f"the {limit['element']} level of {limit['nodes']:,} nodes"
        if limit["bounds"]:
            again += ("; " + ", ".join(f"{n} held at most {b:.4g}" for n, b in limit["bounds"].items())
                      + f" (beyond, the body folds through itself on {level})")
        else:
            again += f"; control again from the pose free of creases the path from rest reaches on {level} " \
                "(the answer's had folded)"
    if at_result["met"]:
        return (f"at the returned contractions: estimated error {est:.3g} <= tolerance {tol:.3g} "
                f"on {where}{again}")
    value = "no estimate" if est is None else f"estimated error {est:.3g}"
    fold = at_result.get("crosses_itself")
    if fold is not None:
        value += (f" (the body crosses itself there on the {fold['element']} level of {fold['nodes']:,} nodes, "
                  "and no mesh resolves a fold: add `self: true` under `contact:` to forbid it)")
    return f"at the returned contractions: tolerance {tol:.3g} NOT met: {value} on {where}{again}"


def fold_said(fold: dict) -> str:
    """The progress line of a fold at the returned contractions (:func:`fold_at`)."""
    return (f"accuracy: at the returned contractions the body crosses itself on the {fold['element']} "
            f"level of {fold['nodes']:,} nodes ({fold['where']}; the scene has no contact.self): "
            "a fold has no converged answer, nothing is estimated there")


def limit_short_of_fold(scene, report: dict, p, eq, frozen, found: dict, progress) -> FoldLimit | None:
    """Upper bounds short of the fold ``found`` (:meth:`AccurateSolve._estimate_at`)
    at the answer ``eq`` of a control run on ``p`` (``frozen``: the winches
    it held besides the scene's, by name): :func:`lay_fold_limit` on the
    level that folds (one solved there, or one a P1 claim was checked
    against). None where no winch moved or there is no room short of the
    fold; ``progress(line)`` hears which."""
    fold = found["round"]["crosses_itself"]
    own = (fold["element"], fold["nodes"]) == (str(p.model.element), p.mesh.n_nodes)
    levels = list(found["at"]) + (list(found["p2"][1]) if found.get("p2") is not None else [])
    return lay_fold_limit(scene, report, p.model, eq.contraction, frozen, fold, levels, own,
                          "the body folds at the answer", progress)


def limit_before_solving(scene, report: dict, p, levels, k: int, contraction, frozen, progress) -> FoldLimit | None:
    """Upper bounds to lay before control runs again on ``levels[k]`` from
    ``contraction`` (the answer of a run on ``p``; ``levels`` as solved
    there): where that level's pose there creases, the run would start on a
    folded branch (a body that may pass through itself can fold on a finer
    mesh at contractions a coarser one reached unfolded), walk it and end
    creased. :func:`lay_fold_limit` on that level; None where its pose
    there does not crease, or no limit can be laid."""
    fold = fold_at(scene, [levels[k]], levels[k])
    if fold is None:
        return None
    return lay_fold_limit(scene, report, p.model, contraction, frozen, fold, levels, True,
                          f"the {fold['element']} level of {fold['nodes']:,} nodes creases there", progress)


def lay_fold_limit(scene, report: dict, model, contraction, frozen, fold: dict, levels, own: bool, what: str,
                   progress) -> FoldLimit | None:
    """Upper bounds short of ``fold`` (a crease at ``contraction`` on one of
    ``levels``, :func:`~plush_opt.solve.accuracy_check.fold_at`) for the
    winches of ``model`` (any level's) not ``frozen`` (by name, besides the
    scene's) that a run drove to their upper bounds (or, where none is, for
    every one it moved: :func:`~plush_opt.solve.fold_limit.held_winches`,
    :func:`~plush_opt.solve.fold_limit.fold_limit`), scanned on the level
    that folds and, where that is P1, on the cheapest :data:`CHECK_ELEMENT`
    level of ``levels`` or the sweep ``report`` (P1 locks in bending and
    folds later). Where nothing creases on the way, a limit without bounds
    (control again from the pose the path reaches) if the fold is on the
    level control runs on (``own``), else None. None too where no winch
    moved or there is no room short of the fold; ``progress(line)`` hears
    which (``what``: the fold, in words)."""
    frozen = set(frozen) | {n for n, f in zip(model.winch_names, scene.frozen) if f}
    held = held_winches(model, contraction, frozen)
    if not held.any():
        return None
    scanned = [next(lv for lv in levels if (lv.element, lv.mesh.n_nodes) == (fold["element"], fold["nodes"]))]
    if fold["element"] != CHECK_ELEMENT:
        scanned.append(min((lv for lv in levels if lv.element == CHECK_ELEMENT), key=lambda lv: lv.cost,
                           default=None) or check_resolution(scene, report))
    names = ", ".join(n for n, h in zip(model.winch_names, held) if h)
    progress(f"accuracy: {what}: scanning {names} for the last contraction short of the fold on "
             f"{len(scanned)} level(s)")
    limit, why = fold_limit([level_model_of(scene, lv) for lv in scanned], contraction, held)
    if limit is None or not (limit.bounds or own):
        progress(f"accuracy: no limit short of the fold: {why}")
        return None
    if not limit.bounds:        # the pose there folded; the path there from rest does not
        progress(f"accuracy: {why}: the pose there is on another branch; control again from the pose "
                 "that path reaches")
        return limit
    progress(f"accuracy: the {limit.element} level of {limit.nodes:,} nodes folds beyond {limit.fraction:.3g} "
             "of the way there; control again with " + ", ".join(f"{n} <= {b:.4g}" for n, b in limit.bounds.items()))
    return limit


def check_resolution(scene, report: dict) -> Resolution:
    """The coarsest :data:`CHECK_ELEMENT` level of the sweep ``report`` of
    ``scene`` (solved or not)."""
    first = [Resolution(r["family"], 0, r["family"]) for r in report.get("not_solved", ())
             if r["element"] == CHECK_ELEMENT and r["refinements"] == 0]
    return max(first, key=lambda res: res.max_area, default=None) or default_levels(scene, CHECK_ELEMENT)[0]


def level_model_of(scene, level):
    """The model of ``level`` of ``scene`` (a :class:`Level`, or a
    :class:`Resolution` of :data:`CHECK_ELEMENT` not solved yet, meshed here)."""
    if isinstance(level, Resolution):
        scene = dataclasses.replace(scene, element=CHECK_ELEMENT)
        return level_model(scene, level_mesh(scene, level))
    return level.model if level.model is not None else \
        level_model(dataclasses.replace(scene, element=level.element), level.mesh)


def _clipped(contraction: dict, bounds: dict) -> dict:
    """``contraction`` (by winch name) with the winches of ``bounds`` at most those."""
    return {n: min(v, bounds[n]) if n in bounds else v for n, v in contraction.items()}


def _number(v):
    import math
    return None if v is None or not math.isfinite(v) else float(v)
