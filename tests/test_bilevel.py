"""Bilevel control (IPOPT, reduced space by default, full space as an
option): certified results, agreement with the gradient loop, honest stops
(at the start, at a budget), a KKT point that is a saddle of E, the
full-space solver cache, frozen winches and option validation."""

import json

import numpy as np
import pytest

from plush_opt.control.bilevel import BilevelOptions, BilevelSolver, solve_bilevel
from plush_opt.control.bilevel_nlp import _objective_expression, force_reference
from plush_opt.control.gradient import solve_control
from plush_opt.solve.equilibrium import solve_equilibrium
from plush_opt.io import load_scene, scene_from_dict
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from plush_opt.fem.objective import Targets
from shipped import PROBLEMS, ROOT, body_size, built


def _certified(model, res):
    eq = res.equilibrium
    assert eq.converged and eq.positive_definite, eq.status
    assert eq.relative_residual <= 1e-10
    assert model.jacobians(eq.x).min() > 0
    assert np.all(res.contraction >= model.lower) and np.all(res.contraction <= model.upper)
    assert np.array_equal(res.contraction, eq.contraction)


@pytest.mark.parametrize("name", PROBLEMS)
def test_shipped_problems_end_at_certified_stable_equilibria(name):
    _, _, model, targets = built(name)
    res = solve_bilevel(model, targets)
    assert res.converged, res.status
    # IPOPT's own KKT test or the loop's stationarity tests, whichever first
    assert res.reason == "stationary" and res.status.startswith(
        ("ipopt (reduced): Solve_Succeeded; certified",
         "ipopt (reduced): stopped by the stop rules; projected gradient below gtol; certified",
         "ipopt (reduced): stopped by the stop rules; objective stopped decreasing (relative decrease "
         "below ftol); certified"))
    assert "User_Requested_Stop" not in res.status     # IPOPT's word for a stop the user asked for
    _certified(model, res)
    info = res.stats.details
    assert info.formulation == "reduced" and info.bound_violation == 0.0
    assert res.objective == pytest.approx(targets.value(res.equilibrium.x), rel=1e-12)
    assert info.objective_ipopt == pytest.approx(res.objective, rel=1e-9, abs=1e-12)
    # the anytime history: the start, one point per IPOPT iteration and one
    # per look-further move, in time order, every one a certified equilibrium
    assert len(res.history) == res.stats.iterations + 1 + len(info.moves)
    t = [h.t_wall for h in res.history]
    assert t == sorted(t)
    assert all(h.dispatchable for h in res.history)
    json.dumps(res.stats.details.to_dict(), allow_nan=False)
    json.dumps(res.to_dict(), allow_nan=False)


@pytest.mark.slow
def test_full_space_formulation_is_certified_by_newton():
    _, _, model, targets = built("gripper")
    res = solve_bilevel(model, targets, options=BilevelOptions(formulation="full"))
    assert res.converged and res.status.startswith("ipopt: Solve_Succeeded; certified"), res.status
    _certified(model, res)
    info = res.stats.details
    assert info.ipopt_pose["stable_equilibrium"] and info.ipopt_pose["min_eigenvalue"] > 0
    assert info.certified_distance <= 1e-6 * body_size(model)
    assert info.kkt["feasibility"] <= 1e-8 and info.kkt["stationarity"] <= 1e-5
    assert res.objective == pytest.approx(solve_bilevel(model, targets).objective, rel=1e-6)


@pytest.mark.parametrize("name", ["gripper", "hexapod"])
def test_objective_agrees_with_the_gradient_loop(name):
    _, _, model, targets = built(name)
    bilevel = solve_bilevel(model, targets)
    method1 = solve_control(model, targets)
    assert bilevel.converged and method1.converged
    gap = abs(bilevel.objective - method1.objective)
    assert gap <= 0.01 * method1.objective, (bilevel.objective, method1.objective)
    span = model.upper - model.lower
    assert np.max(np.abs(bilevel.contraction - method1.contraction) / span) <= 0.01


def test_hexapod_leg_bilevel_leaves_the_local_minimum_on_the_bound():
    """The leg's first millimetres of pull move the foot away from its
    target: c = 0 is a KKT point with the bound active. IPOPT stops there;
    the look-further probe (the gradient loop's) finds the way out and a
    second IPOPT round reaches the loop's answer."""
    _, _, model, targets = built("hexapod_leg")
    res = solve_bilevel(model, targets)
    assert res.converged, res.status
    assert res.stats.details.moves and "probe" in res.status
    assert res.objective <= 1.01 * solve_control(model, targets).objective
    off = solve_bilevel(model, targets, options=BilevelOptions(probe_fractions=()))
    # without the probes it ends where it started: an honest failure, not a success
    assert not off.converged and off.reason == "no_decrease"
    assert "ended at its start" in off.status
    assert off.contraction[0] == pytest.approx(0.0, abs=1e-6)


def test_targets_from_a_forward_solve_are_reached():
    _, _, model, targets = built("gripper")
    c_true = np.array([10.0, 2.0, 5.0])     # interior: a bound would hold IPOPT ~sqrt(mu) off
    eq = solve_equilibrium(model, c_true)
    res = solve_bilevel(model, targets.replace_to(targets.y(eq.x)))
    assert res.converged, res.status
    assert res.objective <= 1e-10
    assert np.abs(res.contraction - c_true).max() <= 1e-4


@pytest.mark.slow
def test_full_space_solver_is_cached_and_targets_are_parameters():
    _, _, model, targets = built("gripper")
    solver = BilevelSolver(model)
    full = BilevelOptions(formulation="full")
    first = solver.solve(targets, options=full)
    assert not first.stats.details.cached_solver and first.stats.t_setup > 0
    again = solver.solve(targets, options=full)
    assert again.stats.details.cached_solver and again.stats.details.t_build == 0.0
    assert np.array_equal(first.contraction, again.contraction)
    moved = targets.replace_to(targets.to + np.array([3.0, -2.0]))
    other = solver.solve(moved, options=full)
    assert other.stats.details.cached_solver, "new target positions must not rebuild the solver"
    assert other.converged and not np.allclose(other.contraction, first.contraction)
    assert other.objective == pytest.approx(moved.value(other.equilibrium.x))
    reweighted = Targets(targets.triangles, targets.nodes, targets.beta, targets.to,
                         [5.0, 1.0, 1.0])
    assert solver.solve(reweighted, options=full).stats.details.cached_solver


def test_objective_expression_equals_targets_value():
    import casadi as ca
    _, _, model, targets = built("gripper")
    x = ca.MX.sym("x", model.n_dofs)
    q = ca.MX.sym("q", targets.n_targets, 2)
    w = ca.MX.sym("w", targets.n_targets)
    beta = ca.MX.sym("beta", targets.n_targets, 3)
    f = ca.Function("O", [x, q, w, beta], [_objective_expression(x, targets.nodes, beta, q, w)])
    rng = np.random.default_rng(0)
    for _ in range(3):
        xv = model.X + rng.normal(scale=2.0, size=model.n_dofs)
        weight = rng.uniform(0.5, 2.0, targets.n_targets)
        t = Targets(targets.triangles, targets.nodes, targets.beta, targets.to, weight)
        got = float(f(xv, t.to, np.sqrt(weight), t.beta))
        assert got == pytest.approx(t.value(xv), rel=1e-12)


def test_frozen_winch_keeps_its_contraction_bit_for_bit():
    _, _, model, targets = built("gripper")
    c0 = np.array([0.0, 0.0, 7.3])
    res = solve_bilevel(model, targets, c0, frozen=[False, False, True])
    assert res.converged, res.status
    assert res.contraction[2] == 7.3
    assert res.stats.details.frozen == ["grip"]
    _certified(model, res)


def _strip(target_x: float):
    """A strip 100 x 6 mm, mirror-symmetric explicit mesh about y = 0,
    clamped at x = 0, with one straight tendon on its axis from the free
    end to the clamp. Contracting it compresses the strip; past about
    1 mm the straight pose is a saddle of E (Euler buckling)."""
    length, h, nx = 100.0, 6.0, 26
    xs = np.linspace(0.0, length, nx)
    nodes = [[x, y] for y in (-h / 2, 0.0, h / 2) for x in xs]

    def idx(i, j):
        return j * nx + i
    tris = []
    for i in range(nx - 1):
        a, b, c, d = idx(i, 0), idx(i + 1, 0), idx(i + 1, 1), idx(i, 1)
        tris += [[a, b, d], [b, c, d]]
        a, b, c, d = idx(i, 1), idx(i + 1, 1), idx(i + 1, 2), idx(i, 2)
        tris += [[a, b, c], [a, c, d]]
    doc = {"format": "plush-opt/1", "name": "strip",
           "mesh": {"nodes": nodes, "triangles": tris},
           "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                        "thickness": 30.0},
           "pins": {"stiffness": 1000.0, "at": [[0, -h / 2], [0, h / 2]], "box": [0, -h / 2, 0, h / 2]},
           "winches": [{"name": "w", "bounds": [0.0, 30.0]}],
           "tendons": {"stiffness": 50.0, "smoothing": 0.01,
                       "list": [{"name": "t", "winch": "w", "path": [[length, 0.0], [0.0, 0.0]]}]},
           "targets": [{"at": [length, 0.0], "to": [target_x, 0.0]}]}
    scene = scene_from_dict(doc)
    mesh = build_mesh(scene)
    model = build_model(scene, mesh)
    return model, Targets.from_mesh(mesh, scene)


def test_a_kkt_point_that_is_a_saddle_of_E_is_never_reported_as_success():
    model, targets = _strip(85.0)
    X = model.X.reshape(-1, 2)
    # the mesh is mirror-symmetric, so the straight pose stays an equilibrium
    mirrored = {tuple(np.round(p * [1, -1], 9)) for p in X}
    assert mirrored == {tuple(np.round(p, 9)) for p in X}
    res = solve_bilevel(model, targets, options=BilevelOptions(formulation="full"))
    pose = res.stats.details.ipopt_pose
    # IPOPT itself succeeds: the straight, compressed strip satisfies the KKT
    # conditions with the tip exactly on its target...
    assert res.stats.details.return_status == "Solve_Succeeded"
    assert res.stats.details.objective_ipopt <= 1e-8
    assert pose["relative_residual"] <= 1e-8
    # ...but it is a saddle of E, and certification says so
    assert not pose["positive_definite"] and pose["min_eigenvalue"] < 0
    assert not res.converged
    assert "saddle of E" in res.status
    # what is returned is the stable (buckled) pose Newton finds from it
    _certified(model, res)
    assert res.stats.details.certified_distance > 1.0
    assert res.objective > 1.0


def test_slack_winches_are_taken_up_before_ipopt():
    scene = load_scene(ROOT / "problems" / "compare" / "finger_slack_start.yaml")
    mesh = build_mesh(scene, max_area=40.0)
    model = build_model(scene, mesh)
    targets = Targets.from_mesh(mesh, scene)
    res = solve_bilevel(model, targets)
    assert res.stats.details.start["slack_taken_up"] == ["flex", "extend"]
    assert res.converged and res.objective < 1e-2
    off = solve_bilevel(model, targets, options=BilevelOptions(take_up_slack=False))
    # without it IPOPT stops at once on the flat start (zero gradient); the
    # look-further moves then reel the slack in, as the gradient loop does
    assert off.converged and "took up the slack of flex" in off.status
    assert off.objective == pytest.approx(res.objective, rel=1e-2, abs=1e-8)


def test_time_limit_is_an_honest_status():
    _, _, model, targets = built("gripper")
    res = solve_bilevel(model, targets, options=BilevelOptions(max_time=1e-9))
    assert not res.converged
    assert "time limit" in res.status and res.stats.details.stopped_by_time_limit
    assert res.equilibrium.converged      # whatever is returned is a certified pose
    assert res.stats.iterations <= 1


def test_iteration_limit_is_an_honest_status():
    _, _, model, targets = built("gripper")
    res = solve_bilevel(model, targets, options=BilevelOptions(max_iter=2))
    assert not res.converged and res.reason == "max_iterations"
    assert "iteration limit (2)" in res.status and res.stats.iterations <= 2
    assert res.equilibrium.converged


def test_force_reference_is_a_model_constant():
    _, _, model, _ = built("gripper")
    assert force_reference(model) == pytest.approx(
        model.mu * model.thickness * np.sqrt(model.rest_area.sum()))


@pytest.mark.parametrize("field, value, match", [
    ("tol", -1.0, "tol"), ("max_iter", 1.5, "max_iter"), ("max_time", 0.0, "max_time"),
    ("min_jacobian", 1.0, "min_jacobian"), ("mu_strategy", "fast", "mu_strategy"),
    ("alpha_for_y", "bold", "alpha_for_y"), ("pose_tol", -1e-3, "pose_tol"),
    ("ipopt", {1: 2}, "ipopt"), ("formulation", "sparse", "formulation"),
    ("hessian_damping", -1.0, "hessian_damping"),
])
def test_options_are_validated(field, value, match):
    with pytest.raises(ValueError, match=match):
        BilevelOptions(**{field: value})


def test_bad_inputs_raise_solver_errors():
    from plush_opt.base.errors import SolverError
    _, _, model, targets = built("gripper")
    with pytest.raises(SolverError, match="outside the winch bounds"):
        solve_bilevel(model, targets, [30.0, 0.0, 0.0])
    with pytest.raises(SolverError, match="contraction"):
        solve_bilevel(model, targets, [0.0, 0.0])


def _slack_start_run():
    """A reduced-space run on the slack-start finger, from its flat start."""
    import time as _time
    from plush_opt.control.bilevel_search import ReducedRun
    from plush_opt.solve.equilibrium import EquilibriumOptions
    scene = load_scene(ROOT / "problems" / "compare" / "finger_slack_start.yaml")
    mesh = build_mesh(scene, max_area=40.0)
    model = build_model(scene, mesh)
    targets = Targets.from_mesh(mesh, scene)
    start = solve_equilibrium(model, scene.contraction, options=EquilibriumOptions(eigenvalue=False))
    return model, ReducedRun(model, targets, BilevelOptions(), scene.frozen.copy(), start,
                             _time.perf_counter())


def test_a_slack_winch_is_tried_again_once_the_objective_has_dropped():
    """A winch whose look-further moves found nothing is tried again from a
    point whose O is lower by probe_gain (a later round may have made its
    slack matter: the 3,303-node tentacle's left_tip), never from the same O."""
    model, run = _slack_start_run()
    point = run.start
    flex, extend = model.winch_names.index("flex"), model.winch_names.index("extend")
    o = point.objective
    assert run._look_further(point, {flex: o, extend: o}) is None
    tried = {flex: o * (1 + 2 * run.options.probe_gain), extend: o}
    moved = run._look_further(point, tried)
    assert moved is not None and run.moves == ["took up the slack of flex"]
    assert tried[flex] == o          # and it is not tried again from this O
    assert moved.eq.converged and moved.objective <= o * (1 + 1e-9)


def test_an_error_inside_an_ipopt_callback_is_raised_as_itself(monkeypatch):
    """An exception in a reduced-space callback (here the sensitivity of
    the third point) stops IPOPT and is re-raised: it does not come back as
    IPOPT's Invalid_Number_Detected and a solver_failed result."""
    from plush_opt.control import bilevel_reduced
    _, _, model, targets = built("gripper")
    real, calls = bilevel_reduced.state_sensitivity, []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise ArithmeticError("sensitivity failed on purpose")
        return real(*args, **kwargs)

    monkeypatch.setattr(bilevel_reduced, "state_sensitivity", failing)
    with pytest.raises(ArithmeticError, match="on purpose"):
        solve_bilevel(model, targets)
    assert len(calls) == 3           # IPOPT was stopped: nothing evaluated after it
    monkeypatch.setattr(bilevel_reduced, "state_sensitivity", real)
    assert solve_bilevel(model, targets).converged


def test_secant_correction_meets_the_secant_condition_and_resets_at_a_kink():
    """The structured secant term S: after a pair (s, y) with y = (J_new -
    J_old)^T r_new it satisfies S s = y and enters the Hessian rows
    (L^T L = S on winches that are not slack); a pair across the tendon
    law's kink (a winch going slack or taut) drops it (Gauss-Newton)."""
    from plush_opt.control.bilevel_reduced import Evaluator
    from plush_opt.solve.equilibrium import EquilibriumOptions
    _, _, model, targets = built("hexapod")
    quick = EquilibriumOptions(eigenvalue=False)
    free = np.arange(model.n_winches)
    c0 = np.full(model.n_winches, 5.0)
    ev = Evaluator(model, targets, c0, free, solve_equilibrium(model, c0, options=quick), quick,
                   damping=1e-3, secant=True)
    a, b = ev.points[-1], ev.at(c0 + [1.0, 0.5])
    ev.accept(a)
    ev.accept(b)
    s = b.c - a.c
    y = (b.J - a.J).T @ b.r
    assert s @ y > 0 and not ev._near_slack(a).any() and not ev._near_slack(b).any()
    np.testing.assert_allclose(ev.S @ s, y, rtol=1e-10, atol=1e-14)
    rows = ev.jacobian_rows(b)[-len(free):]
    np.testing.assert_allclose(rows.T @ rows, ev.S, rtol=1e-8, atol=1e-12 * np.abs(ev.S).max())
    # a pair with a winch slack at one end and taut at the other
    slack = ev.at(np.array([5.0, 0.0]))
    assert ev._near_slack(slack).any() != ev._near_slack(b).any()
    ev.accept(slack)
    assert not ev.S.any()
    off = Evaluator(model, targets, c0, free, a.eq, quick, secant=False)
    off.accept(off.points[-1])
    off.accept(off.at(c0 + [1.0, 0.5]))
    assert not off.S.any()


def test_a_run_whose_every_trial_point_fails_is_an_honest_solver_failure(monkeypatch):
    """Newton certifies nothing but the start: IPOPT cannot take a step. The
    result is not converged, its reason is solver_failed, its status names
    IPOPT's own return status and why (the failed solves, counted), and the
    pose returned is the certified start."""
    from dataclasses import replace as _replace
    from plush_opt.control import bilevel_reduced
    _, _, model, targets = built("gripper")
    real = bilevel_reduced.solve_equilibrium

    def refusing(model_, c, x0=None, options=None):
        eq = real(model_, c, x0, options)
        return _replace(eq, converged=False, status="refused on purpose")

    real_branch = bilevel_reduced.follow_branch

    def refusing_on_branch(model_, c0, x0, c1, guess=None, options=None):
        eq, _ = real_branch(model_, c0, x0, c1, guess, options)
        return _replace(eq, converged=False, status="refused on purpose"), None

    # IPOPT's points are solved on the branch, the look-further probes plainly
    monkeypatch.setattr(bilevel_reduced, "solve_equilibrium", refusing)
    monkeypatch.setattr(bilevel_reduced, "follow_branch", refusing_on_branch)
    res = solve_bilevel(model, targets)
    assert not res.converged and res.reason == "solver_failed", res.status
    assert res.status.startswith("ipopt (reduced): ")
    assert res.status.split(";")[0].split(": ")[1] not in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    # IPOPT sees NaN residuals there; the status says what they were
    assert "; no certified equilibrium at " in res.status, res.status
    assert res.stats.details.calls["failed_equilibrium_solves"] > 0
    assert np.array_equal(res.contraction, model.scene.contraction)
    _certified(model, res)


def test_a_weak_winch_walks_to_its_bound_without_crawling():
    """The hexapod with its targets moved to 3 % of their distance from the
    pose at a = 12, b = 0: b moves the targets little, its tendons are
    nearly slack, and its small gradient points at its lower bound. IPOPT's
    barrier first pushes b about mu / |g| inside; walking it back, a fixed
    damping on the slack winch made its steps g / lambda (122 iterations),
    and counting IPOPT's barrier rises of O as a stall stopped it half-way
    (O 19 % above the loop's). With the damping adapted as the loop's and
    only O within ftol of its best counted as a stall, it takes about a dozen
    and reaches the loop's O, b at its bound."""
    from dataclasses import replace as _replace
    _, _, model, targets = built("hexapod")
    reach = targets.y(solve_equilibrium(model, np.array([12.0, 0.0])).x)
    near = _replace(targets, to=reach + 0.03 * (targets.to - reach))
    loop, res = solve_control(model, near), solve_bilevel(model, near)
    _certified(model, res)
    assert res.converged and res.reason == "stationary", res.status
    assert res.objective <= loop.objective * (1 + 1e-6), (res.objective, loop.objective)
    assert res.stats.iterations <= 20, res.stats.iterations
    assert "bound active: b" in res.status, res.status


def test_the_slack_winches_damping_adapts_as_the_loops():
    """The damping of a (nearly) slack winch falls by the loop's factor
    after an accepted iterate that lowered O with a step that fell short
    along it (downhill, its gradient's sign kept: the crawl), rises where
    the step flipped its gradient or IPOPT's step kept O (never above
    hessian_damping), and a new round starts it afresh."""
    from plush_opt.control import bilevel_reduced as br
    from plush_opt.control.policy import LEVENBERG_MARQUARDT
    from plush_opt.solve.equilibrium import EquilibriumOptions
    _, _, model, targets = built("hexapod")
    quick = EquilibriumOptions(eigenvalue=False)
    free = np.arange(model.n_winches)
    c0 = np.array([11.5, 0.5])
    ev = br.Evaluator(model, targets, c0, free, solve_equilibrium(model, c0, options=quick), quick,
                      damping=1e-3)
    a, b = ev.derivatives(ev.points[-1]), ev.derivatives(ev.at(np.array([12.0, 0.3])))
    ga, gb = a.gradient(), b.gradient()
    assert b.objective < a.objective and ev._near_slack(b)[1] and not ev._near_slack(b)[0]
    assert ga[0] * gb[0] < 0 and ga[1] > 0 and gb[1] > 0      # a overshot, b fell short
    ev.accept(a)
    ev.accept(b)
    np.testing.assert_allclose(ev.mu, [1e-3, 1e-3 / LEVENBERG_MARQUARDT.decrease])
    rows = ev.jacobian_rows(b)[-len(free):]
    lam = float(np.max(np.sum(b.J * b.J, axis=0)))
    assert rows[1, 1] ** 2 == pytest.approx(ev.mu[1] * lam) and rows[0, 0] == 0.0
    ev.accept(a)                          # O went up: the damping rises, capped at its start
    np.testing.assert_allclose(ev.mu, 1e-3)
    ev.accept(b)
    ev.new_round()
    assert np.all(ev.mu == 1e-3) and ev.accepted is None
