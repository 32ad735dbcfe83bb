"""Faults and hostile inputs: the promises of docs/robustness.md, one test
(or a few) per promise. Signals during a run are in
tests/board/test_board_signals.py; invalid problem files in
problems/hard/invalid/ (run by tests/hard/test_hard_files.py).
"""

from __future__ import annotations

import errno
import json
import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cli_helpers import cli, one_error_line
from plush_opt.base.errors import SceneError

ROOT = Path(__file__).resolve().parents[1]
FINGER = ROOT / "problems" / "hard" / "invalid" / "huge_coordinate.yaml"


def finger(tmp_path: Path, name="finger.yaml", **replace) -> Path:
    """The finger of problems/hard/ with a reachable target; ``replace``
    substitutes text (old=new given as pairs in a dict)."""
    text = FINGER.read_text().replace("to: [1.0e300, 20]", "to: [55, 20]")
    for old, new in replace.get("pairs", ()):
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text)
    return path


# 1. the mesh cap holds for the real mesh -------------------------------------

def test_mesh_cap_is_checked_on_the_real_mesh(monkeypatch):
    """area / max_area under the cap, the real mesh over it: refused (here by
    the real count, the trial prediction switched off)."""
    from plush_opt.fem import mesh as mesh_mod
    from plush_opt.base.errors import SceneError
    from plush_opt.io.problem_file import load_scene
    from plush_opt.io.scene import Scene  # noqa: F401  (the scene type build_mesh takes)
    scene = load_scene(ROOT / "problems" / "gripper.yaml")
    body = 40 * 120 + 160 * 30
    cap = int(1.2 * body / scene.max_area)      # over area / max_area, under the real count
    monkeypatch.setattr(mesh_mod, "MAX_ELEMS", cap)
    monkeypatch.setattr(mesh_mod, "TRIAL_MARGIN", 1e9)
    with pytest.raises(SceneError, match=rf"mesh.max_area: 25 gives \d+ triangles \(limit {cap}\)"):
        mesh_mod.build_mesh(scene)
    monkeypatch.setattr(mesh_mod, "TRIAL_MARGIN", 1.1)
    with pytest.raises(SceneError, match=rf"would give about .* triangles \(limit {cap}\)"):
        mesh_mod.build_mesh(scene)


@pytest.mark.slow
def test_a_mesh_far_over_the_cap_is_refused_in_seconds(monkeypatch):
    import triangle
    from plush_opt.fem import mesh as mesh_mod
    from plush_opt.problem import load
    path = ROOT / "problems" / "hard" / "invalid" / "mesh_over_cap.yaml"
    p = cli("solve", path)
    assert "would give about" in one_error_line(p)
    # refused on the trial mesh, never making the real one: loaded as the
    # command loads it, the one mesh made is TRIAL_COARSENING times coarser
    made = []
    triangulate = triangle.triangulate
    monkeypatch.setattr(triangle, "triangulate",
                        lambda *args: made.append(len((out := triangulate(*args))["triangles"])) or out)
    with pytest.raises(SceneError, match="would give about"):
        load(path)
    assert len(made) == 1 and made[0] < 2 * mesh_mod.MAX_ELEMS / mesh_mod.TRIAL_COARSENING, made


# 3. a run script is checked whole before the first command -------------------

@pytest.mark.slow
def test_a_pose_target_off_the_body_is_refused_before_any_step(tmp_path):
    script = tmp_path / "run.yaml"
    script.write_text(yaml.safe_dump({
        "format": "plush-opt-run/1", "problem": str(ROOT / "problems" / "gripper.yaml"),
        "board": str(ROOT / "hw" / "boards" / "gripper.yaml"), "rate": 20,
        "steps": [{"set": {"grip": 5.0}}, {"hold": 0.1},
                  {"pose": {"targets": [{"at": [500, 500], "to": [0, 0]}], "max_time": 1}}]}))
    log = tmp_path / "run.jsonl"
    p = cli("run", script, "--dry-run", "--log", log, timeout=300)
    line = one_error_line(p)
    assert re.search(rf"{re.escape(str(script))}: steps\[2\]\.pose: targets\[0\]\.at: point .* "
                     "lies outside the body", line), line
    assert not log.exists()          # nothing ran, nothing was logged


# 4. run scripts go through the one hardened reader ---------------------------

@pytest.mark.slow
@pytest.mark.parametrize("text, pattern", [
    ("steps: &s [release]\nsteps2: *s\n", r"anchor &s \(anchors and aliases are not allowed\)"),
    ("rate: 20\nrate: 30\n", r"duplicate key"),
    (b"format: plush-opt-run/1\nname: \xff\xfe\n", r"not UTF-8 text"),
    ("format: plush-opt-run/1\x00\n", r"NUL byte"),
])
def test_hostile_run_scripts_are_one_line_errors(tmp_path, text, pattern):
    path = tmp_path / "run.yaml"
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    p = cli("run", path, "--dry-run")
    assert re.search(pattern, one_error_line(p)), p.stderr


def test_exponent_numbers_are_numbers_in_run_scripts(tmp_path):
    from plush_opt.io.run_script import load_run_script
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump({
        "format": "plush-opt-run/1", "problem": str(ROOT / "problems" / "gripper.yaml"),
        "board": str(ROOT / "hw" / "boards" / "gripper.yaml"), "rate": 20,
        "steps": [{"set": {"grip": 5.0}}]}).replace("rate: 20", "rate: 1e1"))
    assert load_run_script(path).rate == 10.0


# 5. exit 3 writes the result -------------------------------------------------

@pytest.mark.slow
def test_control_that_cannot_start_still_writes_its_result(tmp_path):
    problem = finger(tmp_path, pairs=[("poisson_ratio: 0.3", "poisson_ratio: 0.49999")])
    out = tmp_path / "out.json"
    p = cli("solve", problem, "--out", out)
    assert p.returncode == 3, p.stderr
    doc = json.loads(out.read_text())
    assert doc["converged"] is False and doc["status"] == "start_not_certified"
    assert "not certified" in doc["reason"]


# 6. output paths are checked before any work --------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("option, bad, pattern", [
    ("--plot", "/proc/no/such/pose.png", r"--plot /proc/no/such/pose\.png: cannot write in /proc"),
    ("--trace", "{tmp}", r"--trace {tmp}: is a directory"),
    ("--out", "{tmp}/file.json/below.json", r"--out {tmp}/file\.json/below\.json: .* is not a folder"),
])
def test_a_bad_output_path_is_refused_before_the_solve(tmp_path, option, bad, pattern):
    problem = finger(tmp_path)
    (tmp_path / "file.json").write_text("{}")
    out = tmp_path / "out.json"
    bad = bad.format(tmp=tmp_path)
    args = ["--out", out] if option != "--out" else []
    p = cli("solve", problem, *args, option, bad)
    line = one_error_line(p)
    assert re.search(pattern.format(tmp=re.escape(str(tmp_path))), line), line
    assert not out.exists()
    assert p.stdout == ""            # no solve ran


@pytest.mark.slow
def test_trace_of_a_forward_solve_is_refused_before_it(tmp_path):
    out = tmp_path / "out.json"
    p = cli("solve", finger(tmp_path), "--method", "forward", "--out", out, "--trace", tmp_path / "t.csv")
    assert "--trace: only a control run" in one_error_line(p)
    assert not out.exists()


@pytest.mark.slow
def test_plot_creates_its_folder_and_files_respect_the_umask(tmp_path):
    from plush_opt.base.files import write_json_atomic
    p = cli("solve", finger(tmp_path), "--method", "forward", "--plot", tmp_path / "a" / "b" / "pose.png")
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "a" / "b" / "pose.png").stat().st_size > 0
    old = os.umask(0o022)
    try:
        path = write_json_atomic(tmp_path / "r.json", {"a": 1})
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


@pytest.mark.slow
def test_run_log_path_is_checked_before_the_planner(tmp_path):
    from plush_opt.apps.cli import build_parser
    from plush_opt.apps.run_command import cli_run
    args = ("run", ROOT / "examples" / "gripper_run.yaml", "--dry-run", "--log", tmp_path)
    p = cli(*args)
    assert re.search(r"--log .*: is a directory", one_error_line(p))
    # the command's own steps, in order: the planner (its first solve is slow) is never made
    planners = []
    with pytest.raises(SceneError, match=r"--log .*: is a directory"):
        cli_run(build_parser().parse_args(list(map(str, args))), planners.append)
    assert planners == []


@pytest.mark.slow
def test_bench_out_folder_is_checked_first(tmp_path):
    (tmp_path / "f").write_text("")
    p = cli("bench", "--out", tmp_path / "f" / "bench")
    assert re.search(r"--out .*f/bench: .*f is not a folder", one_error_line(p))


# 7. a full disk: no partial line, no partial result, the file named -----------

def _enospc_after(budget):
    """An os.write that writes ``budget`` bytes in all, then fails with ENOSPC."""
    real = os.write
    left = [budget]

    def write(fd, data):
        if left[0] <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = real(fd, bytes(data[:left[0]]))
        left[0] -= n
        return n
    return write


def test_run_log_on_a_full_disk_keeps_only_complete_lines(tmp_path, monkeypatch):
    from plush_opt.apps import run_log
    path = tmp_path / "run.jsonl"
    log = run_log.RunLog(path)
    log.write({"t": 0, "event": "start"})
    monkeypatch.setattr(run_log.os, "write", _enospc_after(10))
    with pytest.raises(OSError) as info:
        log.write({"t": 1, "event": "command", "commanded": {"a": 1.0}})
    assert info.value.filename == str(path) and info.value.errno == errno.ENOSPC
    monkeypatch.undo()
    log.write({"t": 2, "kind": "end", "status": "error"})
    log.close()
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert [r["t"] for r in rows] == [0, 2]


def test_result_on_a_full_disk_names_the_file_and_leaves_nothing(tmp_path, monkeypatch):
    from plush_opt.base import files as results
    out = tmp_path / "out.json"

    def fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(results.os, "fsync", fsync)
    with pytest.raises(OSError) as info:
        results.write_json_atomic(out, {"a": 1})
    assert info.value.filename == str(out) and "No space left" in info.value.strerror
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs (root only; skipped elsewhere)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)],
                                           capture_output=True).returncode != 0:
        pytest.skip("needs root and tmpfs to make a small disk")
    yield mnt
    subprocess.run(["umount", str(mnt)], check=False)


@pytest.mark.slow
def test_a_real_full_disk(tiny_disk, tmp_path):
    """Fill the disk, then solve with --out and run with --log on it."""
    filler = tiny_disk / "filler"
    with open(filler, "wb", buffering=0) as fh:     # every block taken, however small the log
        try:
            while True:
                fh.write(b"x" * 512)
        except OSError:
            pass
    out = tiny_disk / "out.json"
    p = cli("solve", finger(tmp_path), "--method", "forward", "--out", out)
    line = one_error_line(p)
    assert f"{out}: cannot write: No space left on device" in line, line
    assert sorted(x.name for x in tiny_disk.iterdir()) == ["filler"]
    plot = tiny_disk / "pose.png"
    p = cli("solve", finger(tmp_path), "--method", "forward", "--plot", plot)
    assert f"{plot}: cannot write" in one_error_line(p)
    assert sorted(x.name for x in tiny_disk.iterdir()) == ["filler"]
    log = tiny_disk / "run.jsonl"
    p = cli("run", ROOT / "examples" / "gripper_run.yaml", "--dry-run", "--log", log, timeout=600)
    assert p.returncode == 2 and f"{log}: cannot write the run log" in p.stderr, p.stderr
    for row in log.read_text().splitlines():
        json.loads(row)


# 8. a FIFO never blocks ------------------------------------------------------

@pytest.mark.slow
def test_a_fifo_as_problem_file_or_run_script_is_refused(tmp_path):
    fifo = tmp_path / "problem.yaml"
    os.mkfifo(fifo)
    assert "not a regular file" in one_error_line(cli("solve", fifo, timeout=30))
    assert "not a regular file" in one_error_line(cli("run", fifo, "--dry-run", timeout=30))


# 9. huge values --------------------------------------------------------------

@pytest.mark.slow
def test_a_huge_contraction_is_refused_by_the_bounds(tmp_path):
    p = cli("solve", finger(tmp_path), "-c", "curl=1e300", "--out", tmp_path / "o.json")
    assert "outside" in one_error_line(p) and not (tmp_path / "o.json").exists()


def test_summary_of_a_non_finite_residual_is_no_crash():
    from plush_opt.apps.console import _number
    assert _number(None, ".3g") == "n/a" and _number(1.5, ".3g") == "1.5"


# 10. the kernel cache heals itself --------------------------------------------

def _kernel():
    import casadi as ca
    x = ca.SX.sym("x", 3)
    return ca.Function("fault_test_kernel", [x], [ca.sin(x) * ca.sumsqr(x)], ["x"], ["y"])


@pytest.mark.parametrize("damage", ["empty", "garbage", "no_checksum"])
def test_a_broken_cache_entry_is_rebuilt(tmp_path, monkeypatch, damage):
    from plush_opt.base import kernels
    monkeypatch.setenv("PLUSH_OPT_CACHE", str(tmp_path))
    monkeypatch.setenv("PLUSH_OPT_COMPILE", "1")
    if kernels._compiler() is None:
        pytest.skip("no C compiler")
    fn = _kernel()
    kernels.compiled(fn)
    (so,) = tmp_path.glob("fault_test_kernel-*.so")
    if damage == "empty":
        so.write_bytes(b"")
    elif damage == "garbage":
        so.write_bytes(np.random.default_rng(1).bytes(so.stat().st_size))
    else:
        so.with_name(so.name + ".sha256").unlink()
    ext = kernels.compiled(fn)
    assert ext.class_name() != "SXFunction"       # compiled again, not the fallback
    x = [0.3, -0.2, 1.1]
    assert np.allclose(np.asarray(ext(x)), np.asarray(fn(x)))


_COMPILE_ONE = """
import logging, sys, casadi as ca
logging.basicConfig(level=logging.INFO, format="%(message)s")
from plush_opt.base import kernels
x = ca.SX.sym("x", 3)
kernels.compiled(ca.Function("fault_test_parallel", [x], [ca.cos(x) * ca.sumsqr(x)], ["x"], ["y"]))
"""


@pytest.mark.slow
def test_parallel_cold_starts_compile_a_kernel_once(tmp_path):
    env = {**os.environ, "PLUSH_OPT_CACHE": str(tmp_path), "PLUSH_OPT_COMPILE": "1"}
    procs = [subprocess.Popen([sys.executable, "-c", _COMPILE_ONE], env=env, stderr=subprocess.PIPE, text=True)
             for _ in range(4)]
    logs = [p.communicate(timeout=300)[1] for p in procs]
    assert all(p.returncode == 0 for p in procs), logs
    assert sum(text.count("compiled kernel") for text in logs) == 1, logs


# 12. relative stopping floor --------------------------------------------------

@pytest.mark.slow
def test_a_tiny_weight_does_not_make_a_far_target_reached(tmp_path):
    problem = finger(tmp_path, pairs=[("    to: [55, 20]", "    to: [55, 20]\n    weight: 1.0e-20")])
    out = tmp_path / "out.json"
    p = cli("solve", problem, "--out", out)
    doc = json.loads(out.read_text())
    if "targets reached" in doc["status"]:
        assert max(doc["target_error"]) < 1e-3, doc["target_error"]
    assert p.returncode in (0, 3)


# 13. messages are one capped line ---------------------------------------------

@pytest.mark.slow
def test_control_characters_and_long_names_stay_on_one_short_line(tmp_path):
    problem = finger(tmp_path, pairs=[("name: finger", 'name: "bad\\0name\\nsecond line\\e[31m"')])
    line = one_error_line(cli("solve", problem))
    assert "\\x00" in line and "\\n" in line and "\x1b" not in line
    problem = finger(tmp_path, pairs=[("name: finger", "name: " + "x!" * 200_000)])
    line = one_error_line(cli("solve", problem))
    assert len(line) < 2500 and "characters left out" in line


def test_one_line_escapes_and_caps():
    from plush_opt.base.errors import one_line
    assert one_line("a\nb\x00c\u2028") == "a\\nb\\x00c\\u2028"
    long = one_line("y" * 400_000)
    assert len(long) < 2100 and long.startswith("yyy") and long.endswith("yyy")


# 14. smaller ones -------------------------------------------------------------

def test_a_temp_file_left_by_a_killed_writer_is_cleaned_up(tmp_path):
    from plush_opt.base.files import write_json_atomic
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    stale = tmp_path / f".out.json.{dead}.abc123.tmp.json"
    stale.write_bytes(b"")
    write_json_atomic(tmp_path / "out.json", {"a": 1})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


@pytest.mark.parametrize("value", ["10", True, None, float("nan")])
def test_the_driver_refuses_contractions_that_are_not_numbers(value):
    from plush_opt.board import load_calibration
    from plush_opt.board.limits import check_contractions
    from plush_opt.base.errors import HardwareError
    cal = load_calibration(ROOT / "hw" / "boards" / "gripper.yaml")
    allowed = {n: (0.0, 10.0) for n in cal.winch_names}
    with pytest.raises(HardwareError):
        check_contractions({cal.winch_names[0]: value}, allowed, cal)


def test_a_marked_block_is_rewritten_between_its_markers_and_a_missing_marker_is_named(tmp_path):
    from plush_opt.base.files import replace_between, rewrite_block
    doc = tmp_path / "d.md"
    doc.write_text("head\n<!-- b -->\nold\nlines\n<!-- /b -->\ntail\n")
    assert rewrite_block(doc, "<!-- b -->", "<!-- /b -->", "new") is True
    assert doc.read_text() == "head\n<!-- b -->\nnew\n<!-- /b -->\ntail\n"
    assert rewrite_block(doc, "<!-- b -->", "<!-- /b -->", "new") is False
    with pytest.raises(ValueError, match=r"d\.md: no block '<!-- c -->'"):
        rewrite_block(doc, "<!-- c -->", "<!-- /c -->", "x")
    with pytest.raises(ValueError, match="here: no block"):
        replace_between("<!-- b --> without its end", "<!-- b -->", "<!-- /b -->", "x", "here")


def test_a_marked_blocks_body_reads_back_as_it_was_written():
    from plush_opt.base.files import read_between, replace_between
    for body in ("one line", "\nwith blank lines around\n", ""):
        assert read_between(replace_between("a <b> x </b> z", "<b>", "</b>", body), "<b>", "</b>") == body
    assert read_between("<b> without its end", "<b>", "</b>") is None
