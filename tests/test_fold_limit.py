"""Winches held short of a fold (plush_opt.solve.fold_limit): where a
control run's answer creases, ``--accuracy`` lowers the upper bounds of the
winches it drove there to the last contraction free of creases and runs
control again."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from plush_opt.fem.contact_boundary import crossings
from plush_opt.io import load_scene
from plush_opt.solve.accuracy import default_levels, equilibrium_at, level_mesh, level_model
from plush_opt.solve.fold_limit import (FOLD_BISECTIONS, FOLD_CLEARANCE, crease_free_fraction, fold_limit,
                                        held_winches)

ROOT = Path(__file__).resolve().parents[1]
CRESCENT = ROOT / "tests" / "data" / "crescent_coarse.yaml"
# curled hard, the lower arm's inner edge creases on fine P2 meshes (the answer of a control run
# whose target is on the upper tip drives `lower` to its bound, 12)
CURLED = np.array([8.0, 12.0])
LOWER = np.array([False, True])


def _level(scene, element: str, index: int):
    res = default_levels(scene, element)[index]
    sc = dataclasses.replace(scene, element=element)
    return level_model(sc, level_mesh(sc, res))


@pytest.fixture(scope="module")
def crescent():
    scene = load_scene(CRESCENT)
    return scene, _level(scene, "P2", 0), _level(scene, "P2", 2)


def test_the_limit_is_the_last_contraction_short_of_the_crease(crescent):
    scene, coarse, fine = crescent
    s, where, x_limit = crease_free_fraction(fine, CURLED, LOWER)
    assert 0.5 < s < 0.9 and "a crease" in where
    start = np.array([CURLED[0], 0.0])

    def creases(fraction, x0):
        eq = equilibrium_at(fine, start + fraction * (CURLED - start), x0)
        assert eq.converged
        return eq.x, crossings(fine, [eq.x], creases_only=True)[0] is not None

    x, folded = creases(s, None)
    assert not folded and np.allclose(x, x_limit, atol=1e-6)
    _, folded = creases(s + 2.0 ** -FOLD_BISECTIONS, x)     # one bisection step on: the crease
    assert folded
    # the coarse level does not crease there: it sets no limit, and the finer one does
    assert crease_free_fraction(coarse, CURLED, LOWER)[:2] == (1.0, None)
    limit, why = fold_limit([coarse, fine], CURLED, LOWER)
    assert why is None and limit.nodes == fine.n_nodes and limit.element == "P2"
    assert limit.bounds == {"lower": pytest.approx((s - FOLD_CLEARANCE) * 12.0)}
    assert "upper" not in limit.bounds
    limited = limit.applied(scene)
    assert limited.upper.tolist() == [12.0, pytest.approx((s - FOLD_CLEARANCE) * 12.0)]
    assert limited.lower.tolist() == scene.lower.tolist() and limited.winch_names == scene.winch_names
    assert limit.row()["where"] == where


def test_where_nothing_creases_on_the_way_no_bounds_but_the_pose_reached(crescent):
    """Nothing to limit; the pose reached along the way is the start for a
    control run again where the answer's own pose folded (another branch)."""
    scene, coarse, _ = crescent
    limit, why = fold_limit([coarse], CURLED, LOWER)
    assert limit.bounds == {} and "no level scanned creases" in why and limit.applied(scene) == scene
    mesh, x = limit.start
    eq = equilibrium_at(coarse, CURLED, x)
    assert mesh is coarse.mesh
    assert eq.converged and eq.iterations <= 1 and crossings(coarse, [x], creases_only=True) == (None,)
    assert limit.row()["from_rest"] is True


def test_the_winches_a_fold_is_laid_to(crescent):
    _, coarse, _ = crescent
    # at its upper bound: that winch alone (the run drove it there)
    assert held_winches(coarse, [8.0, 12.0], frozen=()).tolist() == [False, True]
    # frozen there: not the run's doing, never limited; the others that moved are
    assert held_winches(coarse, [8.0, 12.0], frozen={"lower"}).tolist() == [True, False]
    # none at an upper bound: every winch the run moved
    assert held_winches(coarse, [8.0, 3.0], frozen=()).tolist() == [True, True]
    assert held_winches(coarse, [8.0, 0.0], frozen=()).tolist() == [True, False]


def _accurate(said):
    """An AccurateSolve on the coarse crescent's file mesh (P1), its sweep
    left out: the levels the check uses are the tests' own."""
    from types import SimpleNamespace
    from plush_opt.apps.accuracy_run import AccurateSolve
    from plush_opt.problem import load
    p = load(CRESCENT)
    acc = object.__new__(AccurateSolve)
    acc.tol, acc.progress, acc.scene, acc.refuted, acc.path_dependent = 1.0, said.append, p.scene, False, False
    acc.levels, acc.index, acc.report = [SimpleNamespace(element="P1", mesh=p.mesh)], 0, {"picked": 0}
    return acc, p


def _control_doc(method="reparam"):
    return {"method": method, "control": {"frozen": []}, "accuracy": {}, "mesh_accuracy": {}}


@pytest.mark.parametrize("method", ["reparam", "forward"])
def test_control_runs_again_with_the_winches_held_short_of_the_fold(monkeypatch, method):
    """The check's rounds: the first answer (lower at its bound, 12) folds on
    a P2 level; control runs again on the answer's level with lower's upper
    bound the limit, from the answer's contractions clipped to it, from rest
    (the scan found that path free of creases to there; the answer's pose,
    at other contractions, can carry a run onto a folded branch: the
    crescent's P2 level of 20,517 nodes did); the second answer meets the tolerance, and the
    result keeps the limit and says it. A forward solve (the user's
    contractions) is never limited: it ends not met, as before."""
    from types import SimpleNamespace
    import plush_opt.apps.accuracy_run as run
    from plush_opt.solve.fold_limit import FoldLimit
    said, scanned, resolved = [], [], []
    acc, p = _accurate(said)
    fine = SimpleNamespace(element="P2", mesh=SimpleNamespace(n_nodes=4027), model="the P2 model", cost=1.0)
    where = "boundary segments 445-1515 and 1386-407 cross near (-1.639, -30.13): a crease"
    rounds = iter([{"crosses_itself": {"element": "P2", "nodes": 4027, "where": where},
                    "estimated_error": None, "met": False},
                   {"estimated_error": 0.3, "met": True}])

    def estimate_at(p, eq, method, history):
        found = {"contraction": dict(zip(p.winch_names, eq.contraction.tolist())), "element": "P1",
                 "nodes": p.mesh.n_nodes, "levels": [], **next(rounds)}
        return {"round": found, "at": [fine], "used": None}

    limit = FoldLimit({"lower": 8.0}, 0.72, "P2", 4027, where)
    monkeypatch.setattr(acc, "_estimate_at", estimate_at)
    monkeypatch.setattr(run, "fold_limit", lambda models, c, held: scanned.append((models, held.tolist())) or
                        (limit, None))

    def resolve(problem, contraction, x0=None):
        resolved.append((problem, contraction, x0))
        eq = SimpleNamespace(converged=True, contraction=np.array([contraction["upper"], 8.0]), x=problem.model.X)
        return problem, eq, _control_doc(method), ()

    eq = SimpleNamespace(converged=True, contraction=np.array([8.0, 12.0]), x=p.model.X)
    _, last, doc, _ = acc.check((p, eq, _control_doc(method), ()), resolve)
    at = doc["accuracy"]["at_result"]
    if method == "forward":
        assert resolved == [] and scanned == [] and at["met"] is False and "fold_limits" not in at
        assert "crosses_itself" in at
        return
    assert scanned == [(["the P2 model"], [False, True])]          # lower alone: at its bound
    (problem, contraction, x0), = resolved
    assert contraction == {"upper": 8.0, "lower": 8.0}
    assert problem.model.upper.tolist() == [12.0, 8.0] and problem.mesh is p.mesh
    assert x0 is None                                                # from rest
    assert at["met"] is True and at["resolves"] == 1 and at["fold_limits"] == [limit.row()]
    assert "lower held at most 8" in at["summary"] and "P2 level of 4,027 nodes" in at["summary"]
    assert any("control again with lower <= 8" in line for line in said)


def test_an_answer_folded_on_another_branch_runs_again_from_the_path_from_rest(monkeypatch):
    """The answer's own pose folds, but the path to its contractions from
    the winches' lower bounds does not: control runs again at the same
    contractions and bounds, from the pose that path reaches."""
    from types import SimpleNamespace
    import plush_opt.apps.accuracy_run as run
    from plush_opt.solve.fold_limit import FoldLimit
    said, resolved = [], []
    acc, p = _accurate(said)
    own = SimpleNamespace(element="P1", mesh=p.mesh, model=p.model, cost=1.0)
    rounds = iter([{"crosses_itself": {"element": "P1", "nodes": p.mesh.n_nodes, "where": "a crease"},
                    "estimated_error": None, "met": False},
                   {"estimated_error": 0.3, "met": True}])
    monkeypatch.setattr(acc, "_estimate_at", lambda p, eq, method, history: {
        "round": {"contraction": {}, "element": "P1", "nodes": p.mesh.n_nodes, "levels": [], **next(rounds)},
        "at": [own], "used": own})
    path_pose = p.model.X + 0.01
    limit = FoldLimit({}, 1.0, "P1", p.mesh.n_nodes, None, start=(p.mesh, path_pose))
    monkeypatch.setattr(run, "fold_limit", lambda models, c, held: (limit, "no level scanned creases on the way"))

    def resolve(problem, contraction, x0=None):
        resolved.append((problem, contraction, x0))
        return problem, SimpleNamespace(converged=True, contraction=np.array([7.0, 0.0]), x=x0), _control_doc(), ()

    eq = SimpleNamespace(converged=True, contraction=np.array([7.0, 0.0]), x=p.model.X)
    _, _, doc, _ = acc.check((p, eq, _control_doc(), ()), resolve)
    (problem, contraction, x0), = resolved
    assert contraction == {"upper": 7.0, "lower": 0.0} and problem.model.upper.tolist() == [12.0, 12.0]
    assert np.array_equal(x0, path_pose)
    at = doc["accuracy"]["at_result"]
    assert at["met"] is True and at["fold_limits"][0]["from_rest"] is True
    assert "control again from the pose free of creases" in at["summary"]
    assert any("another branch" in line for line in said)


def test_a_level_carried_onto_a_folded_branch_is_solved_again_from_rest(crescent):
    """A body that may pass through itself keeps a fold once it has one: the
    coarse crescent's P2 level curled to lower 12 (creased) and brought
    back to 8 stays creased, where the path from rest to 8 does not crease.
    The check at the returned contractions (a level carried from a pose
    that lands it there) takes the pose the path from rest reaches; at 10,
    where that path creases too, it keeps the fold it found."""
    from plush_opt.solve.accuracy import LEVEL_OPTIONS
    from plush_opt.solve.accuracy_check import _unfolded
    _, _, fine = crescent
    x = None
    for lower in (4.0, 8.0, 12.0):                       # curled hard: creased at 12
        x = equilibrium_at(fine, np.array([8.0, lower]), x).x
    assert crossings(fine, [x], creases_only=True)[0] is not None
    for lower, unfolds in ((10.0, False), (8.0, True)):
        eq = equilibrium_at(fine, np.array([8.0, lower]), x)
        crossing = crossings(fine, [eq.x], creases_only=True)
        assert eq.converged and crossing[0] is not None          # brought back: still creased
        again, how, found = _unfolded(fine, eq, "from the pose before", crossing, LEVEL_OPTIONS)
        if unfolds:
            assert found == (None,) and again.converged and how.startswith("by continuation from rest")
            assert crossings(fine, [again.x], creases_only=True) == (None,)
        else:
            assert again is eq and found == crossing and how == "from the pose before"


def test_a_winch_the_caller_froze_is_never_limited_whatever_the_method(monkeypatch):
    """``--freeze lower`` on a bilevel run (whose result has no gradient
    loop's ``control`` block) with `lower` at its upper bound: the fold
    limit is laid to the winch the run moved, never to the frozen one."""
    from types import SimpleNamespace
    import plush_opt.apps.accuracy_run as run
    said, scanned = [], []
    acc, p = _accurate(said)
    fine = SimpleNamespace(element="P2", mesh=SimpleNamespace(n_nodes=4027), model="the P2 model", cost=1.0)
    monkeypatch.setattr(acc, "_estimate_at", lambda p, eq, method, history: {
        "round": {"contraction": {}, "element": "P1", "nodes": p.mesh.n_nodes, "levels": [], "met": False,
                  "estimated_error": None, "crosses_itself": {"element": "P2", "nodes": 4027, "where": "a crease"}},
        "at": [fine], "used": None})
    monkeypatch.setattr(run, "fold_limit", lambda models, c, held: scanned.append(held.tolist()) or
                        (None, "no room"))
    eq = SimpleNamespace(converged=True, contraction=np.array([8.0, 12.0]), x=p.model.X)
    doc = {"method": "bilevel", "accuracy": {}, "mesh_accuracy": {}}
    acc.check((p, eq, doc, ()), lambda *a: pytest.fail("solved again"), frozen=("lower",))
    assert scanned == [[True, False]]


def _moving_to_a_p2_level(said, creased: bool):
    """The check of a P1 answer at (8.112, 0) that P2 refuted: the P2 sweep
    there picks a level of 20,517 nodes (its pose there creased or not)."""
    from types import SimpleNamespace
    acc, p = _accurate(said)
    used = SimpleNamespace(element="P1", resolution="P1 0", mesh=p.mesh, cost=1.0)
    fine = SimpleNamespace(element="P2", resolution="P2 1", mesh=SimpleNamespace(n_nodes=20517),
                           model="the P2 model", cost=2.0, poses=[p.model.X + 0.5],
                           crossing=["boundary segments 3919-13698 and 367-8371 cross: a crease" if creased else None])
    rounds = iter([{"estimated_error": None, "met": False}, {"estimated_error": 0.02, "met": True}])
    acc.levels = [used, fine]
    acc._estimate_at = lambda p, eq, method, history: {
        "round": {"contraction": {}, "element": "P1", "nodes": p.mesh.n_nodes, "levels": [], **next(rounds)},
        "at": [used], "used": used}
    acc._next_level = lambda found, here, start: (1, here, True, "is no estimate > 1 there")
    return acc, p


@pytest.mark.parametrize("path_creases", [True, False])
def test_a_solve_again_on_a_level_that_creases_there_lays_the_limit_first(monkeypatch, path_creases):
    """A refuted P1 answer moves to a P2 level whose pose at its
    contractions creases: control started there would walk a folded branch
    (the crescent's P2 level of 20,517 nodes at (8.112, 0): 144 s to a
    creased answer, then a scan and a run again). The level is scanned
    first; control runs on it with the winch held short of the fold, from
    rest, or, where the path from rest reaches those contractions free of
    creases, from that path's pose."""
    from types import SimpleNamespace
    import plush_opt.apps.accuracy_run as run
    from plush_opt.solve.fold_limit import FoldLimit
    said, scanned, again = [], [], []
    acc, p = _moving_to_a_p2_level(said, creased=True)
    path_pose = (p.mesh, p.model.X + 0.25)
    limit = FoldLimit({"upper": 7.3}, 0.953, "P2", 20517, "a crease") if path_creases else \
        FoldLimit({}, 1.0, "P2", 20517, None, start=path_pose)
    monkeypatch.setattr(run, "fold_limit", lambda models, c, held: scanned.append((models, held.tolist())) or
                        (limit, None if path_creases else "no level scanned creases on the way"))

    def solve_again(resolve, k, contraction, answer):
        again.append((k, contraction, answer))
        eq = SimpleNamespace(converged=True, contraction=np.array([contraction["upper"], 0.0]), x=p.model.X)
        return p, eq, _control_doc(), ()

    acc._again = solve_again
    eq = SimpleNamespace(converged=True, contraction=np.array([8.112, 0.0]), x=p.model.X)
    _, _, doc, _ = acc.check((p, eq, _control_doc(), ()), None)
    assert scanned == [(["the P2 model"], [True, False])]            # upper: the winch the run moved
    (k, contraction, answer), = again
    at = doc["accuracy"]["at_result"]
    assert k == 1 and at["met"] is True and at["resolves"] == 1 and at["fold_limits"] == [limit.row()]
    if path_creases:
        assert contraction == {"upper": 7.3, "lower": 0.0} and answer is None and acc.scene.upper.tolist() == [7.3, 12]
        assert "upper held at most 7.3" in at["summary"]
        assert any("creases there: scanning upper" in line for line in said)
    else:
        assert contraction == {"upper": 8.112, "lower": 0.0} and answer is path_pose
        assert acc.scene.upper.tolist() == [12.0, 12.0] and any("another branch" in line for line in said)


def test_a_solve_again_on_a_level_free_of_creases_there_starts_from_the_answer(monkeypatch):
    import plush_opt.apps.accuracy_run as run
    from types import SimpleNamespace
    said, again = [], []
    acc, p = _moving_to_a_p2_level(said, creased=False)
    monkeypatch.setattr(run, "fold_limit", lambda *a: pytest.fail("scanned"))

    def solve_again(resolve, k, contraction, answer):
        again.append((k, contraction, answer))
        return p, SimpleNamespace(converged=True, contraction=np.array([8.112, 0.0]), x=p.model.X), _control_doc(), ()

    acc._again = solve_again
    eq = SimpleNamespace(converged=True, contraction=np.array([8.112, 0.0]), x=p.model.X + 1.0)
    _, _, doc, _ = acc.check((p, eq, _control_doc(), ()), None)
    (k, contraction, (mesh, x)), = again
    assert contraction == {"upper": 8.112, "lower": 0.0} and mesh is p.mesh and np.array_equal(x, eq.x)
    assert "fold_limits" not in doc["accuracy"]["at_result"]


def test_the_scan_walks_the_path_and_solves_the_answer_last(monkeypatch):
    """The bisection's poses are each solved from the last one free of
    creases, so it walks the path from the lower bounds in ever smaller
    steps; the answer's contractions are solved last, and only where every
    step on the way was free of creases (a jump there from the lower bounds
    lands across the fold: the crescent's 79,625-node level spent minutes
    in it)."""
    from types import SimpleNamespace
    import plush_opt.solve.fold_limit as fl
    model = SimpleNamespace(lower=np.array([0.0, 0.0]))
    for onset, expected in ((0.7, np.floor(0.7 * 2 ** FOLD_BISECTIONS) / 2 ** FOLD_BISECTIONS), (2.0, 1.0)):
        solved = []

        def solve(model, c, x0, options):
            solved.append((float(c[1]) / 10.0, None if x0 is None else float(x0[0])))
            return SimpleNamespace(converged=True, x=np.array([float(c[1]) / 10.0]), status="converged")

        monkeypatch.setattr(fl, "creased_or_solved", solve)
        monkeypatch.setattr(fl, "crossing_of", lambda model, x, creases_only: "a crease" if x[0] > onset else None)
        s, where, x = fl.crease_free_fraction(model, np.array([5.0, 10.0]), np.array([False, True]))
        assert s == pytest.approx(expected) and x[0] == pytest.approx(expected)
        assert solved[0] == (0.0, None) and len(solved) == FOLD_BISECTIONS + 1 + (onset > 1)
        kept = 0.0
        for fraction, start in solved[1:]:           # each from the last pose found free of creases
            assert start == pytest.approx(kept)
            kept = fraction if fraction <= onset else kept
        assert (solved[-1][0] == 1.0) == (onset > 1) and (where is None) == (onset > 1)


def test_newton_that_creases_on_the_way_stops_early(crescent, monkeypatch):
    """Newton from a pose that does not crease, not converged after its
    first iterations (``BRANCH_ITERATIONS`` on a branch, ``CREASE_WATCH`` in
    the scan) and creased there, is on its way to a fold: the solve on a
    branch does not go on (``CREASED_ON_THE_WAY``), a step of the scan
    counts as creased; with nothing creasing the watch changes nothing."""
    import plush_opt.solve.accuracy_carry as carry
    import plush_opt.solve.fold_limit as fl
    from plush_opt.solve.accuracy import LEVEL_OPTIONS
    _, coarse, _ = crescent
    X = coarse.X.copy()
    plain = carry.solve_on_branch(coarse, CURLED, X, LEVEL_OPTIONS)
    assert plain.converged and plain.iterations > 2
    monkeypatch.setattr(carry, "BRANCH_ITERATIONS", 2)
    monkeypatch.setattr(carry, "BRANCH_PROGRESS", np.inf)     # (on its way, as the crescent's level was)
    monkeypatch.setattr(fl, "CREASE_WATCH", 2)
    creased = carry.solve_on_branch(coarse, CURLED, X, LEVEL_OPTIONS,
                                    lambda x: None if np.array_equal(x, X) else "a crease")
    assert not creased.converged and creased.iterations == 2
    assert creased.status == carry.CREASED_ON_THE_WAY + ": a crease"
    watched = carry.solve_on_branch(coarse, CURLED, X, LEVEL_OPTIONS, lambda x: None)
    assert watched.converged and np.max(np.abs(watched.x - plain.x)) <= 1e-6 * coarse.mesh.diameter
    monkeypatch.setattr(fl, "crossing_of", lambda model, x, creases_only: None if np.array_equal(x, X) else "a crease")
    assert fl.creased_or_solved(coarse, CURLED, X, LEVEL_OPTIONS) == "a crease"
    monkeypatch.setattr(fl, "crossing_of", lambda model, x, creases_only: None)
    again = fl.creased_or_solved(coarse, CURLED, X, LEVEL_OPTIONS)
    assert again.converged and np.max(np.abs(again.x - plain.x)) <= 1e-6 * coarse.mesh.diameter


def test_newton_that_fails_early_in_the_scan_is_not_run_again(crescent, monkeypatch):
    """A step of the scan whose Newton from the last pose free of creases
    fails within ``CREASE_WATCH`` iterations goes on by continuation from
    rest at once: the same Newton from the same start would fail the same
    way."""
    from types import SimpleNamespace
    import plush_opt.solve.fold_limit as fl
    from plush_opt.solve.accuracy import LEVEL_OPTIONS
    _, coarse, _ = crescent
    X = coarse.X.copy()
    newton, continued = [], []
    failed = SimpleNamespace(converged=False, iterations=3, x=X, status="line search failed")
    monkeypatch.setattr(fl, "solve_equilibrium", lambda model, c, x0, options: newton.append(x0) or failed)
    monkeypatch.setattr(fl, "continuation", lambda model, eq, x0, options: continued.append(
        (eq, x0, options.continuation)) or "by continuation")
    assert fl.creased_or_solved(coarse, CURLED, X, LEVEL_OPTIONS) == "by continuation"
    assert len(newton) == 1 and continued == [(failed, X, fl.CONTINUATION_STEPS)]


def test_a_level_stopped_creased_on_the_way_takes_the_path_from_rest(crescent):
    """The check's level whose Newton from the answer stopped creased on
    the way: the path from rest decides (crease-free: its pose; creased
    too: its creased pose, the fold the check reports)."""
    from plush_opt.solve.accuracy import LEVEL_OPTIONS
    from plush_opt.solve.accuracy_carry import CREASED_ON_THE_WAY
    from plush_opt.solve.accuracy_check import _unfolded
    _, _, fine = crescent
    for lower, unfolds in ((10.0, False), (8.0, True)):
        stopped = dataclasses.replace(equilibrium_at(fine, np.array([8.0, 0.0])), converged=False,
                                      contraction=np.array([8.0, lower]),
                                      status=f"{CREASED_ON_THE_WAY}: a crease")
        again, how, found = _unfolded(fine, stopped, "from the answer", (), LEVEL_OPTIONS)
        assert again.converged and how.startswith("by continuation from rest (Newton from the answer creased")
        assert np.allclose(again.contraction, [8.0, lower])
        assert (found == (None,)) == unfolds and (crossings(fine, [again.x], creases_only=True) == (None,)) == unfolds
        assert ("and so does the path" in how) != unfolds


def test_a_p1_claim_checked_against_p2_levels_that_crease_is_not_met(monkeypatch):
    """A P1 answer is checked against P2 levels at its contractions; where
    one of them creases there (gripper_object at TOL 1: its right arm
    through the stem on the P2 level of 4,349 nodes), the body folds at the
    answer: not met, no estimate, the fold recorded and said, however well
    the levels agree; and the limit short of it is laid on that P2 level."""
    from types import SimpleNamespace
    import plush_opt.apps.accuracy_run as run
    said, laid = [], []
    acc, p = _accurate(said)
    used = SimpleNamespace(element="P1", mesh=SimpleNamespace(n_nodes=1135), bound_via=None, bound=0.5,
                           on_branch=True, cost=1.0, meets=lambda tol: True, row=lambda: {})
    checked = SimpleNamespace(element="P2", mesh=SimpleNamespace(n_nodes=4349), cost=2.0)
    where = "boundary segments 571-1981 and 1557-442 cross near (8.346, 118.4): a crease"
    monkeypatch.setattr(acc, "_levels_at", lambda p, eq, method, history: ([used], None))
    monkeypatch.setattr(acc, "_cross_check", lambda at, c: (
        {"element": "P2", "nodes": 4349, "agrees": True, "bound": 0.6}, (checked, [checked], {})))
    monkeypatch.setattr(run, "fold_at", lambda scene, levels, lv: {"element": "P2", "nodes": 4349, "where": where}
                        if checked in levels else None)
    eq = SimpleNamespace(converged=True, contraction=np.array([8.0, 12.0]), x=p.model.X)
    found = acc._estimate_at(p, eq, "reparam", ())
    assert found["round"]["met"] is False and found["round"]["estimated_error"] is None
    assert found["round"]["crosses_itself"] == {"element": "P2", "nodes": 4349, "where": where}
    assert found["round"]["cross_check"]["agrees"] is True
    assert any("crosses itself on the P2 level of 4,349 nodes" in line for line in said)
    monkeypatch.setattr(run, "lay_fold_limit", lambda scene, report, model, c, frozen, fold, levels, own, what,
                        progress: laid.append((levels, own)))
    run.limit_short_of_fold(p.scene, {}, p, eq, (), found, said.append)
    assert laid == [([used, checked], False)]
