"""Long commands show progress on stderr by default (a line per item when
stderr is not a terminal) and nothing with -q: sweep and compare."""

import re

import pytest

from cli_helpers import cli
from shipped import ROOT


def test_a_sweep_prints_a_line_per_step_on_stderr(tmp_path):
    p = cli("sweep", ROOT / "problems" / "gripper.yaml", "--winch", "left", "--to", "2", "--back", "0",
            "--steps", "2", "--out", tmp_path / "s.csv")
    assert p.returncode == 0, p.stderr
    lines = p.stderr.splitlines()
    assert [re.sub(r" \(\d+\.\d\d s\)$", "", line) for line in lines] == [
        "sweep: 4 steps of winch left from the start state",
        "sweep: [1/4] left 1 mm: converged", "sweep: [2/4] left 2 mm: converged",
        "sweep: [3/4] left 1 mm: converged", "sweep: [4/4] left 0 mm: converged"]
    assert all(re.search(r" \(\d+\.\d\d s\)$", line) for line in lines[1:])
    assert p.stdout.startswith("sweep: 4 of 4 steps, converged")


@pytest.mark.parametrize("where", ["before", "after"])
def test_a_quiet_sweep_prints_nothing(tmp_path, where):
    args = ["sweep", ROOT / "problems" / "gripper.yaml", "--winch", "left", "--to", "2", "--steps", "2",
            "--out", tmp_path / "s.csv"]
    p = cli("-q", *args) if where == "before" else cli(*args, "-q")
    assert p.returncode == 0, p.stderr
    assert p.stderr == "" and p.stdout == ""
    assert len((tmp_path / "s.csv").read_text().splitlines()) == 1 + 3


@pytest.mark.slow
def test_compare_prints_progress_by_default_and_nothing_with_q(tmp_path):
    problem = ROOT / "problems" / "compare" / "finger_near_zero.yaml"
    p = cli("compare", problem, "--coarse", "--jobs", "1", "--out", tmp_path / "a", timeout=600)
    assert p.returncode == 0, p.stderr
    lines = p.stderr.splitlines()
    assert lines[0] == "compare: 1 problem(s), 3 level(s)"
    # a line per finished level and per reference, as each ends
    assert [line for line in lines if line.startswith("compare: levels: [")] == [
        line for line in lines if re.fullmatch(r"compare: levels: \[\d/3\] finger_near_zero\.yaml P1 x\d+: "
                                               r"ok \(\d+\.\d s\)", line)]
    assert sum(line.startswith("compare: levels: [") for line in lines) == 3
    assert any(re.match(r"compare: references: \[1/\d+\] finger_near_zero\.yaml: ok", line) for line in lines)
    q = cli("-q", "compare", problem, "--coarse", "--jobs", "1", "--out", tmp_path / "b", timeout=600)
    assert q.returncode == 0, q.stderr
    assert q.stderr == ""
    assert (tmp_path / "b" / "report.md").is_file()
