"""Newton's tentative full steps (a watchdog): a full step that raises the
energy is taken once at a time, and kept only if the step after it ends
below the start; otherwise the solve goes back and backtracks as before.
Either way it ends at the same certified equilibrium."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from plush_opt.fem.mesh import mesh_for_nodes
from plush_opt.solve import newton
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
from plush_opt.io import load_scene
from plush_opt.problem import from_scene
from shipped import ROOT, built

OPTIONS = EquilibriumOptions(eigenvalue=False)


def _solve_both(model, c, monkeypatch, caplog):
    """(without tentative steps, with them, the log lines of the second)."""
    monkeypatch.setattr(newton, "TENTATIVE_FAILURES", 0)
    without = solve_equilibrium(model, c, options=OPTIONS)
    monkeypatch.setattr(newton, "TENTATIVE_FAILURES", 1)
    caplog.clear()
    with caplog.at_level(logging.DEBUG, logger="plush_opt.solve.equilibrium"):
        with_ = solve_equilibrium(model, c, options=OPTIONS)
    return without, with_, [r.getMessage() for r in caplog.records]


def _model(name, nodes=None):
    """The shipped problem's model (its own mesh), or on a mesh of about ``nodes`` nodes."""
    if nodes is None:
        return built(name)[2]
    scene = load_scene(ROOT / "problems" / f"{name}.yaml")
    return from_scene(scene, mesh_for_nodes(scene, nodes)).model


@pytest.mark.parametrize("name", ["gripper", "hexapod_leg"])
def test_a_tentative_step_that_pays_off_saves_newton_steps(name, monkeypatch, caplog):
    """From rest with the winches at half their range, the tendons pull a
    soft body: full steps climb the energy's curved valley and the next one
    falls far below the start."""
    model = _model(name)
    c = 0.5 * model.upper
    without, with_, log = _solve_both(model, c, monkeypatch, caplog)
    assert without.converged and with_.converged
    assert any("(tentative)" in m for m in log)
    assert not any("did not pay off" in m for m in log)
    assert with_.iterations < without.iterations
    # the same certified equilibrium
    assert with_.energy == pytest.approx(without.energy, rel=1e-12)
    assert np.max(np.abs(with_.x - without.x)) < 1e-9 * np.max(np.abs(model.X))


def test_a_tentative_step_that_does_not_pay_off_goes_back(monkeypatch, caplog):
    """The gripper at its winches' upper bounds: a tentative step whose next
    step does not end below its start is undone, and the solve backtracks
    from the start as without tentative steps (the same equilibrium, bit for
    bit, one factorised step more)."""
    model = _model("gripper", 300)
    without, with_, log = _solve_both(model, model.upper, monkeypatch, caplog)
    assert without.converged and with_.converged
    assert any("(tentative)" in m for m in log) and any("did not pay off" in m for m in log)
    assert with_.iterations == without.iterations + 1
    assert np.array_equal(with_.x, without.x)
