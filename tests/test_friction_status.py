"""A control run with friction at via points says honestly where it ended
(issue 35): the shipped gripper_friction.yaml stopped "stalled" (exit 3)
about 1 mm from its targets; it now ends at a nonsmooth stationary point
it has tested (tests/test_control_friction.py has the loop's pieces, and
the stalled status of a loop without that test)."""

import json

import pytest

from cli_helpers import cli
from shipped import ROOT


def test_gripper_friction_ends_stationary_at_the_kink_and_says_so(tmp_path):
    out = tmp_path / "r.json"
    p = cli("solve", ROOT / "problems" / "gripper_friction.yaml", "--out", out)
    assert p.returncode == 0, p.stderr              # converged, and the status says what was verified
    assert "Traceback" not in p.stderr
    doc = json.loads(out.read_text())
    assert doc["converged"] is True and doc["reason"] == "stationary"
    assert "at the kink (friction at via points) no move of any single winch" in doc["status"]
    assert "line search failed" not in doc["status"] and not doc["status"].startswith("stalled")
    assert p.stderr.strip() == ""
    assert doc["residual_norm"] is not None and doc["residual_norm"] < 1e-8    # a certified equilibrium
    assert max(doc["target_error"]) < 1.0 and doc["objective"] < 1.5        # about 1 mm from the targets
    assert doc["objective"] < 0.7775          # clip's O here before (reparam's 1.394): reparam ends as low
    assert doc["contractions"]["right"] == 0.0          # on its bound, not held 0.067 inside it


def test_a_forward_solve_along_a_friction_path_counts_its_newton_iterations(tmp_path):
    """The path's steps are Newton solves too: ``timing.iterations`` counts
    them (it said 0 after following 10 steps)."""
    out = tmp_path / "r.json"
    p = cli("solve", ROOT / "problems" / "gripper_friction.yaml", "--method", "forward", "-c", "grip=10",
            "--out", out)
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert doc["friction_path"]["steps_done"] == 10
    assert doc["timing"]["iterations"] >= doc["friction_path"]["steps_done"] // 2 > 0
    assert doc["equilibrium"]["newton_iterations"] == doc["timing"]["iterations"]


def test_a_winch_at_an_interior_optimum_is_not_called_held_by_its_bound():
    """The gripper's optimum has the winch `right` 0.24 mm inside [0, 25]
    with a zero gradient (clip, which holds nothing inside a bound, ends at
    the same contractions): reparam no longer says "bound active: right"."""
    import re
    reparam = cli("solve", ROOT / "problems" / "gripper.yaml")
    clip = cli("solve", ROOT / "problems" / "gripper.yaml", "--method", "clip")
    assert reparam.returncode == 0 and clip.returncode == 0, reparam.stderr + clip.stderr
    assert "bound active" not in reparam.stdout and "bound active" not in clip.stdout, reparam.stdout
    right = [float(re.search(r"right=(\S+),", p.stdout).group(1)) for p in (reparam, clip)]
    assert 0.1 < right[0] < 0.5 and abs(right[0] - right[1]) < 1e-3


def test_a_winch_held_inside_its_bound_says_how_far():
    from types import SimpleNamespace
    import numpy as np
    from plush_opt.control.gradient import _bound_note
    model = SimpleNamespace(winch_names=("a", "b", "c"), lower=np.zeros(3), upper=np.full(3, 20.0))
    last = SimpleNamespace(active_bounds=("a", "b", "c"), contraction=np.array([0.0, 0.08, 19.9]),
                           gradient=np.array([1.0, 1e-3, -1e-12]), objective=1.0)
    # a on its bound; b held 0.08 inside with a gradient that matters; c's gradient is negligible
    assert _bound_note(last, model, 1e-7) == ("; bound active: a, b (held 0.08 inside its lower bound 0 "
                                              "by the reparametrised bounds)")
    # at a stop on O's round-off, b's gradient no larger than a free winch's stopped nothing: not held
    from plush_opt.control.gradient import _unheld_gradient
    free = SimpleNamespace(active_bounds=("b",), contraction=np.array([5.0, 0.08, 19.9]),
                           gradient=np.array([2e-3, 1e-3, 0.0]), objective=1.0)
    assert _unheld_gradient(free, model) == pytest.approx(2e-3 * 20.0)
    assert _bound_note(free, model, 1e-7, _unheld_gradient(free, model)) == ""
    assert _bound_note(free, model, 1e-7) == ("; bound active: b (held 0.08 inside its lower bound 0 "
                                              "by the reparametrised bounds)")
