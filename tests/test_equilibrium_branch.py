"""Equilibria on the stable branch (plush_opt/solve/branch.py): a move past a limit
point fails in a few iterations and says where the branch ends; a move
along the branch gives the certified equilibrium plain Newton finds."""

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest

from plush_opt.solve.branch import solve_on_branch
from plush_opt.solve.equilibrium import LEFT_BRANCH, EquilibriumOptions, solve_equilibrium
from plush_opt.io import load_scene
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from shipped import body_size

ROOT = Path(__file__).resolve().parents[1]
# the control loop's trial budget; no eigenvalue diagnostic on failed poses
# (a Lanczos run on H itself, seconds on this mesh)
TRIAL = EquilibriumOptions(max_iterations=100, eigenvalue=False)
A = 12.3                                           # winch a: legs 0, 2, 4 drawn in


@functools.lru_cache(maxsize=None)
def hexapod_p2():
    """The hexapod on P2 at 4x its max_area (829 nodes): legs 1, 3, 5 (winch
    b) buckle and snap through just past b = 23.2 mm; and its equilibrium
    at b = 22.5 mm, on the stable branch."""
    scene = dataclasses.replace(load_scene(ROOT / "problems" / "hexapod.yaml"), element="P2")
    model = build_model(scene, build_mesh(scene, 4 * scene.max_area))
    start = solve_equilibrium(model, [A, 22.5])
    assert start.converged, start.status
    return model, start


@pytest.mark.slow
def test_a_move_past_the_limit_point_fails_fast_and_says_where():
    model, start = hexapod_p2()
    past = [A, 25.0]
    eq = solve_on_branch(model, start.contraction, start.x, past, options=TRIAL)
    assert not eq.converged
    assert eq.status.startswith("no stable equilibrium on the branch: it ends (limit point) past")
    assert eq.iterations <= 30                       # 18 measured
    # plain (regularised) Newton, given as many iterations, is still on its
    # way after the snap-through (it runs to any limit: the leg folds until
    # two via points of its tendon meet, where no step decreases E)
    plain = solve_equilibrium(model, past, start.x, dataclasses.replace(TRIAL, max_iterations=30))
    assert not plain.converged and plain.status == "iteration limit (30) reached"
    reached = float(eq.status.split("contraction [")[1].split("]")[0].split()[1])
    assert 23.0 < reached < 23.3


def test_a_move_along_the_branch_is_the_certified_plain_newton_equilibrium():
    model, start = hexapod_p2()
    c1 = [A, 23.1]
    eq = solve_on_branch(model, start.contraction, start.x, c1,
                         options=dataclasses.replace(TRIAL, eigenvalue=True))
    assert eq.converged and eq.positive_definite and eq.min_eigenvalue > 0, eq.status
    assert np.array_equal(eq.contraction, c1)
    plain = solve_equilibrium(model, c1, start.x)
    assert plain.converged
    assert np.abs(eq.x - plain.x).max() <= 1e-7 * body_size(model)


def test_sub_steps_stay_on_the_branch_where_the_direct_solve_leaves_it():
    # from rest straight to b = 23.1: the direct solve meets an indefinite
    # Hessian, the sub-steps reach the same pose as the move from b = 22.5
    model, start = hexapod_p2()
    rest = solve_equilibrium(model, [A, 0.0])
    strict = solve_equilibrium(model, [A, 23.1], rest.x, dataclasses.replace(TRIAL, regularise=False))
    eq = solve_on_branch(model, rest.contraction, rest.x, [A, 23.1], options=TRIAL)
    near = solve_on_branch(model, start.contraction, start.x, [A, 23.1], options=TRIAL)
    assert eq.converged and eq.positive_definite, eq.status
    if strict.converged:
        pytest.skip("the direct solve stayed on the branch on this mesh")
    assert strict.status.startswith(LEFT_BRANCH)
    assert np.abs(eq.x - near.x).max() <= 1e-7 * body_size(model)


def test_regularise_off_stops_at_an_indefinite_hessian():
    model, start = hexapod_p2()
    eq = solve_equilibrium(model, [A, 25.0], start.x, dataclasses.replace(TRIAL, regularise=False))
    assert not eq.converged and eq.status.startswith(LEFT_BRANCH)
    assert eq.iterations <= 5


def test_a_symmetric_strip_buckles_through_its_bifurcation_on_the_branch():
    # a pitchfork, not a limit point: the symmetric branch goes on as a
    # saddle and the escape rule carries the move onto the buckled branch
    scene = load_scene(ROOT / "problems" / "hard" / "buckling.yaml")
    mesh = build_mesh(scene)
    model = build_model(scene, mesh)
    rest = solve_equilibrium(model, [0.0])
    eq = solve_on_branch(model, [0.0], rest.x, [2.0])
    assert eq.converged and eq.min_eigenvalue > 0, eq.status
    assert eq.saddle_escapes == 1
    tip = int(np.flatnonzero((mesh.X[:, 0] == 120) & (mesh.X[:, 1] == 0))[0])
    assert abs(eq.nodes[tip, 1]) > 5.0


def test_a_held_force_balances_its_start_and_its_gradient_is_the_energys():
    # the homotopy's first model: the scene plus the start's residual held
    # fixed, so the start is its equilibrium; energy and gradient agree
    from plush_opt.solve.accuracy_carry import WithForce
    model, start = hexapod_p2()
    c = np.array([A, 23.1])
    r0 = model.evaluate(start.x, c, 1).gradient
    held = WithForce(model, 0.5 * r0)
    assert np.linalg.norm(r0) > 1e-3
    ev = held.evaluate(start.x, c, 1)
    assert np.allclose(ev.gradient, 0.5 * r0, rtol=0, atol=1e-12 * np.linalg.norm(r0))
    dx = np.random.default_rng(3).standard_normal(model.n_dofs) * 1e-3
    h = 1e-4
    fd = (held.evaluate(start.x + h * dx, c, 0).energy - held.evaluate(start.x - h * dx, c, 0).energy) / (2 * h)
    assert fd == pytest.approx(ev.gradient @ dx, rel=1e-6)
    full = WithForce(model, r0).evaluate(start.x, c, 1)
    assert np.linalg.norm(full.gradient) <= 1e-12 * np.linalg.norm(r0)


def test_the_homotopy_reaches_the_branchs_equilibrium_and_says_where_the_branch_ends():
    from plush_opt.solve.accuracy_carry import relieved_equilibrium
    model, start = hexapod_p2()
    # along the branch: the pose plain Newton and the branch's own move reach
    near = solve_on_branch(model, start.contraction, start.x, [A, 23.1], options=TRIAL)
    eq = relieved_equilibrium(model, [A, 23.1], start.x, TRIAL)
    assert eq.converged and eq.positive_definite, eq.status
    assert np.abs(eq.x - near.x).max() <= 1e-7 * body_size(model)
    # past the limit point (23.2): not converged, and the status says so
    # (plain Newton from the same start runs to its limit after the snap)
    past = relieved_equilibrium(model, [A, 25.0], start.x, TRIAL)
    assert not past.converged
    assert past.status.startswith("homotopy stopped with ") and "of the start's residual held" in past.status
