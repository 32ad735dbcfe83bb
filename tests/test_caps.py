"""Caps that keep every input fast (issue 34, item 4; docs/robustness.md,
"Caps and read-back files"): what would hang, eat memory or overflow is
refused in one line naming the file, the key and the limit (exit 2)."""

from __future__ import annotations

import re
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import yaml

from cli_helpers import cli, one_error_line
ROOT = Path(__file__).resolve().parents[1]
FINGER = ROOT / "problems" / "hard" / "invalid" / "huge_coordinate.yaml"


def finger(tmp_path: Path, edit=None) -> Path:
    """The finger of problems/hard/ with a reachable target, its document
    changed by ``edit``."""
    data = yaml.safe_load(FINGER.read_text())
    data["targets"][0]["to"] = [55, 20]
    if edit:
        edit(data)
    path = tmp_path / "finger.yaml"
    path.write_text(yaml.safe_dump(data, default_flow_style=True, width=100))
    return path


def _many_via(n):
    def edit(data):
        xs = np.linspace(58, 2, n)
        data["tendons"]["list"][0]["path"] = [[round(float(x), 4), 2.0 + 0.5 * (k % 2)] for k, x in enumerate(xs)]
    return edit


def _set(*keys, value):
    def edit(data):
        d = data
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value
    return edit


@pytest.mark.parametrize("edit, pattern", [
    (_set("tendons", "attachment_radius", value=1e-15),
     r"finger\.yaml: tendons\.attachment_radius: 1e-15 is below 6.08e-05, 1e-06 of the body's size"),
    (_set("tendons", "list", 1, "attachment_radius", value=1e-12),
     r"finger\.yaml: tendons\.list\[1\]\.attachment_radius: 1e-12 is below"),
    (_many_via(6000), r"finger\.yaml: tendons\.list\[0\]\.path: 6000 via points; at most 1000 per tendon"),
    (_many_via(28607), r"finger\.yaml: tendons\.list\[0\]\.path: 28607 via points; at most 1000"),
    (_set("tendons", "smoothing", value=1e300), r"finger\.yaml: tendons\.smoothing: 1e\+300 is too large"),
    (_set("targets", 0, "weight", value=1e308), r"finger\.yaml: targets\[0\]\.weight: must be <= 1e\+12"),
])
def test_problem_file_caps(tmp_path, edit, pattern):
    p = cli("solve", finger(tmp_path, edit), "--out", tmp_path / "r.json", timeout=60)
    assert re.search(pattern, one_error_line(p)), p.stderr
    assert not (tmp_path / "r.json").exists()


def test_via_points_per_file(tmp_path):
    def edit(data):
        lst = data["tendons"]["list"]
        for k in range(6):
            ys = [1.0 + k, 1.5 + k]
            lst.append({"name": f"t{k}", "winch": "curl",
                        "path": [[float(x), ys[j % 2]] for j, x in enumerate(np.linspace(57, 3, 900))]})
    p = cli("solve", finger(tmp_path, edit), "--out", tmp_path / "r.json", timeout=60)
    assert re.search(r"tendons\.list\[7\]\.path: 900 via points; at most 1000 per tendon and 5000 in a file "
                     r"\(this makes 5406\)", one_error_line(p)), p.stderr


def test_tendons_per_file(tmp_path):
    def edit(data):
        data["tendons"]["list"] = [{"name": f"t{k}", "winch": "curl", "path": [[58, 2], [2, 2]]}
                                   for k in range(201)]
    p = cli("solve", finger(tmp_path, edit), "--out", tmp_path / "r.json", timeout=60)
    assert re.search(r"finger\.yaml: tendons\.list: 201 tendons; at most 200", one_error_line(p)), p.stderr


def test_a_small_radius_still_loads_and_builds(tmp_path):
    """At the floor the disc integration is quick (it used to split forever)."""
    from plush_opt.problem import load
    path = finger(tmp_path, _set("tendons", "attachment_radius", value=1e-4))
    assert load(path).model.n_tendons == 2


def _script(tmp_path, **top):
    doc = {"format": "plush-opt-run/1", "problem": str(ROOT / "problems" / "gripper.yaml"),
           "board": str(ROOT / "hw" / "boards" / "gripper.yaml"), "rate": 20,
           "steps": [{"set": {"grip": 5.0}}]}
    doc.update(top)
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("top, pattern", [
    ({"rate": 1e-300}, r"run\.yaml: rate: must be in 0\.1\.\.1000 Hz, got 1e-300"),
    ({"steps": [{"hold": 1e308}]}, r"run\.yaml: steps\[0\]\.hold: must be <= 3600 s, got 1e\+308"),
    ({"steps": [{"pose": {"targets": [{"at": [0, 150], "to": [-30, 140]}], "max_time": 1e308}}]},
     r"run\.yaml: steps\[0\]\.pose\.max_time: must be <= 3600 s, got 1e\+308"),
    ({"steps": [{"pose": {"targets": [{"at": [0, 150], "to": [-30, 140], "weight": 1e308}]}}]},
     r"run\.yaml: steps\[0\]\.pose\.targets\[0\]\.weight: must be <= 1e\+12"),
    ({"steps": [{"hold": 3600} for _ in range(25)]}, r"run\.yaml: steps: holds and pose max_times add up to 90000 s; "
     r"at most 86400 s"),
    ({"steps": ["release"] * 10_001}, r"run\.yaml: steps: 10001 steps; at most 10000"),
])
def test_run_script_caps(tmp_path, top, pattern):
    p = cli("run", _script(tmp_path, **top), "--dry-run", "--log", tmp_path / "log.jsonl")
    assert re.search(pattern, one_error_line(p)), p.stderr


def test_sweep_steps_cap(tmp_path):
    p = cli("sweep", ROOT / "problems" / "gripper_friction.yaml", "--winch", "grip", "--to", "5",
            "--steps", "1000000000", "--out", tmp_path / "s.csv")
    assert re.search(r"--steps: expected 1\.\.10000, got 1000000000", one_error_line(p)), p.stderr


def _via_model(n: int, hessian="auto"):
    from plush_opt.fem.mesh import build_mesh
    from plush_opt.fem.model import Model
    from plush_opt.io.problem_file import scene_from_dict
    data = yaml.safe_load(FINGER.read_text())
    data["targets"][0]["to"] = [55, 20]
    data["tendons"]["list"][0]["path"] = [[float(x), 2.0] for x in np.linspace(58, 2, n)]
    scene = scene_from_dict(data, "finger.yaml")
    mesh = build_mesh(scene)
    tracemalloc.start()
    try:
        model = Model(scene, mesh, hessian)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return model, peak


def test_hessian_memory_is_linear_in_via_points():
    """A tendon's dense l' l'^T block is kept apart (the rank-one form) once
    it is large: four times the via points, about four times the memory (it
    was sixteen), and the equilibrium still converges."""
    (small, m_small), (large, m_large) = _via_model(200), _via_model(800)
    assert large.hessian_layout.form == "rank_one"
    assert large.hessian_nnz < 6 * small.hessian_nnz
    assert m_large < 6 * m_small
    _, m_rank_one = _via_model(800, "rank_one")
    assert m_rank_one < 6 * m_small


def test_few_via_points_keep_the_assembled_form():
    assert _via_model(20)[0].hessian_layout.form == "assembled"


def test_a_disc_below_round_off_is_refused_not_split_forever():
    """A scene built in code skips the file's floor on the radius: the disc
    integration still stops (it used to split the cut triangles forever)."""
    import dataclasses
    from plush_opt.base.errors import SceneError
    from plush_opt.fem.attachments import TendonPoints
    from plush_opt.fem.mesh import build_mesh
    from plush_opt.io.problem_file import scene_from_dict
    data = yaml.safe_load(FINGER.read_text())
    data["targets"][0]["to"] = [55, 20]
    scene = scene_from_dict(data, "finger.yaml")
    tendons = [dataclasses.replace(t, attachment_radius=1e-15) for t in scene.tendons]
    with pytest.raises(SceneError, match=r"attachment radius 1e-15: too small to integrate over this mesh"):
        TendonPoints(build_mesh(scene), tendons)
