"""Newton's inexact steps: where steps with a kept factor stall in the local
phase, conjugate gradients on the current Hessian preconditioned by that
factor take the step a factorisation would have; the pose reached is still
factored afresh and only that factor certifies it."""

from __future__ import annotations

import dataclasses
import logging
import re

import numpy as np
import pytest
import scipy.sparse as sp

from plush_opt.apps.bench_peers import peer_problem
from plush_opt.apps.timing import counting_factorisations
from plush_opt.base.linalg import Factorizer
from plush_opt.control.gradient import ControlOptions
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import Evaluation, Model
from plush_opt.io import load_scene
from plush_opt.problem import from_scene
from plush_opt.solve import kept_factor
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
from plush_opt.solve.sensitivity import state_sensitivity
from shipped import ROOT, body_size, built


def _trial_both_ways(monkeypatch, model, at, c, switch: str, off, on):
    """A control trial's re-solve at ``c`` from the predictor at the
    equilibrium at ``at``, with that equilibrium's factor kept, once with
    ``kept_factor.<switch>`` = ``off`` and once = ``on`` (inexact steps
    allowed on this small mesh): (equilibrium, factorisations) of each."""
    monkeypatch.setattr(kept_factor, "KRYLOV_MIN_DOFS", 0)           # (a small mesh, for a short test)
    near = solve_equilibrium(model, at)
    c = np.asarray(c, dtype=np.float64)
    guess = near.x + state_sensitivity(model, near) @ (c - near.contraction)
    count = counting_factorisations(model)
    out = []
    try:
        for value in (off, on):
            monkeypatch.setattr(kept_factor, switch, value)
            count["n"] = 0
            out.append((solve_equilibrium(model, c, guess, chord=near.factor), count["n"]))
    finally:
        del model.factorizer.factor
    return out


def test_an_inexact_newton_step_spares_a_factorisation_never_the_certificate(monkeypatch, caplog):
    """A control trial's re-solve after a 0.05 mm step, from the predictor
    with the last equilibrium's factor: its kept-factor steps stall above
    the tolerance; with inexact Newton steps (the second on the first's
    Hessian) the certificate's is the only factorisation, at the same
    equilibrium."""
    _, _, model, _ = built("gripper")
    with caplog.at_level(logging.DEBUG, logger="plush_opt.solve.equilibrium"):
        (without, n_without), (with_, n_with) = _trial_both_ways(
            monkeypatch, model, [9.8, 0.0, 5.0], [9.85, 0.0, 5.05], "KRYLOV_STEPS", 0, 2)
    assert without.converged and with_.converged, (without.status, with_.status)
    assert (n_without, n_with) == (2, 1)
    assert any("2 inexact Newton" in r.getMessage() for r in caplog.records)
    assert with_.relative_residual <= 1e-10 and with_.iterations == 0
    assert np.abs(with_.x - without.x).max() <= 1e-9 * body_size(model)
    # its factor is its own Hessian's
    H = model.evaluate(with_.x, with_.contraction).hessian
    b = np.ones(model.n_dofs)
    assert np.linalg.norm(H @ with_.factor.solve(b) - b) <= 1e-8 * np.linalg.norm(b)


class _Identity:
    """A stand-in factor: solve is the identity."""

    shift = 0.0

    @staticmethod
    def solve(b):
        return np.array(b, dtype=np.float64)


def test_an_inexact_step_refuses_a_hessian_not_positive_definite_along_its_search():
    """Conjugate gradients that meet a curvature that is not positive (here
    H = -I) give no step: the solve factors instead (and regularises or
    stops as it would)."""
    n = 6
    g = np.arange(1.0, n + 1.0)
    ev = Evaluation(0.0, g, -sp.identity(n, format="csc"), 1.0, True)
    assert kept_factor.krylov_step(None, None, np.zeros(n), ev, _Identity(), float(np.linalg.norm(g)),
                               EquilibriumOptions()) is None


def test_an_inexact_step_stops_after_its_iterations(monkeypatch):
    """Without convergence within ``KRYLOV_ITERATIONS`` there is no step: a
    preconditioner far from H (the identity for a spread spectrum) needs
    more iterations than one."""
    monkeypatch.setattr(kept_factor, "KRYLOV_ITERATIONS", 1)
    n = 6
    g = np.ones(n)
    ev = Evaluation(0.0, g, sp.diags(np.arange(1.0, n + 1.0)).tocsc(), 1.0, True)
    assert kept_factor.krylov_step(None, None, np.zeros(n), ev, _Identity(), float(np.linalg.norm(g)),
                               EquilibriumOptions()) is None


def test_a_trial_refreshes_the_tendon_term_at_its_predictor_and_spares_a_factorisation(monkeypatch, caplog):
    """A control trial 0.8 mm from the committed equilibrium (split
    Hessian): the committed factor's steps diverge at the predictor (the
    tendons' stiffness moved in their smoothing zone); that factor with the
    predictor's own tendon terms (its sparse part and segment couplings
    kept) converges, so the certificate's is the only factorisation, where
    without the refreshed tendon terms a Newton step's was needed too; the
    same equilibrium, certified by a factor of its own Hessian."""
    scene, mesh, _, _ = built("gripper")
    model = Model(scene, mesh, hessian="split")
    (stale, n_stale), (refreshed, n_refreshed) = _trial_both_ways(
        monkeypatch, model, [11.14, 0.5, 11.48], [11.95, 0.29, 11.2], "FRESH_LOW_RANK", 0, 1)
    assert stale.converged and refreshed.converged, (stale.status, refreshed.status)
    assert (n_stale, n_refreshed) == (2, 1)
    assert (stale.iterations, refreshed.iterations) == (1, 0)
    assert np.abs(refreshed.x - stale.x).max() <= 1e-9 * body_size(model)
    H = model.evaluate(refreshed.x, refreshed.contraction).hessian
    b = np.ones(model.n_dofs)
    assert np.linalg.norm(H @ refreshed.factor.solve(b) - b) <= 1e-8 * np.linalg.norm(b)


def test_a_solve_from_rest_takes_its_second_inexact_step_on_the_hessian_in_hand(monkeypatch, caplog):
    """The gripper's body under gravity from rest (the peer problem, no
    tendons), inexact steps allowed on its small mesh: the Newton step, an
    inexact step with its factor, then inexact steps in the local phase,
    the second on the Hessian the first evaluated: four evaluations of
    order 2 in all (rest, the line search's, the local phase's, the
    certificate's) and two factorisations; the pose Newton reaches without
    inexact steps, certified by a factor of its own Hessian."""
    _, _, prob = peer_problem(ROOT / "problems" / "gripper.yaml", 0)
    model = prob.model
    c = np.zeros(model.n_winches)
    newton = solve_equilibrium(model, c)           # (under KRYLOV_MIN_DOFS: no inexact steps)
    monkeypatch.setattr(kept_factor, "KRYLOV_MIN_DOFS", 0)           # (a small mesh, for a short test)
    orders = []
    plain = model.evaluate

    def evaluate(x, c, order=2):
        orders.append(order)
        return plain(x, c, order)
    monkeypatch.setattr(model, "evaluate", evaluate)
    count = counting_factorisations(model)
    try:
        with caplog.at_level(logging.DEBUG, logger="plush_opt.solve.equilibrium"):
            inexact = solve_equilibrium(model, c)
    finally:
        del model.factorizer.factor
    assert newton.converged and inexact.converged, (newton.status, inexact.status)
    assert any("2 inexact Newton" in r.getMessage() for r in caplog.records)
    assert orders.count(2) == 4 and count["n"] == 2
    assert np.abs(inexact.x - newton.x).max() <= 1e-9 * body_size(model)
    H = model.evaluate(inexact.x, c).hessian
    b = np.ones(model.n_dofs)
    assert np.linalg.norm(H @ inexact.factor.solve(b) - b) <= 1e-8 * np.linalg.norm(b)


@pytest.mark.slow
def test_control_with_inexact_steps_on_the_gripper_p2_level_of_17017_nodes_ends_stationary(caplog):
    """Control as ``solve problems/gripper.yaml --accuracy 0.05`` runs it on
    the level it picks (P2, graded at 16 x the file's max_area, refined
    twice: 17,017 nodes, 34,034 unknowns; poses converged at their
    round-off floor): inexact steps are taken, every trial certified, and
    where the steps can no longer lower O by more than its round-off the
    loop ends stationary (its line search failed there before that was
    told apart), at the objective the loop reaches without inexact steps."""
    scene = dataclasses.replace(load_scene(ROOT / "problems" / "gripper.yaml"), element="P2")
    mesh = build_mesh(scene, max_area=16 * 25.0, graded=True, refinements=2, announce=False)
    p = from_scene(scene, mesh)
    assert p.model.n_dofs == 34_034
    options = ControlOptions(equilibrium=EquilibriumOptions(eigenvalue=False, roundoff=1.0))
    with caplog.at_level(logging.DEBUG, logger="plush_opt.solve.equilibrium"):
        res = p.control("reparam", options=options)
    inexact = [int(m.group(1)) for r in caplog.records
               if (m := re.search(r"(\d+) inexact Newton", r.getMessage()))]
    assert sum(inexact) > 0
    assert (res.converged, res.reason) == (True, "stationary"), res.status
    assert all(it.equilibrium.converged for it in res.history)
    # (without inexact steps, KRYLOV_STEPS = 0: 0.708209497745485, stationary after 9 iterates)
    assert res.objective == pytest.approx(0.708209497745485, rel=1e-9)


def test_kept_factor_steps_that_cut_the_residual_slowly_give_way_to_an_inexact_step(monkeypatch):
    """In the local phase, a kept factor whose steps cut the residual by
    0.44 each (the factor of 1.8 H, H the Hessian in hand): with
    ``KRYLOV_AFTER_RATE`` off the steps go on at that rate until the
    factor's steps run out (then an inexact step); with it, the first slow
    step gives way to an inexact step on H preconditioned by that factor:
    2 steps instead of 13, both below the tolerance at the same equilibrium."""
    _, _, model, _ = built("gripper")
    c = np.array([10.0, 0.0, 5.0])
    eq = solve_equilibrium(model, c)
    x0 = eq.x + 1e-10 * body_size(model) * np.sin(np.arange(model.n_dofs))
    ev0 = model.evaluate(x0, c)
    assert 1e-10 < np.linalg.norm(ev0.gradient) / ev0.force_scale <= kept_factor.FRESH_BELOW
    factor = Factorizer().factor((1.8 * ev0.hessian).tocsc())
    monkeypatch.setattr(kept_factor, "KRYLOV_MIN_DOFS", 0)           # (a small mesh, for a short test)
    out = {}
    for rate in (1.0, 0.3):
        monkeypatch.setattr(kept_factor, "KRYLOV_AFTER_RATE", rate)
        x, ev, steps = kept_factor.kept_factor_steps(model, c, x0, ev0, factor, EquilibriumOptions())
        out[rate] = (steps, np.linalg.norm(ev.gradient) / ev.force_scale, x)
    (slow_steps, slow_left, slow_x), (steps, left, x) = out[1.0], out[0.3]
    assert slow_steps > kept_factor.CHORD_STEPS and steps == 2        # (measured: 13 and 2)
    assert max(slow_left, left) <= 1e-10
    assert np.abs(x - eq.x).max() <= 1e-9 * body_size(model)
    assert np.abs(slow_x - eq.x).max() <= 1e-9 * body_size(model)
