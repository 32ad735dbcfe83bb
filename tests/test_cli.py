"""The command line: results that pass the independent spec checker, and
bad input that ends in one clear line and a non-zero exit."""

import json
import subprocess
import sys

import pytest

from shipped import ROOT
from spec_checker import check_result

GRIPPER = str(ROOT / "problems" / "gripper.yaml")


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "plush_opt", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=300)


def test_solve_with_contraction_writes_a_result_the_spec_checker_accepts(tmp_path):
    out = tmp_path / "r.json"
    p = run("solve", GRIPPER, "--contraction", "left=10", "--out", str(out))
    assert p.returncode == 0, p.stderr
    doc = check_result(out)
    assert doc["method"] == "reparam"   # the gripper has targets: control from left=10
    assert doc["converged"] is True


def test_forward_solve_result_passes_the_spec_checker(tmp_path):
    out = tmp_path / "r.json"
    png = tmp_path / "r.png"
    p = run("solve", GRIPPER, "--method", "forward", "--contraction", "left=10", "--out", str(out),
            "--plot", str(png))
    assert p.returncode == 0, p.stderr
    doc = check_result(out)
    assert doc["method"] == "forward" and doc["contractions"] == {"left": 10.0, "right": 0.0, "grip": 0.0}
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"


def test_hexapod_leg_with_gravity_passes_the_spec_checker(tmp_path):
    out = tmp_path / "r.json"
    p = run("solve", str(ROOT / "problems" / "hexapod_leg.yaml"), "--method", "forward",
            "-c", "leg=8", "--out", str(out))
    assert p.returncode == 0, p.stderr
    doc = check_result(out)
    assert doc["model"]["gravity"] == [0.0, -9810.0]


def test_trace_is_written_for_control(tmp_path):
    trace = tmp_path / "t.csv"
    p = run("solve", GRIPPER, "--trace", str(trace), "--max-iterations", "3")
    assert p.returncode in (0, 3), p.stderr
    lines = trace.read_text().splitlines()
    assert lines[0].startswith("iteration,t_wall_s,objective")
    assert 2 <= len(lines) <= 5


@pytest.mark.parametrize("limit, status", [
    (["--max-iterations", "3"], "iteration limit (3) reached"),
    (["--max-time", "0.001"], "time limit (0.001 s) reached"),
])
def test_bilevel_respects_the_limits_and_writes_its_certified_trace(tmp_path, limit, status):
    out, trace = tmp_path / "r.json", tmp_path / "t.csv"
    p = run("solve", GRIPPER, "--method", "bilevel", *limit, "--out", str(out), "--trace", str(trace))
    assert p.returncode == 3, p.stderr           # not converged: an honest stop, not a failure
    doc = check_result(out)
    assert doc["converged"] is False and status in doc["status"], doc["status"]
    assert doc["reason"] == ("max_iterations" if "iteration" in status else "max_time")
    lines = trace.read_text().splitlines()
    assert lines[0].startswith("iteration,t_wall_s,objective")
    assert 2 <= len(lines) <= 5                  # the start and at most 3 IPOPT iterates


@pytest.mark.parametrize("args, message", [
    (["--contraction", "left=100"], "left=100: outside the winch's bounds"),
    (["--contraction", "middle=1"], "no winch named 'middle'"),
    (["--contraction", "left"], "expected NAME=VALUE"),
    (["--contraction", "left=abc"], "is not a number"),
    (["--freeze", "middle"], "no winch named 'middle'"),
])
def test_bad_options_exit_2_with_one_line(tmp_path, args, message):
    out = tmp_path / "r.json"
    p = run("solve", GRIPPER, *args, "--out", str(out))
    assert p.returncode == 2
    assert message in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr
    assert not out.exists()


def test_bad_problem_file_exit_2_names_file_key_and_index(tmp_path):
    bad = tmp_path / "broken.yaml"
    text = (ROOT / "problems" / "gripper.yaml").read_text().replace(
        "path: [[16, 140]", "path: [[16, 400]")
    bad.write_text(text)
    out = tmp_path / "r.json"
    p = run("solve", str(bad), "--out", str(out))
    assert p.returncode == 2
    assert "broken.yaml" in p.stderr and "tendons.list[1].path[0]" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr
    assert not out.exists()


def test_missing_file_exit_2():
    p = run("solve", "no-such-problem.yaml")
    assert p.returncode == 2 and "no-such-problem.yaml" in p.stderr and "Traceback" not in p.stderr


def test_result_json_is_strict_json(tmp_path):
    out = tmp_path / "r.json"
    assert run("solve", GRIPPER, "--method", "forward", "--out", str(out)).returncode == 0
    json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))


def test_accuracy_picks_a_mesh_and_says_which(tmp_path):
    out = tmp_path / "r.json"
    p = run("solve", str(ROOT / "problems" / "hexapod_leg.yaml"), "--accuracy", "5", "--out", str(out))
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert "mesh_accuracy" in doc and doc["mesh_accuracy"]["summary"] in p.stderr
    assert len(doc["nodes"]) == len(doc["model"]["rest_nodes"])


def test_compare_is_wired(tmp_path):
    p = run("compare", "--help")
    assert p.returncode == 0 and "--coarse" in p.stdout
