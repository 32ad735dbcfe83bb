"""Files the package reads back (issue 34, items 6 and 7): run logs and
result files given to ``export``, board files, measurement files. The
promise of problem files holds for them: type, range and finiteness
checked, one line naming the file, the key (and line or index), exit 2,
never a traceback, never a repair (docs/robustness.md, "Caps and
read-back files")."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
import yaml

from cli_helpers import cli, one_error_line
from plush_opt.base.errors import SceneError

ROOT = Path(__file__).resolve().parents[1]
FINGER = ROOT / "problems" / "hard" / "invalid" / "huge_coordinate.yaml"
DEEP = "[" * 100_000 + "]" * 100_000


# -- run logs given to export ---------------------------------------------

@pytest.fixture(scope="module")
def run_log(tmp_path_factory) -> list[str]:
    """The lines of a dry run's log (a set and a hold on the gripper)."""
    folder = tmp_path_factory.mktemp("log")
    script = folder / "run.yaml"
    script.write_text(yaml.safe_dump({
        "format": "plush-opt-run/1", "problem": str(ROOT / "problems" / "gripper.yaml"),
        "board": str(ROOT / "hw" / "boards" / "gripper.yaml"), "rate": 20,
        "steps": [{"set": {"grip": 4.0}}, {"hold": 0.1}]}))
    p = cli("run", script, "--dry-run", "--log", folder / "run.jsonl")
    assert p.returncode == 0, p.stderr
    return (folder / "run.jsonl").read_text().splitlines()


def _edit_line(n, **change):
    def edit(lines):
        row = json.loads(lines[n])
        for k, v in change.items():
            if v is _DROP:
                del row[k]
            else:
                row[k] = v
        lines[n] = json.dumps(row)
        return "\n".join(lines) + "\n"
    return edit


_DROP = object()


@pytest.mark.parametrize("make, pattern", [
    (lambda lines: "", r"log\.jsonl: empty: not a run log"),
    (lambda lines: "\n".join(lines[:1] + ["{not json"] + lines[1:]), r"log\.jsonl: line 2: not JSON: "),
    (lambda lines: "[1, 2, 3]\n", r"log\.jsonl: line 1: expected a JSON object .*, got a list"),
    (lambda lines: lines[0] + "\n" + lines[1].replace('"set"', '"s\udcff"') + "\n",
     r"log\.jsonl: line 2: not UTF-8 text"),
    (_edit_line(1, t="0.02"), r"log\.jsonl: line 2: t: expected a number, got string '0\.02'"),
    (_edit_line(1, t=_DROP), r"log\.jsonl: line 2: t: missing required key"),
    (_edit_line(1, event=7), r"log\.jsonl: line 2: event: expected a string, got number 7"),
    (_edit_line(1, commanded=[1, 2, 3]), r"log\.jsonl: line 2: commanded: expected a mapping, got a list of 3"),
    (lambda lines: "\n".join(lines[:1] + [DEEP] + lines[1:]), r"log\.jsonl: line 2: not JSON of plush-opt: "
     r"nested too deeply"),
    (_edit_line(1, commanded={"left": 0.0, "right": 0.0, "grip": "4"}),
     r"log\.jsonl: line 2: commanded\.grip: expected a number, got string '4'"),
    (_edit_line(1, commanded={"left": 0.0, "right": 0.0, "grip": True}),
     r"log\.jsonl: line 2: commanded\.grip: expected a number, got boolean true"),
    (_edit_line(1, commanded={"left": 0.0, "right": 0.0, "thumb": 1.0}),
     r"log\.jsonl: line 2: commanded\.thumb: unknown key"),
    (_edit_line(0, problem=None), r"log\.jsonl: line 1: problem: expected a string, got null"),
    (_edit_line(1, t=-1), r"log\.jsonl: line 2: t: must be >= 0, got -1"),
    (_edit_line(1, t=10 ** 400), r"log\.jsonl: line 2: t: expected a finite number, got number 100000000000\.\.\. "
     r"\(401 characters\)$"),
    (_edit_line(1, commanded={"left": 0.0, "right": 0.0, "grip": 1e308}),
     r"log\.jsonl: line 2: commanded: grip=1e\+308: outside the winch's bounds \[0, 20\]"),
])
def test_a_corrupt_run_log_is_one_line(tmp_path, run_log, make, pattern):
    log = tmp_path / "log.jsonl"
    text = make(list(run_log))
    log.write_bytes(text.encode("utf-8", "surrogateescape"))
    p = cli("export", log, "--out", tmp_path / "vtk")
    assert re.search(pattern, one_error_line(p)), p.stderr
    assert not (tmp_path / "vtk" / "run.pvd").exists()


def test_a_good_run_log_still_exports(tmp_path, run_log):
    log = tmp_path / "log.jsonl"
    log.write_text("\n".join(run_log) + "\n")
    p = cli("export", log, "--out", tmp_path / "vtk")
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "vtk" / "run.pvd").exists()


# -- result files given to export --result --------------------------------

@pytest.fixture(scope="module")
def finger_result(tmp_path_factory):
    """(problem file, result document) of a forward solve of the finger."""
    folder = tmp_path_factory.mktemp("result")
    problem = folder / "finger.yaml"
    problem.write_text(FINGER.read_text().replace("to: [1.0e300, 20]", "to: [55, 20]"))
    p = cli("solve", problem, "--method", "forward", "--out", folder / "r.json")
    assert p.returncode == 0, p.stderr
    return problem, json.loads((folder / "r.json").read_text())


def _set(*keys, value):
    def edit(doc):
        d = doc
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value(d[keys[-1]]) if callable(value) else value
        return json.dumps(doc)
    return edit


def _first_triangle_flat(tris):
    tris[0] = [tris[0][0], tris[0][0], tris[0][2]]
    return tris


@pytest.mark.parametrize("edit, pattern", [
    (_set("model", "triangles", value=_first_triangle_flat),
     r"r\.json: model\.triangles\[0\]: degenerate triangle"),
    (_set("model", "rest_nodes", value=lambda X: [[math.nan, X[0][1]]] + X[1:]),
     r"r\.json: model\.rest_nodes\[0\]\[0\]: expected a finite number, got nan"),
    (lambda doc: json.dumps({**doc, "model": DEEP}).replace(f'"{DEEP}"', DEEP),
     r"r\.json: not JSON of plush-opt: nested too deeply"),
    (_set("contractions", "curl", value="3"), r"r\.json: contractions\.curl: expected a number, got string '3'"),
    (_set("contractions", "curl", value=True), r"r\.json: contractions\.curl: expected a number, got boolean"),
    (_set("model", "triangles", value=lambda t: [[t[0][0] + 0.5] + t[0][1:]] + t[1:]),
     r"r\.json: model\.triangles\[0\]\[0\]: expected an integer, got number \d+\.5"),
    (_set("nodes", value=lambda x: [[math.nan, 0.0]] + x[1:]), r"r\.json: nodes\[0\]\[0\]: expected a finite number"),
    (_set("nodes", value=lambda x: [[math.inf, 0.0]] + x[1:]), r"r\.json: nodes\[0\]\[0\]: expected a finite number"),
    (_set("nodes", value=lambda x: [[None, 0.0]] + x[1:]), r"r\.json: nodes\[0\]\[0\]: expected a number, got null"),
    (_set("nodes", value=lambda x: x[1:]), r"r\.json: nodes: \d+ points, but model\.rest_nodes has \d+"),
    (lambda doc: "[]", r"r\.json: expected a JSON object .*, got a list of 0"),
    (_set("model", "tendons", "list", value=[3]), r"r\.json: model\.tendons\.list\[0\]: expected a mapping"),
])
def test_a_tampered_result_is_one_line(tmp_path, finger_result, edit, pattern):
    problem, doc = finger_result
    result = tmp_path / "r.json"
    result.write_text(edit(json.loads(json.dumps(doc))))
    p = cli("export", problem, "--result", result, "--out", tmp_path / "vtk")
    assert re.search(pattern, one_error_line(p)), p.stderr
    assert not (tmp_path / "vtk" / "pose.vtu").exists()


def test_a_good_result_still_exports(tmp_path, finger_result):
    problem, doc = finger_result
    result = tmp_path / "r.json"
    result.write_text(json.dumps(doc))
    p = cli("export", problem, "--result", result, "--out", tmp_path / "vtk")
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "vtk" / "pose.vtu").exists()


# -- board files, run scripts -----------------------------------------------

def _board(tmp_path, port=None, **winch):
    data = yaml.safe_load((ROOT / "hw" / "boards" / "gripper.yaml").read_text())
    data["winches"][0].update(winch)
    data.setdefault("port", {}).update(port or {})
    board = tmp_path / "board.yaml"
    board.write_text(yaml.safe_dump(data))
    script = tmp_path / "run.yaml"
    script.write_text(yaml.safe_dump({
        "format": "plush-opt-run/1", "problem": str(ROOT / "problems" / "gripper.yaml"),
        "board": str(board), "rate": 20, "steps": [{"set": {"grip": 4.0}}]}))
    return script


@pytest.mark.parametrize("port, winch, pattern", [
    ({}, {"max_speed": 1e308}, r"winches\[0\]\.max_speed: 1e\+308 is .* ticks/s; the board moves at 1\.\.1000000"),
    ({}, {"max_speed": 1e6}, r"winches\[0\]\.max_speed: 1e\+06 is .* ticks/s; the board moves at 1\.\.1000000"),
    ({}, {"max_speed": 1e-300}, r"winches\[0\]\.max_speed: 1e-300 is 3\.18e-299 ticks/s; the board moves"),
    ({}, {"spool_radius": 5e-324}, r"winches\[0\]\.spool_radius: 4\.94066e-324 gives inf ticks per length unit"),
    ({}, {"spool_radius": 1e308}, r"winches\[0\]\.spool_radius: 1e\+308 gives 0 ticks per length unit"),
    ({}, {"limits": [0, 1e308]}, r"winches\[0\]\.limits\[1\]: 1e\+308 is too large"),
    ({}, {"tolerance": 1e308}, r"winches\[0\]\.tolerance: must be <= the span of the limits \(25\), got 1e\+308"),
    ({}, {"ticks_per_rev": 1e308}, r"winches\[0\]\.ticks_per_rev: must be <= 1e\+09 ticks, got 1e\+308"),
    ({}, {"gear_ratio": 1e308}, r"winches\[0\]\.gear_ratio: must be <= 1e\+06, got 1e\+308"),
    ({"boot_time": 1e308}, {}, r"port\.boot_time: must be <= 60 s, got 1e\+308"),
    ({"timeout": 1e308}, {}, r"port\.timeout: must be <= 60 s, got 1e\+308"),
    ({"baudrate": 10 ** 30}, {}, r"port\.baudrate: must be in 1\.\.12000000, got 1e\+30"),
])
def test_board_file_values_beyond_the_board(tmp_path, port, winch, pattern):
    p = cli("run", _board(tmp_path, port, **winch), "--dry-run", "--log", tmp_path / "log.jsonl")
    line = one_error_line(p)
    assert re.search(r"board\.yaml: " + pattern, line), line


# -- measurement files ----------------------------------------------------------

def _measurements(tmp_path, replace):
    text = (ROOT / "examples" / "hexapod_leg_measurements.yaml").read_text()
    text = text.replace("problem: ../problems/", f"problem: {ROOT / 'problems'}/")
    assert replace[0] in text
    path = tmp_path / "m.yaml"
    path.write_text(text.replace(replace[0], replace[1], 1))
    return path


@pytest.mark.parametrize("replace, pattern", [
    (("  - [49.74, -2.45]", "  - [1.0e11, -2.45]"),
     r"m\.yaml: poses\[0\]\.positions\[9\]: point \(100000000000\.0, -2\.45\) is more than 10 body "
     r"diameters \(1016\)"),
    (("sigma: 0.3", "sigma: 1.0e-300"), r"m\.yaml: sigma: 1e-300 is below 1e-09 of the body's diameter"),
])
def test_measurement_values_beyond_the_fit(tmp_path, replace, pattern):
    p = cli("calibrate", _measurements(tmp_path, replace), "--out", tmp_path / "fit.yaml", timeout=300)
    assert re.search(pattern, one_error_line(p)), p.stderr


# -- writers -------------------------------------------------------------------------

def test_a_non_finite_value_in_a_result_names_its_key(tmp_path):
    from plush_opt.base.files import write_json_atomic
    with pytest.raises(SceneError, match=r"r\.json: model\.tendons\[1\]\.x: inf is not a finite number"):
        write_json_atomic(tmp_path / "r.json", {"model": {"tendons": [{"x": 1.0}, {"x": math.inf}]}})
    assert list(tmp_path.iterdir()) == []


def test_a_stale_temp_with_an_impossible_pid_is_removed(tmp_path):
    from plush_opt.base.files import write_json_atomic
    stale = tmp_path / f".r.json.{'9' * 20}.tmp"
    stale.write_bytes(b"")
    write_json_atomic(tmp_path / "r.json", {"a": 1})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]


def _cantilever_result(tmp_path):
    from plush_opt.problem import load
    p = load(ROOT / "problems" / "cantilever.yaml")
    out = tmp_path / "r.json"
    assert cli("solve", ROOT / "problems" / "cantilever.yaml", "--out", out).returncode == 0
    return p, json.loads(out.read_text())


def test_a_result_of_another_mesh_says_what_differs(tmp_path):
    """Rest nodes that are not the problem's mesh: the message says how (the
    counts when they differ, else how far and how many nodes are elsewhere),
    never two equal counts as if they differed."""
    from plush_opt.apps.export import recorded_pose
    p, doc = _cantilever_result(tmp_path)
    n = p.mesh.n_nodes
    moved = json.loads(json.dumps(doc))
    moved["model"]["rest_nodes"][7][0] += 0.25
    with pytest.raises(SceneError) as err:
        recorded_pose(p, "r.json", doc=moved)
    assert re.fullmatch(rf"r\.json: model\.rest_nodes\[7\]: 0\.25 length units from node 7 of the mesh of "
                        rf"\S*cantilever\.yaml \(1 of its {n} nodes elsewhere\): a result of another problem "
                        r"file or mesh\?", str(err.value)), err.value
    fewer = json.loads(json.dumps(doc))
    fewer["model"]["rest_nodes"] = fewer["model"]["rest_nodes"][:-1]
    with pytest.raises(SceneError) as err:
        recorded_pose(p, "r.json", doc=fewer)
    assert re.fullmatch(rf"r\.json: model\.rest_nodes: {n - 1} nodes, the mesh of \S*cantilever\.yaml has {n}: "
                        r"a result of another mesh size\?", str(err.value)), err.value
