"""Method 1: the sensitivity-driven gradient loop."""

import dataclasses

import numpy as np
import pytest

from plush_opt.control.bounds import Reparametrisation
from plush_opt.control.gradient import ControlOptions, Controller, solve_control
from plush_opt.solve.equilibrium import solve_equilibrium
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from plush_opt.fem.objective import Targets
from plush_opt.io.scene import Winch
from plush_opt.solve.sensitivity import objective_gradient, state_sensitivity
from shipped import PROBLEMS, built

# contractions at which some tendons are slack (negative contraction lets
# them out) and some taut (tension above 2 K eps)
STATES = {"gripper": [20.0, -8.0, 15.0], "hexapod": [15.0, -2.0], "hexapod_leg": [12.0]}


def _at(model, fractions):
    return model.lower + np.asarray(fractions) * (model.upper - model.lower)


@pytest.mark.parametrize("name", PROBLEMS)
def test_objective_gradient_matches_central_differences_of_fresh_solves(name):
    _, _, model, targets = built(name)
    c = np.array(STATES[name])
    eq = solve_equilibrium(model, c)
    G = model.tendon_state(eq.x, c)["stretch"]
    eps = model.tendon_smoothing
    grad = objective_gradient(model, eq, targets.gradient(eq.x))
    h = 1e-4
    fd = np.empty(model.n_winches)
    for w in range(model.n_winches):
        e = np.zeros(model.n_winches)
        e[w] = h
        fd[w] = (targets.value(solve_equilibrium(model, c + e, eq.x).x)
                 - targets.value(solve_equilibrium(model, c - e, eq.x).x)) / (2 * h)
    err = np.abs(grad - fd).max() / max(np.abs(fd).max(), 1e-300)
    assert err < 1e-5, f"dO/dc {grad} vs central differences {fd}: relative error {err:.2e}"
    if name != "hexapod_leg":   # its single winch's two tendons are both engaged
        assert (G <= -eps).any() and (G >= eps).any(), "want both slack and taut tendons here"


@pytest.mark.parametrize("name", PROBLEMS)
def test_state_sensitivity_three_ways(name):
    """dx/dc: perturb-and-resolve, and the adjoint gradient equals the
    forward sensitivity contracted with dO/dx."""
    _, _, model, targets = built(name)
    c = np.array(STATES[name])
    eq = solve_equilibrium(model, c)
    dxdc = state_sensitivity(model, eq)
    h = 1e-4
    for w in range(model.n_winches):
        e = np.zeros(model.n_winches)
        e[w] = h
        fd = (solve_equilibrium(model, c + e, eq.x).x - solve_equilibrium(model, c - e, eq.x).x) / (2 * h)
        assert np.linalg.norm(dxdc[:, w] - fd) <= 1e-5 * max(np.linalg.norm(fd), 1e-12)
    adjoint = objective_gradient(model, eq, targets.gradient(eq.x))
    forward = targets.gradient(eq.x) @ dxdc
    assert np.abs(adjoint - forward).max() <= 1e-9 * np.abs(forward).max()


def test_tension_chain_rule_equals_implicit_sensitivity():
    """The paper's dx/dtau dtau/dc: with A = dl/dx (routing matrix),
    H dx/dtau = A, and dtau/dc = U''(G) (dG/dc = 1 per winch, tendon
    lengths held) -- identical to H dx/dc = -d2E/dxdc."""
    _, _, model, _ = built("gripper")
    c = np.array(STATES["gripper"])
    eq = solve_equilibrium(model, c)
    A = model.length_gradient(eq.x)                       # (n_dofs, n_tendons)
    dtension = model.tendon_state(eq.x, c)["dtension"]
    W = np.zeros((model.n_tendons, model.n_winches))
    W[np.arange(model.n_tendons), model.tendon_winch] = 1.0
    dx_dtau = -np.column_stack([eq.factor.solve(A[:, t]) for t in range(model.n_tendons)])
    chain = dx_dtau @ (dtension[:, None] * W)
    ref = state_sensitivity(model, eq)
    assert np.abs(chain - ref).max() <= 1e-9 * np.abs(ref).max()


@pytest.mark.slow
def test_reparametrisation_is_c1_monotone_and_within_bounds():
    r = Reparametrisation.for_bounds([0.0, -5.0], [25.0, 5.0], blend=0.05)
    xi = np.linspace(-10, 35, 20001)
    xs = np.stack([xi, xi - 15], axis=1)
    c = np.array([r.f(x) for x in xs])
    d = np.array([r.df(x) for x in xs])
    assert np.all(c >= r.lower) and np.all(c <= r.upper)
    assert np.all(np.diff(c, axis=0) >= 0)
    # C1: derivative continuous, matches differences
    assert np.allclose(np.gradient(c[:, 0], xi), d[:, 0], atol=2e-3)
    assert np.max(np.abs(np.diff(d[:, 0]))) < 1e-2
    # identity away from the bounds, exact bounds at the clamp
    mid = (xi > 2) & (xi < 23)
    assert np.array_equal(c[mid, 0], xi[mid])
    assert r.f(r.clamp(np.array([100.0, 100.0]))).tolist() == [25.0, 5.0]
    # inverse
    for v in ([0.0, -5.0], [0.3, 4.9], [12.0, 0.0], [24.99, 5.0]):
        assert np.allclose(r.f(r.inverse(np.array(v))), v, atol=1e-12)


@pytest.mark.parametrize("name, fractions", [("gripper", [0.45, 0.05, 0.5]),
                                             ("hexapod", [0.5, 0.25]),
                                             ("hexapod_leg", [0.6])])
def test_known_answer_targets_are_recovered_from_rest(name, fractions):
    scene, mesh, model, targets = built(name)
    c_true = _at(model, fractions)
    ref = solve_equilibrium(model, c_true)
    goal = targets.replace_to(targets.y(ref.x))
    ctl = Controller(model, goal, np.zeros(model.n_winches) if np.all(model.lower <= 0) else model.lower)
    for it in ctl.iterates():
        assert np.all(it.contraction >= model.lower) and np.all(it.contraction <= model.upper)
        assert it.equilibrium.converged and it.equilibrium.positive_definite
    res = ctl.result()
    rms = goal.rms_error(res.equilibrium.x)
    assert rms < 0.1, f"{name}: RMS target error {rms:.3g} mm ({res.status})"
    assert res.converged, res.status


def test_unreachable_target_ends_at_the_bound_not_beyond():
    scene, mesh, model, targets = built("hexapod_leg")
    # the foot tip far below and behind: more contraction always helps
    far = Targets.at_points(mesh, [[100, -9]], [[0, -300]])
    res = solve_control(model, far)
    assert "bound active: leg" in res.status
    assert res.contraction[0] <= model.upper[0]
    assert res.contraction[0] >= model.upper[0] - 0.02 * (model.upper[0] - model.lower[0])
    for it in res.history:
        assert it.contraction[0] <= model.upper[0]


def test_frozen_winch_does_not_change_by_a_single_bit():
    _, _, model, targets = built("gripper")
    start = np.array([3.0, 0.0, 7.123456789])
    frozen = np.array([False, False, True])
    ctl = Controller(model, targets, start, frozen)
    seen = [it.contraction[2] for it in ctl.iterates()]
    assert len(seen) > 2
    assert all(v == start[2] for v in seen)
    assert np.array_equal(ctl.result().contraction[2:], start[2:])


def test_saturated_winch_comes_back_when_the_target_moves_back():
    _, mesh, model, _ = built("hexapod_leg")
    far = Targets.at_points(mesh, [[100, -9]], [[0, -300]])
    ctl = Controller(model, far)
    for _ in ctl.iterates():
        pass
    saturated = ctl.contraction[0]
    assert saturated > model.upper[0] - 0.02 * (model.upper[0] - model.lower[0])
    reachable = solve_equilibrium(model, [5.0])
    back = far.replace_to(far.y(reachable.x))
    ctl.set_targets(back)
    for _ in ctl.iterates():
        pass
    assert abs(ctl.contraction[0] - 5.0) < 0.05, ctl.status
    assert back.rms_error(ctl.history[-1].x) < 0.1


def _with_leg_bounds(lower, upper, contraction):
    scene, _, _, _ = built("hexapod_leg")
    w = scene.winches[0]
    scene = dataclasses.replace(scene, winches=(Winch(w.name, (lower, upper), contraction, False),))
    mesh = build_mesh(scene)
    return scene, mesh, build_model(scene, mesh)


def test_all_tendons_slack_ends_with_an_honest_status():
    # the winch may only let tendons out: every tendon stays slack, no gradient
    scene, mesh, model = _with_leg_bounds(-10.0, -5.0, -7.0)
    goal = Targets.at_points(mesh, [[100, -9]], [[80, -40]])
    ctl = Controller(model, goal)
    n = sum(1 for _ in ctl.iterates())
    assert n <= 3
    assert not ctl.converged
    assert "all tendons slack" in ctl.status and "leg" in ctl.status


def test_slack_winch_is_reeled_in_and_the_loop_recovers():
    scene, mesh, model = _with_leg_bounds(-10.0, 15.0, -4.0)
    ref = solve_equilibrium(model, [6.0])
    goal = Targets.at_points(mesh, [[100, -9], [50, 9]], np.zeros((2, 2)))
    goal = goal.replace_to(goal.y(ref.x))
    res = solve_control(model, goal)
    assert res.converged, res.status
    assert abs(res.contraction[0] - 6.0) < 0.01


def test_changing_targets_between_iterates_continues_from_the_current_pose():
    _, _, model, targets = built("gripper")
    ctl = Controller(model, targets)
    gen = ctl.iterates()
    first = [next(gen) for _ in range(3)]
    ctl.set_targets(targets.replace_to(targets.to + [5.0, 0.0]))
    nxt = next(gen)
    assert np.array_equal(nxt.contraction, first[-1].contraction)   # same pose, re-scored
    assert nxt.objective != first[-1].objective
    for _ in gen:
        pass
    assert ctl.history[-1].objective < nxt.objective


@pytest.mark.slow
@pytest.mark.parametrize("options", [ControlOptions(direction="gradient"), ControlOptions(bounds="clip")])
def test_other_directions_and_clipping_reduce_the_objective(options):
    _, _, model, targets = built("gripper")
    res = solve_control(model, targets, options=dataclasses.replace(options, max_iterations=30))
    assert res.objective < 0.1 * res.history[0].objective
    assert all(np.all(h.contraction >= model.lower) and np.all(h.contraction <= model.upper)
               for h in res.history)


def test_iteration_budget_is_an_honest_status():
    _, _, model, targets = built("gripper")
    res = solve_control(model, targets, options=ControlOptions(max_iterations=2))
    assert not res.converged and "iteration limit" in res.status
    assert len(res.history) == 3


def test_options_are_validated():
    with pytest.raises(ValueError, match="bounds: expected one of"):
        ControlOptions(bounds="box")
    with pytest.raises(ValueError, match="direction: expected one of"):
        ControlOptions(direction="newton")


def test_the_step_is_a_function_of_explicit_state():
    """search_direction and line_search take the damping and the
    Barzilai-Borwein step in and give them back: a winch on its bound
    pushed out and a frozen winch are held, the first steepest-descent step
    is initial_gradient_step of the range per unit gradient, steepest
    descent halves its step per rejected trial, Gauss-Newton raises mu per
    rejected trial and lowers it after the accepted one."""
    from types import SimpleNamespace

    from plush_opt.control.bounds import ClipBounds
    from plush_opt.control.step import line_search, search_direction
    lower, upper = np.zeros(3), np.full(3, 10.0)
    bounds, span = ClipBounds(lower, upper), upper - lower
    g = np.array([1.0, -2.0, 0.5])
    xi = np.array([0.0, 5.0, 5.0])
    frozen = np.array([False, False, True])
    sd = ControlOptions(direction="gradient")
    step, bb = search_direction(g, None, xi, frozen, bounds, span, sd, 1e-3, None)
    assert bb == pytest.approx(0.1 * 10.0 / np.sqrt(5.0))
    assert step[0] == 0.0 and step[2] == 0.0 and step[1] == pytest.approx(2.0 * bb)
    step, same = search_direction(g, None, xi, frozen, bounds, span, sd, 1e-3, 0.3)
    assert same == 0.3 and step[1] == pytest.approx(0.6)

    ok = SimpleNamespace(converged=True)
    tried = []

    def trial(c):
        tried.append(c.copy())
        return ok
    values = iter([2.0, 2.0, 0.5])
    found = line_search(xi, xi.copy(), frozen, bounds, 1.0, sd, 1e-3, lambda mu: np.array([0.0, 4.0, 1.0]),
                        trial, lambda eq: next(values))
    assert found.kind == "accepted" and found.equilibrium is ok and found.mu == 1e-3
    assert [c[1] for c in tried] == [9.0, 7.0, 6.0] and all(c[2] == 5.0 for c in tried)
    assert found.xi[1] == 6.0 and found.xi[2] == 5.0

    mus = []
    values = iter([2.0, 2.0, 0.5])
    gn = ControlOptions()
    found = line_search(xi, xi.copy(), frozen, bounds, 1.0, gn, 1e-3,
                        lambda mu: mus.append(mu) or np.array([0.0, 1.0, 0.0]), trial, lambda eq: next(values))
    assert mus == [1e-3, 1e-2, 1e-3 * 100.0] and found.mu == 1e-3 * 100.0 / 3.0
    found = line_search(xi, xi.copy(), frozen, bounds, 1.0, gn, 1e-3, lambda mu: np.zeros(3), trial,
                        lambda eq: 0.0)
    assert found.kind == "stationary" and found.mu == 1e-3
    found = line_search(xi, xi.copy(), frozen, bounds, 1.0, dataclasses.replace(gn, max_backtracks=2), 1e-3,
                        lambda mu: np.array([0.0, 1.0, 0.0]), trial, lambda eq: 2.0)
    assert found.kind == "no_decrease" and found.mu == 1e-3 * 10.0 * 10.0


def test_a_line_search_no_comparison_of_O_could_decide_is_stationary():
    """Where every trial fails, each certified, and none was predicted to
    lower O by more than its round-off (first order, -g . dc), the line
    search says so ('below_roundoff', the largest such decrease); where the
    first trial, certified, changes O by no more than its round-off either
    way, it says so after that trial alone (the others are smaller); with a
    larger prediction, a first trial not certified, or no gradient given,
    it found no decrease ('no_decrease') after every trial."""
    from types import SimpleNamespace

    from plush_opt.control.bounds import ClipBounds
    from plush_opt.control.step import line_search
    bounds = ClipBounds(np.zeros(3), np.full(3, 10.0))
    xi, frozen = np.array([1.0, 5.0, 5.0]), np.zeros(3, dtype=bool)
    g = np.array([1e-8, -1e-8, 0.0])
    gn = dataclasses.replace(ControlOptions(), max_backtracks=3)

    def search(roundoff, certified=(True, True, True), gradient=g, sizes=(2e-6, 1e-6, 5e-7)):
        flags, steps, solved = iter(certified), iter(sizes), []     # -g . dc: 2e-14, 1e-14, 5e-15
        found = line_search(xi, xi.copy(), frozen, bounds, 1.0, gn, 1e-3,
                            lambda mu: np.array([0.0, next(steps), 0.0]),
                            lambda c: solved.append(c) or SimpleNamespace(converged=next(flags), status="x"),
                            lambda eq: 1.0,
                            gradient=gradient, roundoff=roundoff)
        return found.kind, len(solved), found
    kind, solved, found = search(1e-13)
    assert (kind, solved) == ("below_roundoff", 1) and found.predicted == pytest.approx(2e-14)
    assert found.mu == 1e-3 * 10.0                           # (the damping raised for the rejected trial)
    assert search(2.001e-14)[:2] == ("below_roundoff", 1)
    assert search(1.999e-14)[:2] == ("no_decrease", 3)
    assert search(1e-13, certified=(False, True, True))[:2] == ("no_decrease", 3)
    assert search(1e-13, gradient=None)[:2] == ("no_decrease", 3)
    # a first trial predicted to raise O by more than its round-off: the smaller ones are tried
    # (a bounded step's first-order model fails far out), and all of them failing, nothing was predicted
    # to lower O
    assert search(1e-13, sizes=(-1e-3, -1e-4, -1e-5))[:2] == ("below_roundoff", 3)


def test_a_search_whose_trials_all_left_the_branch_says_the_branch_ends_ahead():
    """Where no trial is certified because each left the stable branch (a
    limit point just ahead: the crescent's lower arm at 20,517 nodes, where
    dO/dc grew to 3.6e4 and every trial snapped), the failed search says so;
    where a trial failed otherwise (an iteration limit) it says only that it
    failed."""
    from types import SimpleNamespace

    from plush_opt.control.bounds import ClipBounds
    from plush_opt.control.gradient import BRANCH_AHEAD, LINE_SEARCH_FAILED, _search_verdict
    from plush_opt.control.step import line_search
    from plush_opt.solve.branch import BRANCH_ENDS
    from plush_opt.solve.certificate import LEFT_BRANCH
    bounds = ClipBounds(np.zeros(2), np.full(2, 10.0))
    xi, frozen = np.array([5.0, 5.0]), np.zeros(2, dtype=bool)
    gn = dataclasses.replace(ControlOptions(), max_backtracks=3)
    model = SimpleNamespace(winch_names=("a", "b"), lower=np.zeros(2), upper=np.full(2, 10.0))
    last = SimpleNamespace(active_bounds=(), contraction=xi.copy(), gradient=np.array([-1.0, 0.0]), objective=1.0)
    plant = SimpleNamespace(path_dependent=False, path_cause=None)

    def verdict(statuses):
        trials = iter(statuses)
        found = line_search(xi, xi.copy(), frozen, bounds, 1.0, gn, 1e-3, lambda mu: np.array([0.1, 0.0]),
                            lambda c: SimpleNamespace(converged=False, status=next(trials)), lambda eq: 0.5,
                            gradient=last.gradient, roundoff=1e-13)
        return found.branch_ends, _search_verdict(found, last, model, gn, plant)
    ends, (converged, reason, status) = verdict([f"{BRANCH_ENDS}: it ends (limit point) past ...",
                                                 f"{LEFT_BRANCH}: smallest Hessian eigenvalue ...",
                                                 f"{BRANCH_ENDS}: it ends (limit point) past ..."])
    assert ends and (converged, reason) == (False, "no_decrease") and status == LINE_SEARCH_FAILED + BRANCH_AHEAD
    ends, (_, _, status) = verdict([f"{BRANCH_ENDS}: ...", "iteration limit (500) reached on the branch",
                                    f"{BRANCH_ENDS}: ..."])
    assert not ends and status == LINE_SEARCH_FAILED


def test_objective_roundoff_bounds_its_evaluation_at_nearby_float_poses():
    """Targets.roundoff(x): O at poses one unit in the last place from x
    (each coordinate up or down) stays within it of O(x)."""
    _, _, model, targets = built("gripper")
    x = solve_equilibrium(model, np.array([12.0, 0.3, 11.0])).x
    rng = np.random.default_rng(0)
    O, bound = targets.value(x), targets.roundoff(x)
    moved = [abs(targets.value(x * (1 + rng.choice([-1.0, 1.0], x.size) * np.finfo(float).eps)) - O)
             for _ in range(200)]
    assert 0 < max(moved) <= bound


@pytest.mark.slow
def test_a_loop_that_runs_out_of_resolution_ends_stationary_not_failed():
    """Steepest descent on the hexapod's leg with no stop rule of its own
    (gtol and ftol 0) goes on until its steps cannot lower O by more than
    O's round-off: it ends there 'stationary' (to the objective's
    round-off), at the golden optimum, not 'line search failed'."""
    _, _, model, targets = built("hexapod_leg")
    res = solve_control(model, targets, options=ControlOptions(gtol=0.0, ftol=0.0, direction="gradient"))
    assert (res.converged, res.reason) == (True, "stationary"), res.status
    assert res.status.startswith("stationary to the objective's round-off"), res.status
    assert res.objective == pytest.approx(0.713999138600949, rel=1e-9)
