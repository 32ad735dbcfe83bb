"""Scripted runs with the real planner: the shipped run sends the same
commands every time, one per pose step (its final certified pose)."""

import json

import pytest

from plush_opt.apps.planner import ControlPlanner
from plush_opt.apps.runs import run_script
from plush_opt.base.errors import SolverError
from plush_opt.io.run_script import load_run_script
from shipped import ROOT


def _log(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_the_shipped_run_sends_the_same_commands_every_time(tmp_path):
    script = load_run_script(ROOT / "examples" / "gripper_run.yaml")
    logs = []
    for k in (1, 2):
        run_script(script, dry_run=True, planner=ControlPlanner(script.problem), log_path=tmp_path / f"{k}.jsonl")
        logs.append(_log(tmp_path / f"{k}.jsonl"))
    commands = [[(r["step"], r["kind"], r["commanded"], r["ticks"]) for r in log if r["event"] == "command"]
                for log in logs]
    assert commands[0] == commands[1]
    # a dry run's log is a plan: its times too are the same every time
    assert [r["t"] for r in logs[0]] == [r["t"] for r in logs[1]]
    # one command per set, pose and release step; a pose's is its final pose, certified and converged
    moving = [i for i, s in enumerate(script.steps) if s.kind != "hold"]
    assert [c[0] for c in commands[0]] == moving
    poses = [r for r in logs[0] if r["event"] == "command" and r["kind"] == "pose"]
    assert all(r["converged"] for r in poses)


def test_the_planner_marks_every_result_certified_and_says_when_time_cut_it():
    planner = ControlPlanner(ROOT / "problems" / "gripper.yaml")
    results = list(planner.pose([{"at": [0, 150], "to": [-30, 140]}], ["grip"], max_time=60))
    assert len(results) >= 3 and all(r["certified"] is True for r in results)
    assert results[-1]["time_limited"] is False
    cut = list(planner.pose([{"at": [0, 150], "to": [30, 140]}], ["grip"], max_time=1e-9))
    assert cut[-1]["time_limited"] is True and cut[-1]["certified"] is True


def test_a_pose_step_cut_by_max_time_is_an_error(tmp_path):
    script = tmp_path / "run.yaml"
    script.write_text(f"format: plush-opt-run/1\nproblem: {ROOT / 'problems' / 'gripper.yaml'}\n"
                      f"board: {ROOT / 'hw' / 'boards' / 'gripper.yaml'}\nrate: 20\n"
                      "steps:\n  - pose: {targets: [{at: [0, 150], to: [-30, 140]}], max_time: 1.0e-9}\n")
    with pytest.raises(SolverError, match=r"steps\[0\]\.pose: the planner stopped at max_time \(1e-09 s\)"):
        run_script(script, dry_run=True, planner=ControlPlanner(ROOT / "problems" / "gripper.yaml"),
                   log_path=tmp_path / "log.jsonl")
    assert not [r for r in _log(tmp_path / "log.jsonl") if r["event"] == "command"]
