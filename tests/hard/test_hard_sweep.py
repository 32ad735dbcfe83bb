"""The certificate holds on every solver path: all shipped problems and all
hard problems, several contractions, both equilibrium backends, method 1
control (and the bilevel method when it is present).

Whatever a solver returns, ``converged=True`` must mean what it says:
the pose is admissible, the relative residual is within tolerance, and
the Hessian is positive definite beyond round-off. Each claim is
re-checked independently from ``model.evaluate`` (dense Cholesky of
``H - 10 eps |H| I``, see hardlib.py). Unconverged results must come with
a status and an admissible pose.
"""

from __future__ import annotations

import numpy as np
import pytest

from hardlib import (BACKENDS, SHIPPED, assert_honest, assert_within_bounds, backend_marks, built, eq_options,
                     hard_names, recheck)
from plush_opt.control.gradient import ControlOptions, solve_control
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
from plush_opt.base.errors import SceneError, SolverError
from plush_opt.solve.plant import make_plant

try:
    from plush_opt.control.bilevel import BilevelOptions, solve_bilevel
except ImportError:                      # pragma: no cover - depends on the tree
    solve_bilevel = None

SHIPPED_NAMES = sorted(p.stem for p in SHIPPED.glob("*.yaml"))
REFUSED = ("underpinned_one_pin", "underpinned_one_node",      # SceneError before solving
           "underpinned_island", "underpinned_hinge")
SWEPT = SHIPPED_NAMES + [n for n in hard_names() if n not in REFUSED]

#: (scene, backend) -> reason of a strict xfail, for known defects
KNOWN = {}


def settings_of(model):
    """Contractions to sweep, (k, n_winches): all winches at 0 %, 40 % and
    100 % of their range, and alternately at the upper and lower bound."""
    lo, hi = model.lower, model.upper
    alternate = np.where(np.arange(model.n_winches) % 2 == 0, hi, lo)
    return [lo, lo + 0.4 * (hi - lo), hi.copy(), alternate]


def _params():
    for name in SWEPT:
        for backend in BACKENDS:
            reason = KNOWN.get((name, backend))
            marks = ([pytest.mark.xfail(strict=True, raises=AssertionError, reason=reason)]
                     if reason else []) + backend_marks(backend)
            yield pytest.param(name, backend, marks=marks, id=f"{name}-{backend}")


def test_the_sweep_covers_every_problem_file():
    assert {"gripper", "hexapod", "hexapod_leg"} <= set(SHIPPED_NAMES)
    assert len(hard_names()) >= 10 and set(REFUSED) <= set(hard_names())
    for name in REFUSED:
        with pytest.raises(SceneError, match=r"pins: .*more pin\(s\) at distinct points are needed"):
            built(name)


@pytest.mark.parametrize("name, backend", list(_params()))
def test_equilibria_are_certified_or_honest(name, backend):
    _, _, model, _ = built(name)
    settings = settings_of(model)
    if backend == "ipopt" and model.contact is not None and model.contact.self_contact:
        # self-contact's pairs grow with the square of the boundary: refused in one line
        with pytest.raises(SceneError, match="not self-contact"):
            solve_equilibrium(model, model.lower, options=eq_options(backend))
        return
    if backend == "ipopt" and model.contact is not None and model.contact.obstacles:
        # every obstacle pair in one expression: IPOPT takes ~15 s a solve here, so one
        # setting (tests/test_contact_ipopt.py compares it with Newton on a small body)
        settings = settings[1:2]
    claimed = 0
    for c in settings:
        eq = solve_equilibrium(model, c, options=eq_options(backend))
        assert_honest(model, eq, f"{name} {backend} c={np.round(c, 3).tolist()}")
        claimed += eq.converged
    if name in SHIPPED_NAMES and backend == "newton":
        assert claimed == len(settings), f"{name}: a shipped problem should solve at every setting"


@pytest.mark.slow
@pytest.mark.parametrize("name", SWEPT)
def test_method1_iterates_are_certified_within_bounds(name):
    _, _, model, targets = built(name)
    if not targets.n_targets:
        pytest.skip("no targets: forward problem only")
    if make_plant(model).path_dependent:
        # the loop drives the path-dependent plant (its iterates are states
        # of a path, not equilibria of the model alone): tested in test_friction*.py
        from plush_opt.control import Controller
        assert Controller(model, targets).plant.path_dependent
        return
    runs = [ControlOptions(equilibrium=EquilibriumOptions(eigenvalue=False)),
            ControlOptions(bounds="clip", max_iterations=10,
                           equilibrium=EquilibriumOptions(eigenvalue=False))]
    for options in runs:
        try:
            res = solve_control(model, targets, options=options)
        except SolverError as exc:             # an uncertifiable start is refused, honestly
            assert "the starting equilibrium is not certified" in str(exc)
            continue
        what = f"{name} {options.bounds}/{options.equilibrium.backend}"
        assert isinstance(res.status, str) and res.status
        for it in res.history:
            assert_within_bounds(model, it.contraction, what)
            problems = recheck(model, it.equilibrium)
            assert it.equilibrium.converged and not problems, \
                f"{what} iterate {it.iteration}: {it.equilibrium.status}; {problems}"
        if res.converged:
            assert res.objective <= res.history[0].objective


@pytest.mark.slow
@pytest.mark.skipif(solve_bilevel is None, reason="plush_opt.control.bilevel not present")
@pytest.mark.parametrize("name", SWEPT)
def test_bilevel_claims_are_certified(name):
    _, _, model, targets = built(name)
    if not targets.n_targets:
        pytest.skip("no targets: forward problem only")
    if make_plant(model).path_dependent:
        # no history in the bilevel method: it refuses, naming the key
        with pytest.raises(SceneError, match="tendons.friction"):
            solve_bilevel(model, targets, model.scene.contraction, model.scene.frozen)
        return
    res = solve_bilevel(model, targets, model.scene.contraction, model.scene.frozen,
                        options=BilevelOptions(max_time=5.0))
    assert isinstance(res.status, str) and res.status
    assert_honest(model, res.equilibrium, f"{name} bilevel")
    if res.converged:
        assert_within_bounds(model, res.contraction, f"{name} bilevel")
        assert not recheck(model, res.equilibrium), res.status


@pytest.mark.slow
def test_ipopt_backend_certifies_a_pose_that_passes_the_certificate():
    _, _, model, _ = built("gripper")
    c = np.zeros(model.n_winches)
    eq = solve_equilibrium(model, c, options=eq_options("ipopt"))
    assert_honest(model, eq)
    if not eq.converged:                      # the pose itself is fine:
        assert not recheck(model, eq), eq.status
    assert eq.converged, eq.status
