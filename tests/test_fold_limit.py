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
from plush_opt.fem.mesh import build_mesh
from plush_opt.io import load_scene
from plush_opt.solve.accuracy import GRADED, default_levels, equilibrium_at, level_model
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
    return level_model(sc, build_mesh(sc, max_area=res.max_area, graded=GRADED, refinements=res.refinements))


@pytest.fixture(scope="module")
def crescent():
    scene = load_scene(CRESCENT)
    return scene, _level(scene, "P2", 0), _level(scene, "P2", 2)


def test_the_limit_is_the_last_contraction_short_of_the_crease(crescent):
    scene, coarse, fine = crescent
    s, where = crease_free_fraction(fine, CURLED, LOWER)
    assert 0.5 < s < 0.9 and "a crease" in where
    start = np.array([CURLED[0], 0.0])

    def creases(fraction, x0):
        eq = equilibrium_at(fine, start + fraction * (CURLED - start), x0)
        assert eq.converged
        return eq.x, crossings(fine, [eq.x], creases_only=True)[0] is not None

    x, folded = creases(s, None)
    assert not folded
    _, folded = creases(s + 2.0 ** -FOLD_BISECTIONS, x)     # one bisection step on: the crease
    assert folded
    # the coarse level does not crease there: it sets no limit, and the finer one does
    assert crease_free_fraction(coarse, CURLED, LOWER) == (1.0, None)
    limit, why = fold_limit([coarse, fine], CURLED, LOWER)
    assert why is None and limit.nodes == fine.n_nodes and limit.element == "P2"
    assert limit.bounds == {"lower": pytest.approx((s - FOLD_CLEARANCE) * 12.0)}
    assert "upper" not in limit.bounds
    limited = limit.applied(scene)
    assert limited.upper.tolist() == [12.0, pytest.approx((s - FOLD_CLEARANCE) * 12.0)]
    assert limited.lower.tolist() == scene.lower.tolist() and limited.winch_names == scene.winch_names
    assert limit.row()["where"] == where


def test_no_limit_where_nothing_creases(crescent):
    _, coarse, _ = crescent
    limit, why = fold_limit([coarse], CURLED, LOWER)
    assert limit is None and "no level scanned creases" in why


def test_the_winches_a_fold_is_laid_to(crescent):
    _, coarse, _ = crescent
    # at its upper bound: that winch alone (the run drove it there)
    assert held_winches(coarse, [8.0, 12.0], frozen=()).tolist() == [False, True]
    # frozen there: not the run's doing, never limited; the others that moved are
    assert held_winches(coarse, [8.0, 12.0], frozen={"lower"}).tolist() == [True, False]
    # none at an upper bound: every winch the run moved
    assert held_winches(coarse, [8.0, 3.0], frozen=()).tolist() == [True, True]
    assert held_winches(coarse, [8.0, 0.0], frozen=()).tolist() == [True, False]
