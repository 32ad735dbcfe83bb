"""The order of the accuracy sweep: each level's cost predicted before it
is solved, the cheapest way to a level that meets the tolerance first, and
a stop as soon as one does (plush_opt.solve.accuracy_sweep)."""

import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from plush_opt.solve.accuracy import Resolution
from plush_opt.solve.accuracy_sweep import EXTRA_BUDGET, Chain, CostModel, Planner


def level(element, n, t, estimate=None, ratio=None):
    return SimpleNamespace(element=element, mesh=SimpleNamespace(n_nodes=n), cost=t, estimate=estimate,
                           ratio=ratio)


def chain(element, n0, refinements=3, family=1.0):
    return Chain(element, tuple(Resolution(family, r, family) for r in range(refinements + 1)), [n0])


def test_the_cost_model_fits_the_exponent_of_the_levels_solved():
    cost = CostModel()
    cost.add("P2", 1000, 1.0)
    cost.add("P2", 4000, 8.0)                      # t ~ n^1.5
    assert cost.exponent("P2") == pytest.approx(1.5)
    assert cost.predict("P2", 16000) == pytest.approx(64.0)
    # an element not solved yet: priced like the other one, per node
    assert cost.predict("P1", 4000) == pytest.approx(8.0)


def test_a_level_between_two_solved_ones_is_priced_between_them():
    """Small levels carry fixed costs (t = 0.05 + 1e-6 n^1.5 here): a level
    between two solved ones is interpolated, not extrapolated from the
    largest (which made the leg's 490-node level dearer than its 832-node
    one), and beyond them the nearest one prices it."""
    cost = CostModel()
    for n in (226, 832, 3187):
        cost.add("P1", n, 0.05 + 1e-6 * n ** 1.5)
    assert cost.predict("P1", 832) == pytest.approx(0.05 + 1e-6 * 832 ** 1.5)
    assert cost.predict("P1", 226) < cost.predict("P1", 490) < cost.predict("P1", 832)
    p = cost.exponent("P1")
    assert cost.predict("P1", 12748) == pytest.approx((0.05 + 1e-6 * 3187 ** 1.5) * 4 ** p)
    assert cost.predict("P1", 100) == pytest.approx((0.05 + 1e-6 * 226 ** 1.5) * (100 / 226) ** p)
    # two levels of one size (two families) count as their mean in log t
    cost.add("P1", 832, 0.5)
    assert cost.predict("P1", 832) == pytest.approx(math.sqrt(0.5 * (0.05 + 1e-6 * 832 ** 1.5)))


def test_a_chain_whose_first_estimate_is_cheaper_goes_first():
    p2, p1 = chain("P2", 800), chain("P1", 200)
    plan = Planner([p2, p1], tol=1.0)
    assert plan.pick(None) is p1                    # three P1 levels cost less than three P2 levels
    for n, t in ((200, 0.1), (800, 0.5), (3200, 2.5)):
        plan.solved(p1, level("P1", n, t))
    # its first estimate (at 800 nodes) is 8 x the tolerance, shrinking by 0.9 per level: no P1
    # level left is predicted to meet it, so the P2 chain is next
    p1.solved[1].estimate, p1.solved[1].ratio = 8.0, 0.9
    assert math.isinf(plan.cost_to_meet(p1))
    assert plan.pick(None) is p2


def test_the_estimate_trend_predicts_how_many_levels_a_chain_still_needs():
    p1 = chain("P1", 200)
    plan = Planner([p1], tol=1.0)
    for n, t in ((200, 0.1), (800, 0.4), (3200, 1.6)):
        plan.solved(p1, level("P1", n, t))
    p1.solved[1].estimate, p1.solved[1].ratio = 3.0, 0.25      # level 2 predicted 0.75: needs level 3
    assert plan.predicted_error(p1, 2) == pytest.approx(0.75)
    assert plan.cost_to_meet(p1) == pytest.approx(plan.cost.predict("P1", 12800))


def test_after_a_level_meets_only_cheaper_levels_are_solved_within_the_budget():
    p2, p1 = chain("P2", 800), chain("P1", 200)
    plan = Planner([p2, p1], tol=1.0)
    for n, t in ((200, 0.1), (800, 0.4), (3200, 1.6)):
        plan.solved(p1, level("P1", n, t))
    best = level("P1", 800, 0.3)
    assert plan.pick(best) is None                  # the P2 chain's first level, predicted 0.4 s: not faster
    best = level("P1", 3200, 1.6)
    assert plan.pick(best) is p2                    # 800 P2 nodes: predicted 0.4 s < 1.6 s
    plan.extra_spent = EXTRA_BUDGET * best.cost
    assert plan.pick(best) is None                  # the budget is spent


@pytest.mark.slow        # a sweep of mesh levels
def test_where_no_level_meets_at_the_returned_contraction_the_sweep_goes_on_there(monkeypatch):
    """The check at the returned contractions finds no level meeting the
    tolerance (forced here): the sweep goes on with them as a probe, every
    level solved before kept (not solved again at the probes); where it
    picks the level in use, that level is estimated afresh (it meets the
    tolerance there) and not solved again: the same mesh gives the same pose."""
    import numpy as np
    import plush_opt.apps.accuracy_run as run
    import plush_opt.solve.accuracy as accuracy
    from plush_opt.solve.equilibrium import solve_equilibrium
    root = Path(__file__).parent.parent
    acc = run.AccurateSolve(root / "problems" / "cantilever.yaml", 0.002)
    first_levels = list(acc.levels)
    c = np.array([0.6])
    eq = solve_equilibrium(acc.problem.model, c)
    assert eq.converged
    real_bounds, calls = run.bounds_at, []

    def bounds_at(*a, **k):           # the first check: as if no level met the tolerance there
        at = real_bounds(*a, **k)
        calls.append(at)
        for lv in at if len(calls) == 1 else ():
            lv.bound = lv.bound_via = None
        return at

    monkeypatch.setattr(run, "bounds_at", bounds_at)
    solved_here = []
    real_solve = accuracy._solve_level
    monkeypatch.setattr(accuracy, "_solve_level",
                        lambda *a, **k: solved_here.append(a[1]) or real_solve(*a, **k))
    resolved = []

    def resolve(problem, contraction, x0=None):
        resolved.append(problem)
        again = solve_equilibrium(problem.model, [contraction[problem.winch_names[0]]])
        return problem, again, {"accuracy": {}, "mesh_accuracy": {}}, ()

    p = acc.problem
    _, last, doc, _ = acc.check((p, eq, {"accuracy": {}, "mesh_accuracy": {}}, ()), resolve)
    assert np.asarray(acc.report["contractions"])[-1].tolist() == c.tolist()
    # the levels of the first sweep are kept: none of them is solved again
    assert not {(lv.element, lv.resolution) for lv in first_levels} & {(acc.scene.element, r) for r in solved_here}
    assert all(lv.y.shape[0] == len(acc.report["contractions"]) for lv in acc.levels)
    # the sweep picks the level in use again: estimated afresh there, not solved again (the same pose)
    assert resolved == [] and doc["accuracy"]["at_result"]["resolves"] == 0
    assert doc["accuracy"]["at_result"]["met"] is True
    assert doc["accuracy"]["at_result"]["estimated_error"] <= 0.002


@pytest.mark.slow        # three sweeps of the leg's levels
def test_the_legs_sweep_table_in_the_docs_is_what_the_sweep_solves():
    """docs/accuracy.md's table of what a sweep solves on the hexapod leg
    (tools/accuracy_sweep_cost.py): its levels, in order, and its pick
    and bound are the sweep's (counted work: the same on every run); only
    the CPU column is a measurement."""
    from plush_opt.io import load_scene
    from plush_opt.solve.accuracy import choose_levels
    root = Path(__file__).parent.parent
    doc = (root / "docs" / "accuracy.md").read_text()
    table = doc[doc.index("| TOL | levels solved, in order"):]
    rows = [line.split("|")[1:-1] for line in table.splitlines()[2:5]]
    scene = load_scene(root / "problems" / "hexapod_leg.yaml")
    for tol, order, total, largest, picked, bound, _ in rows:
        _, levels, report = choose_levels(scene, float(tol))
        nodes = [lv.mesh.n_nodes for lv in levels]
        assert order.strip() == ", ".join(f"{lv.element} {lv.mesh.n_nodes:,}" for lv in levels), tol
        assert (total.strip(), largest.strip()) == (f"{sum(nodes):,}", f"{max(nodes):,}")
        assert picked.strip() == f"{report['element']} {report['nodes']:,}"
        assert bound.strip() == f"{report['estimated_error']:.3g}"
