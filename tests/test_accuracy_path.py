"""``--accuracy`` where the pose depends on the path (friction at via points):
the sweep's probe poses are the plant's fresh paths, and at the returned
pose every level replays the path it was reached by
(plush_opt/solve/accuracy_path.py; docs/accuracy.md, "What is guaranteed").

problems/gripper_friction.yaml on a coarse mesh keeps them fast.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from plush_opt import load
from shipped import ROOT, with_max_area

FRICTION = ROOT / "problems" / "gripper_friction.yaml"
COARSE = 150.0          # max_area (mm^2): ~140 nodes, enough for the stick/slip paths
SAME = 1e-6             # poses reached by the same path agree to solver tolerance (mm)
HISTORY = 1e-3          # poses reached by other paths (or without friction) differ by more (mm)


@pytest.fixture(scope="module")
def friction_problem():
    return load(FRICTION, max_area=COARSE)


def test_replay_reaches_the_control_runs_answer_and_the_path_matters(friction_problem):
    """The returned path (the control run's start and accepted iterates)
    replayed on the answer's own mesh gives the answer back; the fresh path
    straight to the same contractions gives another pose, so replaying is
    what makes the levels comparable."""
    from plush_opt.control import ControlOptions
    from plush_opt.solve.accuracy_path import replay
    from plush_opt.solve.plant import make_plant
    p = friction_problem
    # six iterates: the state of the first four is also reached by a straight
    # path to their contractions (to 3e-13 mm); by the sixth it is not
    res = p.control("reparam", options=ControlOptions(max_iterations=6))
    assert res.equilibrium.converged and len(res.history) >= 3
    waypoints = np.array([it.contraction for it in res.history])
    plant = make_plant(p.model)
    c = res.equilibrium.contraction
    again = replay(plant, waypoints, c)
    assert again.converged
    assert np.max(np.abs(again.x - res.equilibrium.x)) < SAME
    fresh = replay(plant, None, c)
    assert fresh.converged and np.max(np.abs(fresh.x - res.equilibrium.x)) > HISTORY
    assert plant.state is None          # the replay ran on a fork: nothing committed to the plant given


def test_a_sweeps_probe_pose_is_the_plants_fresh_path(friction_problem):
    """A level of the sweep solves each probe contraction by the plant's
    fresh path from the start state, in ``PROBE_PATH_STEPS`` steps (what
    ``Problem.equilibrium`` gives in its ten, to well within the estimate's
    differences), not by the frictionless model's equilibrium (what it did
    before, and claimed the tolerance for a model the scene does not have)."""
    from plush_opt.solve.accuracy import LEVEL_OPTIONS, PROBE_PATH_STEPS, Resolution, _solve_level, probe_points
    from plush_opt.problem import from_scene
    from plush_opt.solve.equilibrium import solve_equilibrium
    p = friction_problem
    given = {"left": 12.0, "grip": 10.0}
    c = p.contraction_vector(given)
    points, _ = probe_points(p.scene)
    level = _solve_level(p.scene, Resolution(COARSE, 0, COARSE), c[None], points, None, LEVEL_OPTIONS)
    on_level = from_scene(p.scene, level.mesh)
    x = level.poses[0]
    assert np.max(np.abs(x - on_level.plant.equilibrium(c, steps=PROBE_PATH_STEPS).x)) < SAME
    assert np.max(np.abs(x - on_level.equilibrium(given).x)) < HISTORY
    assert np.max(np.abs(x - solve_equilibrium(on_level.model, c).x)) > HISTORY


@pytest.mark.slow          # a sweep of friction paths at four contractions on six levels
def test_load_with_accuracy_chooses_the_mesh_on_the_friction_plants_poses(tmp_path):
    """The Python API no longer refuses a friction scene: its mesh is chosen
    on the plant's fresh paths to the probe contractions (the poses
    ``Problem.equilibrium`` returns)."""
    p = load(with_max_area(FRICTION, tmp_path, COARSE, "gripper_friction.yaml"), accuracy=20.0)
    assert p.mesh_report["status"] == "met" and p.mesh_report["element"] in ("P1", "P2")
    assert p.plant.path_dependent


@pytest.mark.slow          # a sweep of friction paths and the control run's path replayed on each level (~15 CPU s)
def test_solve_accuracy_on_a_friction_scene_replays_the_returned_path(tmp_path):
    """``solve --accuracy`` on a friction scene (refused before): P2 levels,
    the estimate at the returned pose made along the returned path (the
    result says so, and how many waypoints it has: the run's start and its
    accepted iterates, as its ``friction_path`` records them)."""
    out = tmp_path / "r.json"
    p = subprocess.run([sys.executable, "-m", "plush_opt", "solve", str(ROOT / "tests" / "data" / "friction_strip.yaml"),
                        "--accuracy", "1", "--out", str(out)], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr and "the returned path replayed" in p.stderr
    doc = json.loads(out.read_text())
    at = doc["accuracy"]["at_result"]
    assert at["met"] is True and at["estimated_error"] <= 1.0 and at["element"] == "P2"
    assert at["path"] == f"the returned path replayed ({len(doc['friction_path']['contractions'])} waypoints)"
    assert doc["friction_path"]["from"].startswith("the control run's starting state")
    levels = doc["mesh_accuracy"]["at_result"][-1]["levels"]
    assert len(levels) >= 3 and all(lv["element"] == "P2" for lv in levels)


def test_a_friction_path_solves_its_steps_to_the_callers_tolerance(friction_problem, monkeypatch):
    """The path's inner equilibrium solves take the caller's residual
    tolerance and round-off allowance (a fine level of ``--accuracy``
    accepts a step at its round-off floor, where a 67,313-node P2 start state
    once ended the reference "not converged"); with the defaults nothing
    changes."""
    from plush_opt.solve.certificate import EquilibriumOptions
    from plush_opt.solve.friction_path import FrictionOptions
    from plush_opt.solve.friction_solve import path_options
    assert path_options(EquilibriumOptions()) == FrictionOptions()
    level = path_options(EquilibriumOptions(gtol=1e-9, roundoff=1.0)).equilibrium
    assert (level.gtol, level.roundoff, level.eigenvalue) == (1e-9, 1.0, False)
    import plush_opt.solve.friction_solve as friction_solve
    asked = []

    def recorded(fm, start, path, options=None, **kw):
        asked.append((options.equilibrium.gtol, options.equilibrium.roundoff))
        return real(fm, start, path, options, **kw)
    real = friction_solve.follow
    monkeypatch.setattr(friction_solve, "follow", recorded)
    c = friction_problem.contraction_vector({"left": 12.0, "grip": 10.0})
    eq = friction_problem.plant.fork().equilibrium(c, options=EquilibriumOptions(gtol=1e-9, roundoff=1.0))
    assert eq.converged and asked and set(asked) == {(1e-9, 1.0)}


def test_a_level_that_already_ends_the_path_is_not_replayed_again(friction_problem, monkeypatch):
    """After the levels are extended along the returned path
    (extend_along), the estimate made again at the same pose keeps their
    replayed poses instead of replaying every level a second time."""
    import plush_opt.solve.accuracy_path as accuracy_path
    from plush_opt.fem.mesh import build_mesh
    from plush_opt.solve.accuracy import Level, Resolution
    from plush_opt.solve.accuracy_path import levels_along
    p = friction_problem
    c = p.contraction_vector({"left": 6.0, "grip": 5.0})
    waypoints = np.array([0.5 * c, c])
    points = np.array([t.at for t in p.scene.targets])
    scene = p.scene.replace(element="P2")
    levels = [Level("P2", Resolution(a, 0, a), build_mesh(scene, max_area=a), 0.0, 0.0, 0, [], np.empty((0, 0, 2)))
              for a in (400.0, 200.0)]
    first = levels_along(p.scene, levels, waypoints, c, points)
    assert all(lv.along is not None and lv.poses[0] is not None for lv in first)

    def no_replay(*args, **kwargs):
        raise AssertionError("replayed again")
    monkeypatch.setattr(accuracy_path, "replay", no_replay)
    again = levels_along(p.scene, first, waypoints, c, points)
    assert [np.array_equal(a.poses[0], b.poses[0]) for a, b in zip(first, again)] == [True, True]
    with pytest.raises(AssertionError, match="replayed again"):     # another path is replayed
        levels_along(p.scene, first, waypoints[:1], 0.5 * c, points)
