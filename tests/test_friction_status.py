"""A control run with friction at via points that cannot go further says
why (issue 35): the shipped gripper_friction.yaml stops at a certified pose
about 1 mm from its targets where no trial step lowers O, and its status
names the friction, not a failed line search."""

import json

from cli_helpers import cli
from shipped import ROOT


def test_gripper_friction_says_it_stalled_on_friction(tmp_path):
    out = tmp_path / "r.json"
    p = cli("solve", ROOT / "problems" / "gripper_friction.yaml", "--out", out)
    assert p.returncode == 3, p.stderr              # not converged: never claimed
    assert "Traceback" not in p.stderr
    doc = json.loads(out.read_text())
    assert doc["converged"] is False and doc["reason"] == "no_decrease"
    assert doc["status"].startswith("stalled: no trial step lowered O (friction at via points")
    assert "best certified iterate, not a proven optimum" in doc["status"]
    assert "line search failed" not in doc["status"]
    assert p.stderr.strip().splitlines() == [f"plush-opt: not converged: {doc['status']}"]
    assert doc["residual_norm"] is not None and doc["residual_norm"] < 1e-8    # a certified equilibrium
    assert max(doc["target_error"]) < 1.5 and doc["objective"] < 1.5        # about 1 mm from the targets


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
