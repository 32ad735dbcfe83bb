"""The plant (plush_opt/solve/plant.py): the forward model as one object
that owns its history. The factory is the one place that asks whether a
scene has friction at via points; drive/commit/reset keep the history the
path solver gives; the sensitivities match a re-solve at a nearby
contraction for the history-free and the path-dependent plant alike."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from plush_opt.solve.friction_solve import drive, solve_forward
from plush_opt.solve.plant import ElasticPlant, FrictionPlant, make_plant
from plush_opt.solve.sensitivity import implicit_derivative
from test_friction import arc, problem

PACKAGE = Path(__file__).resolve().parent.parent / "plush_opt"
SAME = 1e-6            # poses reached the same way agree to solver tolerance (mm)
HISTORY = 1e-3         # poses reached by other histories differ by more (mm)

# ways to ask "does this scene have friction" that belong to the factory alone
DECISIONS = re.compile(r"has_friction|follows_friction|friction_tendons|\.friction is (not )?None"
                       r"|getattr\([^)]*[\"']friction|FrictionModel\(|friction_solve|friction_path"
                       r"|problem\.friction\b|p\.friction\b")


def test_only_the_factory_decides_whether_a_scene_has_friction():
    found = [f"{path.relative_to(PACKAGE)}:{n}: {line.strip()}"
             for folder in ("apps", "control") for path in sorted((PACKAGE / folder).rglob("*.py"))
             for n, line in enumerate(path.read_text().splitlines(), 1) if DECISIONS.search(line)]
    assert found == []
    askers = sorted(str(path.relative_to(PACKAGE)) for path in PACKAGE.rglob("*.py")
                    if "friction_tendons(" in path.read_text())
    assert askers == ["fem/friction.py", "solve/plant.py"]


def test_the_factory_builds_the_plant_the_scene_needs():
    assert type(problem(arc(0.3, stiff=False)).plant) is FrictionPlant
    plain = problem(arc(0.0, stiff=False))
    assert type(plain.plant) is ElasticPlant and not plain.plant.path_dependent
    assert plain.plant.history_note is None
    segmented = make_plant(plain.model, segmented=True)           # the sweep's: every tendon in segments
    assert type(segmented) is FrictionPlant and segmented.path_dependent


def test_friction_plant_drive_commit_reset_keep_the_history():
    p = problem(arc(0.3, stiff=False))
    fm = p.plant.friction_model
    plant = p.plant.fork()
    assert plant.state is None and plant.friction_model is fm        # forks share the model
    fresh = solve_forward(fm, [1.0])
    up = plant.drive([3.0])
    assert plant.state is None                                       # driving does not commit
    assert np.max(np.abs(plant.drive([1.0]).x - fresh.x)) <= SAME
    plant.commit(up)
    assert plant.state is up.friction and p.plant.state is None      # the problem's plant keeps none
    back = plant.drive([1.0])
    by_hand = drive(fm, solve_forward(fm, [3.0]).friction, [1.0])
    assert np.max(np.abs(back.x - by_hand.x)) <= SAME                # the old path, step by step
    assert np.max(np.abs(back.x - fresh.x)) > HISTORY                # hysteresis: the history matters
    plant.reset()
    assert plant.state is None and np.max(np.abs(plant.drive([1.0]).x - fresh.x)) <= SAME
    plant.reset(up.friction)
    assert np.max(np.abs(plant.drive([1.0]).x - by_hand.x)) <= SAME


def test_elastic_plant_is_history_free():
    p = problem(arc(0.0, stiff=False))
    plant = p.plant.fork()
    first = plant.drive([2.0])
    plant.commit(first)
    assert plant.state is first
    again = plant.drive([2.0])
    assert np.array_equal(again.x, p.equilibrium({"w": 2.0}).x)     # the committed pose changes nothing
    trial = plant.trial(np.array([2.5]), first.x)                    # on the committed stable branch
    assert trial.converged and np.max(np.abs(trial.x - p.equilibrium({"w": 2.5}).x)) <= SAME


@pytest.mark.parametrize("friction", [0.0, 0.3])
def test_sensitivity_against_a_re_solve_at_a_nearby_contraction(friction):
    p = problem(arc(friction, stiff=False))
    plant = p.plant.fork()
    eq = plant.drive([2.0])
    plant.commit(eq)
    S = plant.sensitivity(eq)[:, 0]
    assert np.abs(S).max() > 0
    errors = []
    for h in (1e-2, 1e-3):                       # loading on: the same stick/slip modes
        near = plant.drive([2.0 + h], eq.x)
        assert near.converged
        errors.append(np.abs((near.x - eq.x) / h - S).max() / np.abs(S).max())
    assert errors[1] <= 1e-4 and errors[1] < 0.2 * errors[0]             # first order: O(h)
    dO_dx = np.random.default_rng(0).standard_normal(eq.x.size)
    assert plant.objective_gradient(eq, dO_dx)[0] == pytest.approx(S @ dO_dx, rel=1e-6)


def test_implicit_derivative_solves_column_by_column():
    p = problem(arc(0.0, stiff=False))
    eq = p.equilibrium({"w": 2.0})
    M = np.column_stack([p.model.mixed(eq.x, eq.contraction)[:, 0], np.zeros(eq.x.size),
                         np.arange(eq.x.size, dtype=float)])
    D = implicit_derivative(eq.factor, M)
    for j in range(3):
        assert np.array_equal(D[:, j], -eq.factor.solve(M[:, j]) if M[:, j].any() else np.zeros(eq.x.size))
    only = implicit_derivative(eq.factor, M, columns=[2])
    assert np.array_equal(only[:, 2], D[:, 2]) and not only[:, :2].any()


def test_control_commits_to_its_own_fork_never_to_the_problems_plant():
    from plush_opt.control import ControlOptions, Controller
    from test_friction import arc_with_target
    p = problem(arc_with_target())
    res = p.control("clip", options=ControlOptions(max_iterations=2))
    assert p.plant.state is None                                   # Problem.control forked it
    plant = p.plant.fork()
    ctl = Controller(p.model, p.targets, options=ControlOptions(bounds="clip", max_iterations=2), plant=plant)
    for it in ctl.iterates():
        assert plant.state is it.equilibrium.friction              # every iterate committed
    assert np.array_equal(ctl.history[-1].x, res.history[-1].x) and p.plant.state is None
