"""What a body resting on the floor costs Newton: the steps after a fall
corrected for the barrier's curvature (plush_opt/solve/contact_step.py),
the gauge of the free sliding motion (its diagonal read off the layout's
slots, in place only where the caller gives the matrix up), the rigid
motions, and the barrier's derivatives by order."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from plush_opt.apps.bench_contact import slab
from plush_opt.fem import contact_geometry as geo
from plush_opt.fem import free_motion
from plush_opt.fem.mesh import area_for_nodes
from plush_opt.fem.model import Model, sum_terms
from plush_opt.solve import newton
from plush_opt.solve.contact_step import remainder
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
from plush_opt.solve.free_fall import free_fall

NO_EIG = EquilibriumOptions(eigenvalue=False)


@pytest.fixture(scope="module")
def floor_slab():
    """The bench's slab lying on the floor, about 300 nodes."""
    scene = slab(True)
    _, mesh = area_for_nodes(scene, 300)
    return Model(scene, mesh)


def _fallen(model):
    """(pose, evaluation) at the end of the slab's fall onto the floor."""
    c = np.zeros(model.n_winches)
    x0 = np.asarray(model.X, dtype=np.float64).reshape(-1)
    x, ev = free_fall(model, c, x0, model.evaluate(x0, c))
    assert x is not x0                                   # it fell
    return x, ev


def test_the_contact_remainder_is_what_its_linearisation_leaves_and_shrinks_with_the_square_of_the_step(floor_slab):
    model, c = floor_slab, np.zeros(1)
    x, ev = _fallen(model)
    dx = -model.factorizer.factor(ev.hessian_form).solve(ev.gradient)
    term = model.contact
    at, to = term.evaluate(x, c, 2), term.evaluate(x + dx, c, 1)
    H = at.hessian["contact_hess"].tocsr()
    r = remainder(term, x, c, dx)
    assert np.allclose(r, to.gradient - at.gradient - H @ dx, rtol=0, atol=1e-12 * np.abs(to.gradient).max())
    half = remainder(term, x, c, dx / 2)
    assert 3.5 < np.linalg.norm(r) / np.linalg.norm(half) < 4.5     # a second-order remainder
    # nothing in contact at either end: no remainder
    lifted = x + np.tile([0.0, 5.0], model.n_dofs // 2)
    assert remainder(term, lifted, c, 0.01 * dx) is None


def test_the_steps_after_a_fall_are_corrected_and_reach_the_same_certified_pose_in_fewer_newton_steps(
        floor_slab, monkeypatch):
    model, c = floor_slab, np.zeros(1)
    corrected = solve_equilibrium(model, c, options=NO_EIG)
    monkeypatch.setattr(newton, "corrected_step", lambda model, c, x, g, dx, factor: dx)
    plain = solve_equilibrium(model, c, options=NO_EIG)
    assert corrected.converged and plain.converged, (corrected.status, plain.status)
    assert (corrected.iterations, plain.iterations) == (2, 3)
    assert np.abs(corrected.x - plain.x).max() <= 1e-9 * np.abs(plain.x).max()


def test_a_solve_whose_body_did_not_fall_takes_no_correction(floor_slab, monkeypatch):
    model, c = floor_slab, np.zeros(1)
    x, _ = _fallen(model)
    asked = []
    monkeypatch.setattr(newton, "corrected_step", lambda *args: asked.append(1) or args[4])
    eq = solve_equilibrium(model, c, x0=x, options=NO_EIG)
    assert eq.converged, eq.status
    assert asked == []


def test_the_gauge_changes_a_matrix_in_place_only_where_the_caller_gives_it_up():
    H = sp.csc_matrix(np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 2.0]]))
    before = H.toarray()
    R = np.array([[0.0], [1.0], [0.0]])
    kept = free_motion.gauge(H, R)
    assert kept is not H and np.array_equal(H.toarray(), before)
    assert kept[1, 1] == before[1, 1] + 2.0                  # the mean of |diag|, on the pivot dof
    given = free_motion.gauge(H, R, owned=True)
    assert given is H and H[1, 1] == before[1, 1] + 2.0
    assert np.array_equal(given.toarray(), kept.toarray())


def test_a_gauged_evaluation_adds_the_mean_diagonal_on_one_dof_per_free_motion(floor_slab):
    model, c = floor_slab, np.zeros(1)
    x, _ = _fallen(model)
    plain = sum_terms(model.terms, model.hessian_layout, x, c, 2)
    gauged = model.evaluate(x, c)
    R = gauged.hessian_form.free_motions
    assert R.shape[1] == 1                                   # it slides along the floor
    diff = (gauged.hessian - plain.hessian).tocoo()
    assert diff.nnz == 1 and diff.row[0] == diff.col[0]
    assert diff.data[0] == pytest.approx(np.mean(np.abs(plain.hessian.diagonal())), rel=1e-14)
    assert np.array_equal(model.hessian_layout.diagonal_slots.shape, (model.n_dofs,))


def test_a_flat_motion_under_a_net_force_above_the_solvers_tolerance_is_not_gauged(floor_slab):
    """A gauged motion keeps its net force (the steps are projected off
    it), so only one balanced to round-off may be gauged: a net force of
    1e-8 of the force scale, far below the old cut (1e-6) and far above
    Newton's tolerance (1e-10), makes the sliding motion one the body
    slides along, not a free one."""
    model, c = floor_slab, np.zeros(1)
    x, _ = _fallen(model)
    plain = sum_terms(model.terms, model.hessian_layout, x, c, 2)
    R, U = free_motion.split_motions(plain.hessian, x, plain.gradient, plain.force_scale)
    assert (R.shape[1], U.shape[1]) == (1, 0)                # balanced to round-off: free
    pushed = plain.gradient + 1e-8 * plain.force_scale * R[:, 0]
    R, U = free_motion.split_motions(plain.hessian, x, pushed, plain.force_scale)
    assert (R.shape[1], U.shape[1]) == (0, 1)


def test_rigid_motions_are_orthonormal_translations_and_a_rotation_about_the_centroid():
    x = np.random.default_rng(3).standard_normal(40) * 10 + 5
    V = free_motion.rigid_motions(x)
    assert np.allclose(V.T @ V, np.eye(3), atol=1e-14)
    P = x.reshape(-1, 2)
    d = P - P.mean(axis=0)
    rot = np.c_[-d[:, 1], d[:, 0]].ravel() / np.linalg.norm(d)
    assert np.allclose(V[:, 2], rot, rtol=0, atol=1e-15)
    assert np.allclose(V[0::2, 0], 1 / np.sqrt(20)) and not V[1::2, 0].any()


@pytest.mark.parametrize("s", [np.array([0.2, 0.24, 0.249999]), np.array([0.01, 0.2]), np.array([0.3, -1.0, 0.1])])
def test_the_barrier_by_order_gives_the_same_values_and_none_above_it(s):
    full = geo.barrier(s, 0.25)
    for order in (0, 1):
        part = geo.barrier(s, 0.25, order)
        for k in range(3):
            if k <= order:
                assert np.array_equal(part[k], full[k], equal_nan=True)
            else:
                assert part[k] is None


def test_the_contact_bench_times_the_floor_and_the_pinned_solves_in_turn():
    from plush_opt.apps.bench_contact import median_times
    calls = []
    timed = median_times({"floor": lambda: calls.append("floor") or 1, "pinned": lambda: calls.append("pinned") or 2},
                         3)
    assert calls == ["floor", "pinned"] * 3
    assert [timed[k][2] for k in ("floor", "pinned")] == [1, 2]
    assert all(wall >= 0 and cpu >= 0 for wall, cpu, _ in timed.values())
