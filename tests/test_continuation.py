"""A forward solve that fails from rest tries continuation in the
contraction and says so; the residual's round-off floor certifies a pose
whose Newton solve stalled on it, and nothing else."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from plush_opt import load
from plush_opt.solve import equilibrium
from plush_opt.solve.equilibrium import HANDOVER_WINDOW, EquilibriumOptions, roundoff_floor, solve_equilibrium
from cli_helpers import cli
from shipped import built

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def strip():
    return load(DATA / "thin_strip.yaml").model


def test_the_thin_strip_fails_from_rest_and_continuation_finds_its_pose(strip):
    plain = solve_equilibrium(strip, [30.0], options=EquilibriumOptions(eigenvalue=False))
    assert not plain.converged and plain.continuation_steps == 0
    assert plain.status.startswith("iteration limit")
    eq = solve_equilibrium(strip, [30.0], options=EquilibriumOptions(eigenvalue=False, continuation=4))
    assert eq.converged and eq.positive_definite
    assert eq.relative_residual <= 1e-10
    assert eq.continuation_steps >= 4
    # Newton from rest hands over as soon as it stops making progress, not at its limit
    assert "by continuation in the contraction" in eq.status
    assert f"no progress after {2 * HANDOVER_WINDOW} iterations" in eq.status
    assert np.array_equal(eq.contraction, [30.0])
    # the same pose as a careful continuation by hand (1 mm steps from rest)
    x = None
    for c in np.arange(1.0, 30.01, 1.0):
        step = solve_equilibrium(strip, [c], x, EquilibriumOptions(eigenvalue=False))
        assert step.converged, step.status
        x = step.x
    assert np.abs(eq.x - x).max() <= 1e-6


def test_a_continuation_that_fails_is_never_called_converged(strip):
    opts = EquilibriumOptions(eigenvalue=False, continuation=2, max_iterations=5)
    eq = solve_equilibrium(strip, [30.0], options=opts)
    assert not eq.converged
    assert "continuation in the contraction from [0.0] failed" in eq.status
    assert eq.status.startswith("iteration limit (5) reached")


def test_where_continuation_fails_after_a_handover_newton_resumes(monkeypatch):
    """The hand-over costs time, never an equilibrium: Newton from rest on
    the buckling strip halves its best residual only after 40 iterations
    (it converges at 61); with a window of 20 it hands over there, and where
    continuation fails too it resumes and ends where it would have."""
    _, _, model, _ = built("hard/buckling")
    c = np.array(model.upper)
    plain = solve_equilibrium(model, c)
    assert plain.converged and plain.iterations > 40
    monkeypatch.setattr(equilibrium, "HANDOVER_WINDOW", 20)
    monkeypatch.setattr(equilibrium, "continuation",
                        lambda model, failed, *a: replace(failed, status=f"{failed.status}; continuation failed"))
    eq = solve_equilibrium(model, c, options=EquilibriumOptions(continuation=4))
    assert eq.converged and eq.iterations == plain.iterations
    assert "resumed after 40 iterations (no progress after 40 iterations" in eq.status
    assert np.abs(eq.x - plain.x).max() <= 1e-9


def test_a_solve_that_converges_directly_is_unchanged_by_the_option():
    _, _, model, _ = built("hexapod_leg")
    plain = solve_equilibrium(model, [8.0])
    cont = solve_equilibrium(model, [8.0], options=EquilibriumOptions(continuation=4))
    assert cont.continuation_steps == 0 and cont.status == plain.status == "converged"
    assert np.array_equal(plain.x, cont.x) and plain.iterations == cont.iterations


def test_plush_opt_solve_says_it_used_continuation(tmp_path):
    out = tmp_path / "strip.json"
    r = cli("solve", str(DATA / "thin_strip.yaml"), "--contraction", "pull=30", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "by continuation in the contraction" in r.stdout
    doc = json.loads(out.read_text())
    assert doc["converged"] and doc["continuation_steps"] >= 4
    assert "by continuation" in doc["status"]


def test_a_newton_stall_on_the_round_off_floor_is_certified():
    """gtol below what float64 can resolve: Newton stalls on the floor; the
    certificate accepts the positive definite pose within it."""
    _, _, model, _ = built("hexapod_leg")
    tight = EquilibriumOptions(gtol=1e-14, eigenvalue=False, roundoff=1.0)
    before = solve_equilibrium(model, [8.0], options=EquilibriumOptions(gtol=1e-14, eigenvalue=False))
    assert not before.converged and before.status.startswith("residual stalled")
    eq = solve_equilibrium(model, [8.0], options=tight)
    assert eq.converged and eq.positive_definite
    assert eq.status.startswith("converged to the round-off floor")
    floor = roundoff_floor(model, eq.x, eq.contraction)
    assert 1e-14 * eq.force_scale < eq.residual_norm <= floor
    reference = solve_equilibrium(model, [8.0], options=EquilibriumOptions(eigenvalue=False))
    assert np.abs(eq.x - reference.x).max() <= 1e-9


def test_a_solve_that_is_not_converged_is_not_rescued_by_the_floor():
    _, _, model, _ = built("hexapod_leg")
    eq = solve_equilibrium(model, [8.0], options=EquilibriumOptions(max_iterations=3, eigenvalue=False,
                                                                     roundoff=1.0))
    assert not eq.converged and eq.status.startswith("iteration limit (3)")
    assert eq.residual_norm > 1e3 * roundoff_floor(model, eq.x, eq.contraction)


def test_a_saddle_is_never_certified_by_the_floor():
    """The straight buckling strip past its critical contraction: the
    residual vanishes, the Hessian is indefinite: not converged."""
    _, _, model, _ = built("hard/buckling")
    eq = solve_equilibrium(model, [2.0], options=EquilibriumOptions(escape_saddles=False, eigenvalue=False,
                                                                     roundoff=1.0))
    assert not eq.converged and not eq.positive_definite
    assert eq.status.startswith("saddle")
    assert eq.residual_norm <= eq.force_scale * 1e-10


@pytest.fixture(scope="module")
def strip_with_target():
    return load(DATA / "thin_strip.yaml").with_targets([{"at": [150, 0], "to": [120, 40]}])


def test_control_whose_start_fails_from_rest_starts_by_continuation(strip_with_target):
    from plush_opt.base.errors import SolverError
    from plush_opt.control import ControlOptions
    with pytest.raises(SolverError, match="starting equilibrium is not certified"):
        strip_with_target.control("reparam", {"pull": 30.0},
                                  options=ControlOptions(start_continuation=0, max_iterations=1))
    res = strip_with_target.control("reparam", {"pull": 30.0}, options=ControlOptions(max_iterations=2))
    start = res.history[0]
    assert np.array_equal(start.contraction, [30.0])
    assert "by continuation in the contraction" in start.equilibrium.status
    assert start.equilibrium.continuation_steps >= 4
    assert res.history[-1].objective < start.objective      # and the loop went on from there


@pytest.mark.slow
def test_bilevel_whose_start_fails_from_rest_starts_by_continuation(strip_with_target):
    from plush_opt.control import BilevelOptions
    res = strip_with_target.control("bilevel", {"pull": 30.0}, options=BilevelOptions(max_iter=3))
    assert res.history[0].objective > res.objective
    assert res.equilibrium is not None and res.equilibrium.converged


def test_start_continuation_is_checked():
    from plush_opt.control import BilevelOptions, ControlOptions
    with pytest.raises(ValueError, match="start_continuation"):
        ControlOptions(start_continuation=-1)
    with pytest.raises(ValueError, match="start_continuation"):
        BilevelOptions(start_continuation=1.5)


def test_the_survey_tool_applies_the_solvers_handover_rule():
    """tools/newton_from_rest.py (the survey behind HANDOVER_WINDOW) says
    the window fires on the thin strip where the solver hands over."""
    import sys
    sys.path.insert(0, str(Path(__file__).parent.parent / "tools"))
    import newton_from_rest
    assert newton_from_rest.fires([1.0] * 61, 30) == 60 and newton_from_rest.fires([1.0] * 60, 30) is None
    assert newton_from_rest.fires([0.5 ** k for k in range(100)], 30) is None
    rows = [[c.strip() for c in r.split("|")[1:-1]]
            for r in newton_from_rest.rows(DATA / "thin_strip.yaml", [HANDOVER_WINDOW])]
    assert [(r[3], r[4], r[-1]) for r in rows] == [("500", "no", str(2 * HANDOVER_WINDOW))] * 3


def test_the_round_off_floor_never_assembles_a_low_rank_hessian(monkeypatch):
    """On a fine mesh with finite attachments the tendons' blocks of the
    assembled Hessian hold billions of entries (`--accuracy 0.05` on the
    crescent ran out of memory there): the floor bounds |H| |x| by the
    sparse and low-rank parts apart, within a few % of the assembled one."""
    from plush_opt.base.low_rank import LowRankHessian
    model = load(Path(__file__).parent.parent / "problems" / "hexapod.yaml", max_area=2.0).model
    c = 0.5 * (np.asarray(model.lower) + np.asarray(model.upper))
    eq = solve_equilibrium(model, c, options=EquilibriumOptions(eigenvalue=False))
    assert eq.converged
    H = model.evaluate(eq.x, c, order=2).hessian_form
    assert isinstance(H, LowRankHessian)
    exact = np.abs(H.assemble()) @ np.abs(eq.x)
    bound = H.abs_product(np.abs(eq.x))
    assert np.all(bound >= exact * (1 - 1e-12)) and np.linalg.norm(bound) <= 1.1 * np.linalg.norm(exact)
    monkeypatch.setattr(LowRankHessian, "assemble", lambda self: pytest.fail("the floor assembled H"))
    assert roundoff_floor(model, eq.x, c) > 0
