"""The real planner behind scripted runs, and `plush-opt run` end to end."""

import json
import subprocess
import sys

import numpy as np
import pytest

from plush_opt.apps.planner import ControlPlanner
from shipped import ROOT


def test_planner_forward_then_pose_streams_certified_iterates_within_bounds():
    planner = ControlPlanner(ROOT / "problems" / "gripper.yaml")
    out = planner.forward({"grip": 8.0})
    assert out["converged"] and out["contraction"]["grip"] == 8.0
    iterates = list(planner.pose([{"at": [0, 150], "to": [-30, 140]}], ["grip"], max_time=10))
    assert len(iterates) >= 3
    for it in iterates:
        c = np.array([it["contraction"][n] for n in planner.winch_names])
        assert np.all(c >= planner.lower) and np.all(c <= planner.upper)
        assert it["contraction"]["grip"] == 8.0          # frozen, bit for bit
    objectives = [it["objective"] for it in iterates]
    assert objectives[-1] < 0.01 * objectives[0]
    assert iterates[-1]["converged"] and iterates[-1]["status"] != "running"


@pytest.mark.slow
def test_cli_run_dry_run_writes_a_parseable_log(tmp_path):
    log = tmp_path / "run.jsonl"
    p = subprocess.run([sys.executable, "-m", "plush_opt", "run",
                        str(ROOT / "examples" / "gripper_run.yaml"), "--dry-run", "--log", str(log)],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    assert rows[0]["kind"] == "start" and rows[-1]["status"] == "completed"
    assert {r["kind"] for r in rows} >= {"pose", "set", "hold", "release"}


@pytest.mark.slow
def test_demo_solves_and_plays_on_the_emulator(tmp_path):
    p = subprocess.run([sys.executable, "-m", "plush_opt", "demo", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    for name in ("result.json", "pose.png", "trace.png", "trace.csv", "run.jsonl", "run.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    rows = [json.loads(line) for line in (tmp_path / "run.jsonl").read_text().splitlines()]
    assert rows[-1]["status"] == "completed"
    assert any(r.get("measured") for r in rows)
    # the hexapod stands on its feet: one patch on the floor per foot
    assert "demo: contact: 2 patch(es) on the floor" in p.stdout + p.stderr
