"""The reduced-space bilevel method's evaluations stay on the stable branch
(plush_opt/solve/branch.py), as the gradient loop's line-search trials do: a
point IPOPT asks for past a limit point fails in a few Newton iterations
(NaN residuals: IPOPT cuts its step back) instead of running a regularised
Newton to its iteration limit; where nothing crosses a fold, the runs are
the plain solves' bit for bit."""

import dataclasses
import functools

import casadi as ca
import numpy as np
import pytest

from plush_opt.solve.branch import follow_branch
from plush_opt.control import bilevel_reduced
from plush_opt.control.bilevel_reduced import Evaluator, ResidualCallback
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
from plush_opt.io import load_scene
from plush_opt.problem import from_scene
from shipped import PROBLEMS, ROOT, body_size, problem

# the bilevel method's evaluation options (no eigenvalue diagnostic)
QUICK = EquilibriumOptions(eigenvalue=False)
A = 12.3                                           # winch a: legs 0, 2, 4 drawn in


@functools.lru_cache(maxsize=None)
def hexapod_p2():
    """The hexapod on P2 at 4x its max_area (829 nodes), whose winch b's
    branch ends at a fold just past b = 23.2 mm (tests/test_equilibrium_branch.py),
    with an evaluator started at b = 22.5 mm, on the stable branch."""
    scene = dataclasses.replace(load_scene(ROOT / "problems" / "hexapod.yaml"), element="P2")
    p = from_scene(scene, max_area=4 * scene.max_area)
    start = solve_equilibrium(p.model, [A, 22.5], options=QUICK)
    assert start.converged, start.status
    return p, start


def _evaluator(p, start, options=QUICK):
    ev = Evaluator(p.model, p.targets, start.contraction, np.arange(p.model.n_winches), start, options)
    ev.derivatives(ev.points[-1])                  # the predictor's dx/dc, as in a run
    return ev


@pytest.mark.slow
def test_an_evaluation_past_the_fold_fails_in_a_few_newton_iterations():
    p, start = hexapod_p2()
    ev = _evaluator(p, start)
    assert ev.at([A, 25.0]) is None
    assert (ev.solves, ev.failures) == (1, 1)
    assert ev.newton_iterations <= 40               # 18 measured for this move
    # IPOPT's next trial, half the step along the same ray, is past the end
    # the branch follower found: it fails without a solve
    assert ev.at([A, 23.75]) is None
    assert (ev.solves, ev.past_end) == (1, 1)
    # IPOPT sees a failure as NaN residuals (an evaluation error: it cuts its step)
    m = ev.B.shape[0] + 2
    r = np.asarray(ResidualCallback("r", ev, 2, m)(ca.DM([A, 25.0]))).ravel()
    assert r.shape == (m,) and np.isnan(r).all()
    # short of the end, and off that ray, points are solved as ever
    assert ev.at([A, 23.1]) is not None and ev.solves == 2
    # the plain solve from the same predictor is still on its way at any limit
    plain = _evaluator(p, start, dataclasses.replace(QUICK, max_iterations=40))
    assert plain.at([A, 25.0], on_branch=False) is None
    assert plain.newton_iterations == 40


@pytest.mark.slow
def test_the_branch_follower_says_how_far_out_the_branch_has_ended():
    p, start = hexapod_p2()
    eq, failed = follow_branch(p.model, start.contraction, start.x, [A, 25.0], options=QUICK)
    assert not eq.converged and failed is not None
    reached = float(eq.status.split("contraction [")[1].split("]")[0].split()[1])
    b_failed = 22.5 + failed * 2.5
    assert 23.0 < reached < b_failed < 23.5          # the fold: just past 23.2
    # a move that stays on the branch has no end to report
    assert follow_branch(p.model, start.contraction, start.x, [A, 23.1], options=QUICK)[1] is None


def test_an_evaluation_along_the_branch_is_the_certified_plain_equilibrium():
    p, start = hexapod_p2()
    point = _evaluator(p, start).at([A, 23.1])
    assert point is not None and point.eq.converged and point.eq.positive_definite
    plain = solve_equilibrium(p.model, [A, 23.1], start.x)
    assert plain.converged
    assert np.abs(point.eq.x - plain.x).max() <= 1e-7 * body_size(p.model)


@pytest.mark.slow
@pytest.mark.parametrize("name", PROBLEMS)
def test_runs_that_cross_no_fold_are_the_plain_solves_bit_for_bit(name, monkeypatch):
    p = problem(name)
    on_branch = p.control(method="bilevel")

    def plain(model, c0, x0, c1, guess=None, options=None):
        return solve_equilibrium(model, c1, guess, options), None

    monkeypatch.setattr(bilevel_reduced, "follow_branch", plain)
    before = p.control(method="bilevel")
    assert on_branch.converged and before.converged
    assert on_branch.contractions == before.contractions
    assert on_branch.objective == before.objective
    assert on_branch.stats.iterations == before.stats.iterations
    assert on_branch.stats.equilibrium_solves == before.stats.equilibrium_solves
    assert [h.objective for h in on_branch.history] == [h.objective for h in before.history]
    assert ([h.newton_iterations for h in on_branch.history]
            == [h.newton_iterations for h in before.history])
