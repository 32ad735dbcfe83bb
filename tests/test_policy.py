"""The control policy both methods share (plush_opt/control/policy.py):
stop rules, the look-further probe and the damping rule, on small
synthetic inputs."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from plush_opt.control import policy
from plush_opt.control.bilevel_options import BilevelOptions
from plush_opt.control.gradient import ControlOptions
from plush_opt.control.policy import (LEVENBERG_MARQUARDT, LOOP_ORDER, REDUCED_ORDER, Damping, ProbeRule,
                                      ProbeSite, StallState, StopRules, held_at_bounds, look_further,
                                      predict, probe_candidates, projected_gradient)

RULES = StopRules(gtol=1e-7, ftol=1e-9, patience=2, floor=1e-14, max_iterations=10, max_time=5.0)


def test_the_stall_count_rises_within_ftol_resets_on_a_decrease_and_ignores_a_rise():
    s = RULES.init_state(1.0)
    s = RULES.update(s, 1.0 - 1e-12)                # within ftol of the best: one more
    assert s == StallState(1, 1.0 - 1e-12)
    s = RULES.update(s, 2.0)                        # a rise (IPOPT's barrier): count kept
    assert s.count == 1 and s.best == 1.0 - 1e-12
    assert not RULES.stalled(s)
    s = RULES.update(s, s.best)
    assert RULES.stalled(s)
    s = RULES.update(s, 0.5)                        # a real decrease: back to zero
    assert s == StallState(0, 0.5)
    assert RULES.init_state() == StallState(0, math.inf)
    assert RULES.update(RULES.init_state(), 3.0) == StallState(0, 3.0)


def test_for_decreasing_objectives_the_stall_rule_is_the_loops_relative_decrease_test():
    """The loop only takes steps that lower O: the shared rule then counts
    exactly as its own test did (one more where O fell by less than ftol
    relative to the previous iterate, else zero)."""
    rng = np.random.default_rng(3)
    ftol = RULES.ftol
    o = 1.0
    state, count = RULES.init_state(o), 0
    for _ in range(200):
        new = o * (1 - (ftol * rng.uniform(0.0, 2.0) if rng.random() < 0.7 else rng.uniform(0, 0.5)))
        new = min(new, np.nextafter(o, 0.0))
        count = count + 1 if new > o * (1 - ftol) else 0
        state = RULES.update(state, new)
        assert state.count == count and state.best == new
        o = new


def test_each_stop_rule_on_its_own():
    s = StallState(0, 1.0)
    assert RULES.first(LOOP_ORDER, s, objective=1e-15, projected=1.0) == "reached"
    assert RULES.first(LOOP_ORDER, s, objective=1.0, projected=1.0, no_gradient=True) == "no_gradient"
    assert RULES.first(LOOP_ORDER, s, objective=1.0, projected=1e-8) == "stationary"
    assert RULES.first(LOOP_ORDER, s, objective=1.0, projected=2e-7) is None
    assert RULES.first(LOOP_ORDER, StallState(2, 1.0), objective=1.0, projected=1.0) == "stalled"
    assert RULES.first(LOOP_ORDER, s, objective=1.0, projected=1.0, iterations=10) == "iterations"
    assert RULES.first(LOOP_ORDER, s, objective=1.0, projected=1.0, t=5.0) == "time"
    # stationary is relative to max(O, floor): a tiny O does not make every gradient large
    assert RULES.stationary(1e-22, 0.0) and not RULES.stationary(1e-20, 0.0)
    no_limit = StopRules(1e-7, 1e-9, 2, 1e-14, 10, None)
    assert not no_limit.out_of_time(1e9)
    assert RULES.exhausted(1.0, 10, 0.0) and RULES.exhausted(0.0, 0, 0.0) and RULES.exhausted(1.0, 0, 5.0)
    assert not RULES.exhausted(1.0, 9, 4.9)


def test_without_an_iterate_only_the_budget_rules_apply():
    assert RULES.first(REDUCED_ORDER, StallState(5, 1.0), iterations=3) is None
    assert RULES.first(REDUCED_ORDER, StallState(5, 1.0), iterations=10) == "iterations"


def test_the_order_is_where_the_two_methods_differ():
    """With the budget spent at an iterate that also reaches the targets,
    the loop reports the targets, the reduced search its budget."""
    s = StallState(0, 1.0)
    both = dict(objective=0.0, projected=0.0, iterations=10, t=6.0)
    assert RULES.first(LOOP_ORDER, s, **both) == "reached"
    assert RULES.first(REDUCED_ORDER, s, **both) == "time"
    assert set(LOOP_ORDER) == set(policy.RULES) and set(REDUCED_ORDER) <= set(policy.RULES)


def test_both_methods_build_the_same_rules_from_their_default_options():
    loop = ControlOptions().stop_rules(BilevelOptions().objective_floor)
    reduced = BilevelOptions().stop_rules()
    assert (loop.gtol, loop.ftol, loop.patience, loop.floor, loop.max_time) == \
        (reduced.gtol, reduced.ftol, reduced.patience, reduced.floor, reduced.max_time)
    seq = [1.0, 0.5, 0.5 * (1 - 1e-10), 0.5 * (1 - 2e-10), 0.4]
    a, b = loop.init_state(seq[0]), reduced.init_state(seq[0])
    for o in seq[1:]:
        a, b = loop.update(a, o), reduced.update(b, o)
        assert a == b
        order = [r for r in LOOP_ORDER if r in REDUCED_ORDER and r not in ("iterations", "time")]
        assert loop.first(tuple(order), a, objective=o, projected=1e-9) == \
            reduced.first(tuple(order), b, objective=o, projected=1e-9)


def test_held_winches_are_those_at_a_bound_with_the_gradient_pointing_out():
    lower, upper = np.zeros(4), np.full(4, 10.0)
    c = np.array([0.0, 10.0, 0.0, 5.0])
    g = np.array([1.0, -1.0, -1.0, 1.0])           # out, out, in, interior
    assert held_at_bounds(c, g, lower, upper, 1e-6, np.zeros(4, bool)) == [0, 1]
    assert held_at_bounds(c, g, lower, upper, 1e-6, np.array([True, False, False, False])) == [1]
    # the tolerance may be per winch (the reduced search's fraction of each range)
    c2 = np.array([0.05, 9.99, 0.0, 5.0])
    assert held_at_bounds(c2, g, lower, upper, np.array([0.1, 0.001, 0.1, 0.1]), np.zeros(4, bool)) == [0]


def test_the_projected_gradient_drops_held_winches_unless_the_rest_of_the_way_matters():
    g = np.array([3.0, 4.0, 12.0])
    span = np.array([2.0, 2.0, 2.0])
    assert projected_gradient(g, [], span) == pytest.approx(13.0 * 2.0)
    assert projected_gradient(g, [2], span) == pytest.approx(5.0 * 2.0)
    lower, upper = np.zeros(3), np.full(3, 2.0)
    c = np.array([1.0, 1.0, 1e-3])                  # winch 2 a little inside its lower bound
    # |g| x gap = 12e-3: negligible against 0.1, not against 1e-3
    assert projected_gradient(g, [2], span, c, lower, upper, negligible=0.1) == pytest.approx(10.0)
    assert projected_gradient(g, [2], span, c, lower, upper, negligible=1e-3) == pytest.approx(26.0)
    assert np.array_equal(g, [3.0, 4.0, 12.0])      # the caller's gradient is not changed


def _line_model(n=2):
    return SimpleNamespace(lower=np.zeros(n), upper=np.full(n, 10.0), admissible=lambda x: True)


def _site(c, objective, start, slack=(), held=()):
    return ProbeSite(np.array(c, float), np.zeros(4), objective, start, list(slack), list(held))


def test_a_stuck_run_probes_a_held_winch_inwards_and_takes_the_first_real_gain():
    model = _line_model()
    rule = ProbeRule(stuck_fraction=0.5, fractions=(0.05, 0.15, 0.4), gain=1e-3)
    seen = []

    def solve(c):
        seen.append(c.copy())
        return (0.9 if c[0] >= 1.5 else 1.0 - 1e-6), "eq"     # only the 15 % probe gains enough
    move, tried = look_further(rule, _site([0.0, 5.0], 1.0, 1.0, held=[0]), {}, model, solve,
                               lambda r: np.zeros(2))
    assert [s[0] for s in seen] == [0.5, 1.5]                # inwards from the lower bound
    assert move.winch == 0 and move.kind == "probe" and move.contraction[0] == 1.5
    assert move.contraction[1] == 5.0 and move.result == "eq"
    assert tried == {0: 1.0}
    # from the upper bound the probes go down; none gains: no move, the winch tried
    seen.clear()
    move, tried = look_further(rule, _site([10.0, 5.0], 1.0, 1.0, held=[0]), {1: 1.0}, model,
                               lambda c: seen.append(c.copy()) or (1.0, "eq"), lambda r: np.zeros(2))
    assert [s[0] for s in seen] == [9.5, 8.5, 6.0]
    assert move is None and tried == {0: 1.0, 1: 1.0}


def test_a_run_that_made_progress_does_not_probe_and_a_failed_solve_is_skipped():
    model = _line_model()
    rule = ProbeRule(0.5, (0.05, 0.15), 1e-3)
    site = _site([0.0, 5.0], 0.4, 1.0, held=[0])             # O halved since the start: not stuck
    assert probe_candidates(rule, site, {}) == []
    move, tried = look_further(rule, site, {}, model, lambda c: pytest.fail("solved"), None)
    assert move is None and tried == {}
    stuck = _site([0.0, 5.0], 0.9, 1.0, held=[0])
    move, tried = look_further(rule, stuck, {}, model, lambda c: None, None)
    assert move is None and tried == {0: 0.9}


def test_a_slack_winch_is_reeled_in_and_kept_only_if_pulling_then_helps(monkeypatch):
    model = _line_model()
    monkeypatch.setattr(policy, "take_up", lambda model, x, c, w: 2.0)
    rule = ProbeRule(0.5, (0.05,), 1e-3)
    site = _site([1.0, 5.0], 0.1, 1.0, slack=[0])
    move, _ = look_further(rule, site, {}, model, lambda c: (0.1, "eq"), lambda r: np.array([-1.0, 0.0]))
    assert move.kind == "slack" and move.contraction[0] == 2.0
    # pulling does not help: the take-up is not kept, the probe from it is tried
    seen = []

    def solve(c):
        seen.append(c[0])
        return 0.1, "eq"
    move, _ = look_further(rule, site, {}, model, solve, lambda r: np.array([1.0, 0.0]))
    assert move is None and seen == [2.0, 2.5]
    # O may rise by round-off only
    move, _ = look_further(rule, site, {}, model, lambda c: (0.1 * (1 + 1e-6), "eq"),
                           lambda r: np.array([-1.0, 0.0]))
    assert move is None


def test_winches_held_together_are_probed_together_and_the_probe_that_lowers_o_most_is_taken():
    model = _line_model(3)
    rule = ProbeRule(stuck_fraction=0.5, fractions=(0.05, 0.15), gain=1e-3)
    site = _site([0.0, 0.0, 5.0], 1.0, 1.0, held=[0, 1])
    seen = []

    def both(c):                      # each winch alone raises O, both together lower it
        seen.append(c.copy())
        return (0.8 if c[0] > 0 and c[1] > 0 else 1.1), "eq"
    move, tried = look_further(rule, site, {}, model, both, None)
    assert [s.tolist() for s in seen] == [[0.5, 0.0, 5.0], [0.0, 0.5, 5.0], [0.5, 0.5, 5.0]]
    assert move.kind == "probe" and move.winches == (0, 1) and move.contraction.tolist() == [0.5, 0.5, 5.0]
    assert move.describe(["a", "b", "c"]) == "a, b to 0.5, 0.5"
    assert tried == {0: 1.0, 1: 1.0}
    # where one winch alone lowers O most it is that one, and only it counts as tried
    move, tried = look_further(rule, site, {}, model, lambda c: (1.0 - 0.1 * c[1] + 0.2 * c[0], "eq"), None)
    assert move.winches == (1,) and move.winch == 1 and move.contraction.tolist() == [0.0, 0.5, 5.0]
    assert tried == {1: 1.0}
    # nothing lowers O: no move, every fraction tried alone and together, every winch tried
    seen.clear()
    move, tried = look_further(rule, site, {}, model, lambda c: seen.append(c.copy()) or (1.0, "eq"), None)
    assert move is None and len(seen) == 6 and tried == {0: 1.0, 1: 1.0}
    # a single held winch is probed alone only
    seen.clear()
    look_further(rule, _site([0.0, 0.0, 5.0], 1.0, 1.0, held=[1]), {}, model,
                 lambda c: seen.append(c.copy()) or (1.0, "eq"), None)
    assert [s.tolist() for s in seen] == [[0.0, 0.5, 5.0], [0.0, 1.5, 5.0]]


def test_the_loop_tries_a_winch_once_the_reduced_search_again_after_a_real_decrease():
    once = ProbeRule(0.5, (0.05,), 1e-3, retry=False)
    again = ProbeRule(0.5, (0.05,), 1e-3, retry=True)
    site = _site([0.0, 5.0], 0.9, 1.0, held=[0, 1])
    assert probe_candidates(once, site, {0: 5.0}) == [1]
    assert probe_candidates(again, site, {0: 5.0}) == [0, 1]
    assert probe_candidates(again, site, {0: 0.9 * (1 + 1e-3)}) == [1]      # not lower by gain
    assert probe_candidates(again, site, {0: 0.9 * (1 + 2e-3)}) == [0, 1]


def test_the_damping_schedule():
    d = Damping(initial=1e-3, minimum=1e-9, decrease=3.0, increase=10.0)
    assert d == LEVENBERG_MARQUARDT
    assert d.accepted(1e-3) == 1e-3 / 3.0 and isinstance(d.accepted(1e-3), float)
    assert d.accepted(2e-9) == 1e-9                       # the floor
    assert d.rejected(1e-3) == 1e-3 * 10.0 and d.rejected(1e-3, 2) == 1e-3 * 100.0
    assert d.scale(np.array([0.0, 4.0, 2.0])) == 4.0 and d.scale(np.zeros(2)) == 1e-300
    capped = d.with_cap(1e-3, curvature_floor=1e-308)
    assert (capped.initial, capped.maximum, capped.minimum, capped.curvature_floor) == (1e-3, 1e-3, 1e-9, 1e-308)
    mu = np.array([1e-3, 1e-4])
    np.testing.assert_array_equal(capped.rejected(mu), [1e-3, 1e-3])                 # per winch, capped
    np.testing.assert_array_equal(capped.accepted(mu), [1e-3 / 3.0, 1e-4 / 3.0])
    assert d.with_cap(0.0).minimum == 0.0
    opts = ControlOptions(initial_damping=1e-2, min_damping=1e-8, damping_decrease=2.0, damping_increase=4.0)
    assert opts.damping == Damping(1e-2, 1e-8, 2.0, 4.0)


def test_the_predictor_is_used_only_where_admissible():
    x, dxdc = np.zeros(2), np.array([[1.0, 0.0], [0.0, 2.0]])
    ok = SimpleNamespace(admissible=lambda x: True)
    np.testing.assert_array_equal(predict(ok, x, dxdc, np.zeros(2), np.array([1.0, 1.0])), [1.0, 2.0])
    bad = SimpleNamespace(admissible=lambda x: False)
    assert predict(bad, x, dxdc, np.zeros(2), np.ones(2)) is x
    assert predict(ok, x, None, np.zeros(2), np.ones(2)) is x
