"""The gradient loop on a friction plant ends at an honest stop (issue 35).

With friction at via points O is piecewise smooth in the contractions: a
via point that slipped sticks when its winch reverses. The loop's step (in
the last step's modes) can then point where O rises at any length, and the
loop stopped "stalled" short of what a single winch's move still reaches
(gripper_friction.yaml: O 1.394, exit 3). Now trials near a bound are the
step's linear prediction, and where the loop would stop it tests the kink
with single-winch moves (plush_opt/control/kink.py): it either moves on or
stops at a point no such move improves, and says so (the shipped example
from the command line: tests/test_friction_status.py).

The notched finger (tests/data/notched_finger*.yaml) is a second scene of
this kind: reparam (friction 0.3) and clip (friction 0.1) stalled on it.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import plush_opt
from plush_opt.control.bounds import ClipBounds, ReparamBounds
from plush_opt.control.gradient import LINE_SEARCH_FAILED, _search_verdict
from plush_opt.control.gradient_options import ControlOptions
from plush_opt.control.kink import KinkRule, kink_verdict, probe_kink
from plush_opt.control.step import Outcome, line_search
from shipped import ROOT

DATA = ROOT / "tests" / "data"
# the single-winch moves a test of the claim re-drives, as fractions of the range
CHECK_STEPS = (1e-3, 1e-4)


# -- the notched finger ------------------------------------------------------------

def _independent_check(p, result, steps=CHECK_STEPS):
    """The stop's claim re-driven from the final state the result records:
    no single free winch moved by ``steps`` of its range (within bounds)
    lowers O by more than the loop's ftol. Returns the lowest O found."""
    plant = p.plant.fork(result.equilibrium.friction)
    model, c0 = p.model, result.equilibrium.contraction
    lowest = np.inf
    for h in steps:
        for w in range(model.n_winches):
            for sign in (1.0, -1.0):
                c = c0.copy()
                c[w] = np.clip(c0[w] + sign * h * (model.upper[w] - model.lower[w]), model.lower[w], model.upper[w])
                if c[w] == c0[w]:
                    continue
                eq = plant.trial(c)
                assert eq.converged, eq.status
                lowest = min(lowest, p.targets.value(eq.x))
    return lowest


@pytest.mark.parametrize("name, method", [("notched_finger", "reparam"), ("notched_finger", "clip"),
                                          ("notched_finger_mu01", "reparam"), ("notched_finger_mu01", "clip")])
def test_the_notched_finger_converges_with_both_bounds(name, method):
    """reparam at friction 0.3 and clip at friction 0.1 stalled (exit 3) on
    the notched finger; each run now ends stationary at the kink, O fell
    from iterate to iterate, and no single-winch move from the state the
    result records lowers O."""
    p = plush_opt.load(DATA / f"{name}.yaml")
    result = p.control(method=method)
    assert result.converged and result.reason == "stationary", result.status
    assert "friction at via points" in result.status and "single winch" in result.status
    objectives = [it.objective for it in result.history]
    assert all(b <= a for a, b in zip(objectives, objectives[1:]))
    assert all(it.equilibrium.converged for it in result.history)
    assert result.equilibrium.converged and result.objective < 1.0      # about 0.5 mm from the tip targets
    assert _independent_check(p, result) >= result.objective * (1 - ControlOptions().ftol)


def test_without_the_test_at_the_kink_the_loop_says_it_stalled():
    """The loop as it was (plain trials, no test at the kink) stalls on
    gripper_friction.yaml where it did (O 1.394) and says why, and what to
    try; the test at the kink alone moves on from there."""
    p = plush_opt.load(ROOT / "problems" / "gripper_friction.yaml")
    result = p.control(options=ControlOptions(trial_in_blend="mapped", kink_steps=()))
    assert not result.converged and result.reason == "no_decrease"
    assert result.status.startswith("stalled: no trial step lowered O (friction at via points")
    assert "another path may end lower: --method clip" in result.status
    assert result.objective == pytest.approx(1.39375, rel=1e-4)
    kink = p.control(options=ControlOptions(trial_in_blend="mapped"))
    assert kink.converged and kink.objective < 0.95 * result.objective, kink.status


# -- the pieces --------------------------------------------------------------------

class _Pose(SimpleNamespace):
    pass


def _piecewise(c):
    """A kink at (1, 2): O = |c0 - 1| + 2 |c1 - 2| + 0.5 (a trial's 'pose' is c)."""
    return abs(c[0] - 1.0) + 2.0 * abs(c[1] - 2.0) + 0.5


def _probe(c, failing=()):
    trials = []

    def trial(ct):
        trials.append(ct.copy())
        return _Pose(x=ct.copy(), converged=not any(np.allclose(ct, f) for f in failing))

    rule = KinkRule(steps=(1e-2, 1e-3), gain=1e-9, doublings=4, max_step=0.2)
    found = probe_kink(rule, np.array(c, float), _piecewise(c), np.array([False, False]), np.zeros(2),
                       np.full(2, 10.0), trial, lambda eq: _piecewise(eq.x))
    return rule, found, trials


def test_the_probe_finds_no_move_at_a_kink_and_says_what_it_checked():
    rule, found, trials = _probe([1.0, 2.0])
    assert not found.moved and found.tried == 8 and found.failed == 0 and len(trials) == 8
    converged, reason, status = kink_verdict(rule, found, (False, "no_decrease", "stalled: ..."),
                                             "friction at via points", "")
    assert converged and reason == "stationary" and status.startswith("stationary (nonsmooth, friction at via points): no step along")
    assert "single winch by 0.001 to 0.01 of its range within its bounds" in status
    converged, reason, status = kink_verdict(rule, found, (True, "stationary", "objective stopped decreasing"),
                                             "friction at via points", "")
    assert converged and reason == "stationary" and status == ("objective stopped decreasing; at the kink (friction at via points) no move of "
                                    "any single winch by 0.001 to 0.01 of its range within its bounds lowers O either")


def test_the_probe_takes_the_best_move_and_lengthens_it():
    """From (1.5, 2): lowering c0 helps (slope -1), the other moves do not;
    the move of 0.1 is doubled while O falls: 0.2, 0.4, then 0.8 passes the
    kink at 1 (O rises again), so it stops at 0.4."""
    _, found, _ = _probe([1.5, 2.0])
    assert found.moved
    np.testing.assert_allclose(found.contraction, [1.1, 2.0])
    assert found.objective == pytest.approx(_piecewise([1.1, 2.0]))


def test_a_probe_with_a_trial_that_did_not_certify_claims_nothing_more():
    rule, found, _ = _probe([1.0, 2.0], failing=[[1.1, 2.0]])
    assert not found.moved and found.failed == 1
    converged, reason, status = kink_verdict(rule, found, (False, "no_decrease", "stalled: x"),
                                             "friction at via points", "")
    assert not converged and reason == "no_decrease" and status == ("stalled: x; the test at the kink is incomplete: 1 of 8 single-winch "
                                        "moves did not reach a certified equilibrium")


def test_a_frozen_winch_and_a_bound_are_never_probed_past():
    trials = []
    rule = KinkRule(steps=(1e-2,), gain=1e-9, doublings=0, max_step=0.2)
    found = probe_kink(rule, np.array([0.0, 2.0]), 1.0, np.array([False, True]), np.zeros(2), np.full(2, 10.0),
                       lambda c: trials.append(c.copy()) or _Pose(x=c, converged=True), lambda eq: 2.0)
    assert not found.moved
    assert [t.tolist() for t in trials] == [[0.1, 2.0]]          # winch 0 upwards only; winch 1 frozen


def test_a_predicted_trial_moves_a_winch_at_its_bound_as_the_model_said():
    """At the lower edge of the blend zone f' = 0 is floored at 0.1: a step
    of 4.86 on xi predicts 0.486 on c, and the predicted trial moves it so
    far (f(xi + dxi) moved it 4.36). Away from the blend zones, and for
    clip, the trial is xi + step itself."""
    b = ReparamBounds([0.0], [25.0], 0.02)
    xi = b.edges()[0]
    assert float(b.f(xi + 4.86)[0]) == pytest.approx(4.36)
    xi_t = b.predicted(xi, np.array([4.86]), 0.1)
    assert float(b.f(xi_t)[0]) == pytest.approx(0.486)
    inside = np.array([10.0])
    assert b.predicted(inside, np.array([1.25]), 0.1)[0] == inside[0] + 1.25
    assert b.predicted(xi, np.array([0.0]), 0.1)[0] == xi[0]                   # no step: xi as it is
    assert b.predicted(xi, np.array([-1.0]), 0.1)[0] == pytest.approx(xi[0])   # outwards: stays on the bound
    c = ClipBounds([0.0], [25.0])
    assert c.predicted(np.array([24.0]), np.array([3.0]), 0.1)[0] == 25.0


def test_a_step_that_vanishes_under_the_damping_is_not_called_stationary():
    """Every trial rejected: the damping grows until the step moves nothing.
    That is a failed search ('vanished'), not a step that moves no winch:
    a history-free plant reports a failed line search (it used to read
    "every free winch is held at a bound" with no winch at a bound), a
    path-dependent one the stall (and its stop is then tested at the kink)."""
    opts = ControlOptions()
    b = ReparamBounds([0.0], [25.0], opts.blend)
    xi = np.array([10.0])
    found = line_search(xi, b.f(xi), np.array([False]), b, 1.0, opts, opts.initial_damping,
                        lambda mu: np.array([1.0 if mu <= opts.initial_damping else 0.0]),
                        lambda c: _Pose(x=c, converged=True), lambda eq: 2.0)
    assert found.kind == "vanished"
    first = line_search(xi, b.f(xi), np.array([False]), b, 1.0, opts, opts.initial_damping,
                        lambda mu: np.array([0.0]), lambda c: None, lambda eq: 2.0)
    assert first.kind == "stationary"
    model = SimpleNamespace(winch_names=("a",), lower=np.zeros(1), upper=np.full(1, 25.0))
    last = SimpleNamespace(active_bounds=(), contraction=np.array([10.0]), gradient=np.zeros(1), objective=1.0)
    free = SimpleNamespace(path_dependent=False, path_cause=None)
    friction = SimpleNamespace(path_dependent=True, path_cause="friction at via points")
    converged, reason, status = _search_verdict(found, last, model, opts, free)
    assert (converged, reason) == (False, "no_decrease") and status == LINE_SEARCH_FAILED
    converged, reason, status = _search_verdict(found, last, model, opts, friction)
    assert (converged, reason) == (False, "no_decrease") and status.startswith("stalled: no trial step lowered O")
    assert _search_verdict(Outcome("vanished", 1.0), last, model, opts, friction)[1] == "no_decrease"


@pytest.mark.slow       # six control runs
def test_the_table_in_docs_control_is_the_codes():
    """docs/control.md's table of friction runs (tools/friction_control_table.py)
    quotes the code: exit, O (its six digits) and iterates of every run
    with the defaults (the 'before' cells: the same tool with the handling
    of the kink switched off). The iterates within ITERATES_MOVE: on a
    path-dependent plant the machine's round-off moves a trial across a
    test (14 iterates on one host where another took 13, O the same to its
    six digits)."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("table", ROOT / "tools" / "friction_control_table.py")
    table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(table)
    text = (ROOT / "docs" / "control.md").read_text()
    block = text[text.index("<!-- kink-table -->"):text.index("<!-- /kink-table -->")].splitlines()[3:]
    shown = [line for line in block if line.startswith("|")]         # (its rows; the run's date after them)

    def now(row):           # the run's (exit, O, iterates), CPU seconds left out
        return row.strip("| ").split(" | ")[-1].split(", ")[:3]

    got, doc = [now(r) for r in table.rows(before=False)], [now(r) for r in shown]
    assert [g[:2] for g in got] == [d[:2] for d in doc]
    assert all(abs(int(g[2]) - int(d[2])) <= ITERATES_MOVE for g, d in zip(got, doc)), (got, doc)


ITERATES_MOVE = 2
