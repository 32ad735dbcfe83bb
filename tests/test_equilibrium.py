"""Equilibria: Newton against IPOPT, certification, warm starts, honest failures."""

import numpy as np
import pytest

from plush_opt.solve.equilibrium import EquilibriumOptions, IpoptEquilibrium, solve_equilibrium
from plush_opt.base.errors import SolverError
from plush_opt.apps.timing import counting_factorisations
from shipped import PROBLEMS, body_size, built

LEVELS = (0.1, 0.4, 0.8)   # fractions of each winch's range


@pytest.mark.slow
@pytest.mark.parametrize("name", PROBLEMS)
@pytest.mark.parametrize("level", LEVELS)
def test_newton_and_ipopt_agree_and_are_certified(name, level):
    _, _, model, _ = built(name)
    c = model.lower + level * (model.upper - model.lower)
    newton = solve_equilibrium(model, c)
    ipopt = solve_equilibrium(model, c, options=EquilibriumOptions(backend="ipopt"))
    for eq in (newton, ipopt):
        assert eq.converged, eq.status
        assert eq.positive_definite and eq.min_eigenvalue > 0
        assert eq.relative_residual <= 1e-10
        assert model.jacobians(eq.x).min() > 0
    gap = np.abs(newton.x - ipopt.x).max()
    assert gap <= 1e-6 * body_size(model), f"Newton and IPOPT differ by {gap:.3e}"


def test_min_eigenvalue_matches_dense_eigensolver():
    _, _, model, _ = built("hexapod_leg")
    eq = solve_equilibrium(model, [6.0])
    H = model.evaluate(eq.x, eq.contraction).hessian.toarray()
    assert eq.min_eigenvalue == pytest.approx(np.linalg.eigvalsh(H)[0], rel=1e-6)


def test_warm_start_reaches_the_same_equilibrium_faster():
    _, _, model, _ = built("gripper")
    cold = solve_equilibrium(model, [10.0, 0.0, 5.0])
    near = solve_equilibrium(model, [9.5, 0.0, 5.0])
    warm = solve_equilibrium(model, [10.0, 0.0, 5.0], near.x)
    assert warm.converged and warm.iterations < cold.iterations
    assert np.abs(warm.x - cold.x).max() <= 1e-7 * body_size(model)


def test_inadmissible_start_is_reported_not_solved():
    _, _, model, _ = built("gripper")
    x0 = model.X.copy().reshape(-1, 2)
    x0[:, 0] *= -1
    for backend in ("newton", "ipopt"):
        eq = solve_equilibrium(model, np.zeros(3), x0, EquilibriumOptions(backend=backend))
        assert not eq.converged and "not admissible" in eq.status


def test_iteration_limit_is_an_honest_status():
    _, _, model, _ = built("gripper")
    eq = solve_equilibrium(model, [20.0, 0.0, 15.0], options=EquilibriumOptions(max_iterations=2))
    assert not eq.converged and "iteration limit" in eq.status
    assert eq.residual_norm > 0


def test_wrong_sizes_and_options_raise():
    _, _, model, _ = built("gripper")
    with pytest.raises(SolverError, match="contraction: expected 3 values"):
        solve_equilibrium(model, [1.0])
    with pytest.raises(SolverError, match="x0: expected"):
        solve_equilibrium(model, np.zeros(3), np.zeros(5))
    with pytest.raises(ValueError, match="backend: expected one of"):
        EquilibriumOptions(backend="magic")
    with pytest.raises(ValueError, match="gtol"):
        EquilibriumOptions(gtol=0)


def test_full_contraction_from_rest_converges_admissible():
    """Every winch at its upper bound, straight from rest."""
    _, _, model, _ = built("gripper")
    eq = solve_equilibrium(model, model.upper)
    assert eq.converged, eq.status
    assert model.jacobians(eq.x).min() > 0


def test_an_ipopt_equilibrium_builds_its_nlp_once_and_solves_as_a_fresh_one():
    _, _, model, _ = built("hexapod_leg")
    options = EquilibriumOptions(backend="ipopt")
    ipopt = IpoptEquilibrium(model)
    first = solve_equilibrium(model, [6.0], options=options, ipopt=ipopt)
    solver = ipopt.solver(options)
    again = solve_equilibrium(model, [6.0], options=options, ipopt=ipopt)
    assert ipopt.solver(options) is solver                   # kept, not rebuilt
    fresh = solve_equilibrium(model, [6.0], options=options)
    assert first.converged and np.array_equal(first.x, again.x) and np.array_equal(first.x, fresh.x)
    _, _, other, _ = built("gripper")
    with pytest.raises(ValueError, match="another model"):
        solve_equilibrium(other, np.zeros(3), options=options, ipopt=ipopt)


@pytest.mark.parametrize("bad", [{"backtrack": 1.0}, {"stall_gain": 0.0}, {"shift_growth": 1.0},
                                 {"stall_window": 0}, {"max_escapes": -1}, {"symmetric_gradient": 2.0}])
def test_tuning_options_are_validated(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        EquilibriumOptions(**bad)


def test_a_kept_factor_saves_factorisations_never_the_certificate():
    """Newton started with the factor of a nearby equilibrium (a chord)
    reaches the same equilibrium with fewer factorisations, and certifies
    it with a factor of its own Hessian."""
    from plush_opt.solve.sensitivity import state_sensitivity
    _, _, model, _ = built("gripper")
    near = solve_equilibrium(model, [9.8, 0.0, 5.0])
    c = np.array([9.802, 0.0, 5.0])       # a control loop's last, short steps
    guess = near.x + state_sensitivity(model, near) @ (c - near.contraction)
    count = counting_factorisations(model)
    try:
        plain = solve_equilibrium(model, c, guess)
        n_plain, count["n"] = count["n"], 0
        kept = solve_equilibrium(model, c, guess, chord=near.factor)
        n_kept = count["n"]
    finally:
        del model.factorizer.factor
    assert plain.converged and kept.converged, (plain.status, kept.status)
    assert n_kept < n_plain, (n_kept, n_plain)
    assert kept.factor is not near.factor and kept.relative_residual <= 1e-10
    assert np.abs(kept.x - plain.x).max() <= 1e-7 * body_size(model)
    H = model.evaluate(kept.x, kept.contraction).hessian
    b = np.ones(model.n_dofs)
    assert np.linalg.norm(H @ kept.factor.solve(b) - b) <= 1e-8 * np.linalg.norm(b)
