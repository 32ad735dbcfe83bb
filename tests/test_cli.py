"""The command line: results that pass the independent spec checker, and
bad input that ends in one clear line and a non-zero exit."""

import json
import subprocess
import sys

import pytest

from shipped import ROOT
from spec_checker import check_result

pytestmark = pytest.mark.slow  # each runs the command line in a new process

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
    p = run("solve", str(ROOT / "problems" / "cantilever.yaml"), "--accuracy", "0.002", "--out", str(out))
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert doc["accuracy"]["summary"] in p.stderr and doc["accuracy"]["nodes"] == len(doc["nodes"])
    assert len(doc["nodes"]) == len(doc["model"]["rest_nodes"])


def test_compare_is_wired(tmp_path):
    p = run("compare", "--help")
    assert p.returncode == 0 and "--coarse" in p.stdout


# -- a new user's session: shipped files, output levels, honest summaries, pictures, viewers --

def test_examples_copies_the_shipped_files_and_never_overwrites(tmp_path):
    p = run("examples", "ex", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    for rel in ("problems/gripper.yaml", "examples/gripper_run.yaml", "hw/boards/gripper.yaml"):
        assert (tmp_path / "ex" / rel).is_file(), rel
    again = run("examples", "ex", cwd=tmp_path)
    assert again.returncode == 2 and "exists already" in again.stderr and "Traceback" not in again.stderr


def test_quiet_default_verbose_and_debug_say_more_and_more(tmp_path):
    outs = {flag: run("solve", GRIPPER, *([flag] if flag else [])) for flag in ("-q", "", "-v", "-vv")}
    for flag, p in outs.items():
        assert p.returncode == 0, (flag, p.stderr)
    assert outs["-q"].stdout == "" and outs["-q"].stderr == ""
    assert "targets RMS error" in outs[""].stdout and outs[""].stderr == ""
    assert "control (reparam)" in outs["-v"].stderr and "iterate 1" in outs["-v"].stderr
    assert "debug" not in outs["-v"].stderr
    assert "debug plush_opt" in outs["-vv"].stderr and "nodes" in outs["-vv"].stderr
    top = run("-q", "solve", GRIPPER)
    assert top.stdout == "" and top.returncode == 0
    both = run("solve", GRIPPER, "-q", "-v")
    assert both.returncode == 2 and "not allowed with" in both.stderr


def test_forward_solve_of_a_file_with_targets_says_how_far_they_are():
    p = run("solve", GRIPPER, "--method", "forward")
    assert p.returncode == 0, p.stderr
    rms = float(p.stdout.split("targets RMS error ")[1].split()[0])
    assert rms > 10, p.stdout          # the rest pose is far from the gripper's targets
    assert "targets objective" in p.stdout


def test_ipopt_print_level_reaches_ipopt():
    p = run("solve", GRIPPER, "--method", "forward", "--equilibrium", "ipopt", "--ipopt-print-level", "5")
    assert p.returncode == 0, p.stderr
    assert "Number of Iterations" in p.stdout
    silent = run("solve", GRIPPER, "--method", "forward", "--equilibrium", "ipopt")
    assert "Number of Iterations" not in silent.stdout
    bad = run("solve", GRIPPER, "--ipopt-print-level", "13")
    assert bad.returncode == 2 and "--ipopt-print-level" in bad.stderr


def test_pose_picture_with_fixed_tension_scale_and_vtk_export(tmp_path):
    meshio = pytest.importorskip("meshio")
    png, vtk = tmp_path / "pose.png", tmp_path / "vtk"
    p = run("solve", GRIPPER, "--max-iterations", "3", "--plot", str(png), "--tension-max", "5",
            "--vtk", str(vtk))
    assert p.returncode in (0, 3), p.stderr
    assert png.read_bytes()[:4] == b"\x89PNG"
    pose = meshio.read(vtk / "pose.vtu")
    assert {"triangle", "line"} <= {c.type for c in pose.cells}
    assert {"J", "tension", "tendon"} <= set(pose.cell_data) and "displacement" in pose.point_data
    J = pose.cell_data["J"][0]
    assert J.min() > 0 and abs(J.mean() - 1) < 0.5           # area ratios of a sane pose
    pvd = (vtk / "trace.pvd").read_text()
    frames = pvd.count("<DataSet")
    assert frames == 4 and all((vtk / f"trace_{k:04d}.vtu").is_file() for k in range(frames))
    bad = run("solve", GRIPPER, "--tension-max", "-1", "--plot", str(png))
    assert bad.returncode == 2 and "--tension-max" in bad.stderr


def test_run_shows_its_steps_warns_when_far_and_plots_and_exports(tmp_path):
    pytest.importorskip("meshio")
    shipped = ROOT / "examples" / "gripper_run.yaml"
    # the shipped carry step, with its second target 28 mm below where the
    # bar's end can go with the hand frozen
    text = shipped.read_text().replace("to: [-45, 123]", "to: [-45, 95]")
    text = text.replace("../problems/", f"{ROOT}/problems/").replace("../hw/", f"{ROOT}/hw/")
    assert "to: [-45, 95]" in text
    script = tmp_path / "far.yaml"
    script.write_text(text)
    log, png, vtk = tmp_path / "run.jsonl", tmp_path / "run.png", tmp_path / "vtk"
    p = run("run", str(script), "--dry-run", "--log", str(log), "--plot", str(png), "--vtk", str(vtk))
    assert p.returncode == 0, p.stderr
    assert "step 1/7 pose" in p.stderr and "step 7/7 release" in p.stderr
    # the carry step cannot reach both its targets with the hand frozen: said, not hidden
    assert "steps[3].pose ended" in p.stderr and "warning" in p.stderr
    assert "RMS target error at most" in p.stderr and "1 far from their targets" in p.stderr
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert (vtk / "run.pvd").read_text().count("<DataSet") >= 5
    quiet = run("-q", "run", str(script), "--dry-run", "--log", str(tmp_path / "q.jsonl"))
    assert "step 1/7" not in quiet.stderr
    # the shipped script itself reaches its targets: no warning
    ok = run("run", str(shipped), "--dry-run", "--log", str(tmp_path / "ok.jsonl"))
    assert ok.returncode == 0 and "warning" not in ok.stderr, ok.stderr
    again = run("export", str(log), "--out", str(tmp_path / "again"))
    assert again.returncode == 0, again.stderr
    assert (tmp_path / "again" / "run.pvd").is_file()


def test_export_a_pose_of_a_problem_file(tmp_path):
    pytest.importorskip("meshio")
    p = run("export", GRIPPER, "-c", "left=8", "--out", str(tmp_path / "e"))
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "e" / "pose.vtu").is_file()


def test_bench_without_problem_files_is_an_error(tmp_path):
    p = run("bench", str(tmp_path / "none.yaml"), "--out", str(tmp_path / "b"))
    assert p.returncode == 2 and "no such problem file" in p.stderr
    assert not (tmp_path / "b" / "bench.md").exists()
