"""A body that folds through itself: found in a pose, told a crease (the
boundary folded back on itself over a short stretch) from an overlap (two
parts far apart along it passing through each other), and a crease left
out of the accuracy sweep's mesh choice (a crease has no length scale, so
its levels do not converge and say nothing of the mesh the other
contractions need; an overlap converges like any pose)."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from plush_opt.fem.contact_boundary import build_boundary, self_crossing
from plush_opt.fem.mesh import build_mesh
from plush_opt.io.problem_file import load_scene, scene_from_dict
from plush_opt.solve.accuracy import Level, Resolution, choose_levels, leave_out_creases
from plush_opt.solve.accuracy_estimate import estimate_levels

from shipped import ROOT

STRIP = {
    "format": "plush-opt/1", "name": "strip",
    "mesh": {"outline": [[0, 0], [10, 0], [10, 1], [0, 1]], "max_area": 0.2},
    "material": {"model": "neo_hookean", "youngs_modulus": 0.05, "poisson_ratio": 0.3, "thickness": 1.0},
    "winches": [{"name": "w", "bounds": [0.0, 1.0]}],
    "pins": {"stiffness": 1000.0, "at": [[0, 0], [0, 1]]},
    "tendons": {"stiffness": 1.0, "smoothing": 0.05, "list": [{"name": "t", "winch": "w", "path": [[1, 0.5], [9, 0.5]]}]},
}


def _strip(element, max_area=0.2):
    doc = dict(STRIP, mesh=dict(STRIP["mesh"], element=element, max_area=max_area))
    return build_mesh(scene_from_dict(doc, "strip.yaml"))


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_a_strip_folded_back_through_itself_crosses_and_one_moved_rigidly_does_not(element):
    mesh = _strip(element)
    boundary = build_boundary(mesh)
    X = mesh.X
    assert self_crossing(boundary, X.ravel()) is None
    turn = np.array([[0.0, -1.0], [1.0, 0.0]])
    assert self_crossing(boundary, (X @ turn.T + [3.0, -2.0]).ravel()) is None
    # the right half laid back over the left half, 0.5 higher: its outline cuts the left half's
    folded = X.copy()
    right = X[:, 0] > 5.0
    folded[right] = np.c_[10.0 - X[right, 0], X[right, 1] + 0.5]
    where = self_crossing(boundary, folded.ravel())
    assert where is not None and "cross near" in where
    # its two ends cross, about 10 apart along the outline of 22: an overlap, not a crease
    assert "an overlap, 10" in where and "apart along a boundary of 22" in where
    assert self_crossing(boundary, folded.ravel(), creases_only=True) is None


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_a_loop_in_the_outline_is_a_crease(element):
    mesh = _strip(element, 0.05)
    boundary = build_boundary(mesh)
    where = self_crossing(boundary, _creased(mesh))
    assert where is not None and "a crease, 0.625 apart along a boundary of 22" in where
    assert self_crossing(boundary, _creased(mesh), creases_only=True) == where


def test_a_crossing_between_a_hole_and_the_outline_is_an_overlap():
    doc = dict(STRIP, mesh=dict(STRIP["mesh"], outline=[[0, 0], [10, 0], [10, 3], [0, 3]],
                                holes=[[[4, 1], [6, 1], [6, 2], [4, 2]]]))
    mesh = build_mesh(scene_from_dict(doc, "holed.yaml"))
    # the outline's top above the hole pushed down into it
    x = mesh.X.copy()
    top = (x[:, 1] > 2.0) & (x[:, 0] >= 4.0) & (x[:, 0] <= 6.0)
    x[top, 1] -= 1.5
    where = self_crossing(build_boundary(mesh), x.ravel())
    assert where is not None and "an overlap, on separate boundaries" in where
    assert self_crossing(build_boundary(mesh), x.ravel(), creases_only=True) is None


def _creased(mesh, R=0.4):
    """The strip with a loop in its outline at x = 5: a prolate cycloid of
    radius ``R`` over one unit of its length, the parts either side 2 R higher."""
    x = mesh.X[:, 0]
    s = np.clip(x - 5.0, -0.5, 0.5)
    return np.c_[x - R * np.sin(2 * np.pi * s), mesh.X[:, 1] + R * (1 - np.cos(2 * np.pi * s))].ravel()


def _folded(mesh):
    """The strip's right half laid back over its left half, 0.5 higher."""
    folded = mesh.X.copy()
    right = mesh.X[:, 0] > 5.0
    folded[right] = np.c_[10.0 - mesh.X[right, 0], mesh.X[right, 1] + 0.5]
    return folded.ravel()


def _posed(element, pose_of):
    mesh = _strip(element, 0.05)
    res = Resolution(0.2, 0, 0.2)
    return Level(element, res, mesh, 0.0, 1e-3 * mesh.n_nodes, 1, [pose_of(mesh)], np.zeros((1, 1, 2)))


def test_a_fold_at_the_returned_contractions_is_found_on_the_level_in_use_or_a_finer_one():
    """What the check at the returned contractions asks before it claims
    anything there: whether the answer's level, or one finer, creases
    (a coarser level's crease says nothing of the answer's, and an overlap
    converges like any pose)."""
    from plush_opt.solve.accuracy_check import fold_at
    scene = scene_from_dict(STRIP, "strip.yaml")
    rest = lambda mesh: mesh.X.ravel()              # noqa: E731
    coarse, fine = _posed("P1", rest), _posed("P2", _creased)
    assert fold_at(scene, [coarse, fine], coarse) == {"element": "P2", "nodes": fine.mesh.n_nodes,
                                                      "where": fold_at(scene, [fine], fine)["where"]}
    assert "a crease" in fold_at(scene, [fine], fine)["where"]
    coarse, fine = _posed("P1", _creased), _posed("P2", rest)
    assert fold_at(scene, [coarse, fine], fine) is None
    assert fold_at(scene, [coarse, fine], coarse)["element"] == "P1"
    # a level off the answer's branch (no pose there) has nothing to cross
    assert fold_at(scene, [dataclasses.replace(coarse, poses=[None]), fine], coarse) is None
    # an overlap is no fold: its levels converge, the estimate there stands
    overlap = _posed("P2", _folded)
    assert fold_at(scene, [overlap], overlap) is None
    # with self-contact a pose never crosses: nothing to look for
    held = scene_from_dict({**STRIP, "contact": {"self": True, "distance": 0.05}}, "strip.yaml")
    assert fold_at(held, [_posed("P1", _creased)], _posed("P1", _creased)) is None


def test_the_line_at_the_returned_contractions_says_the_body_crosses_itself_there():
    from plush_opt.apps.accuracy_run import at_result_summary
    at_result = {"estimated_error": None, "met": False, "element": "P1", "nodes": 1512, "resolves": 0,
                 "crosses_itself": {"element": "P2", "nodes": 5455, "where": "boundary segments 1-2 and 7-8 cross"}}
    line = at_result_summary(at_result, 1.0)
    assert "NOT met: no estimate (the body crosses itself there on the P2 level of 5,455 nodes" in line
    assert "`self: true` under `contact:`" in line


def _level(ys, n, crossing=()):
    res = Resolution(1.0, {100: 0, 400: 1, 1600: 2}[n], 1.0)
    return Level("P2", res, SimpleNamespace(n_nodes=n), 0.0, 0.01 * n, 1, [None] * len(ys),
                 np.array(ys, dtype=np.float64).reshape(len(ys), 1, 2), crossing=crossing)


def test_a_contraction_where_a_level_crosses_itself_is_left_out_of_every_level_and_said_once():
    # contraction 0 converges (1, 0.1, 0.01); contraction 1 jumps about (a fold)
    levels = [_level([[0, 0], [0, 0]], 100, (None, None)),
              _level([[1, 0], [3, 0]], 400, (None, "segments 1-2 and 7-8 cross near (0, 0)")),
              _level([[1.1, 0], [0, 0]], 1600, (None, None))]
    estimate_levels(levels)
    assert levels[1].estimate == np.inf
    said, rows = [], []
    leave_out_creases(levels, np.array([[0.0], [0.5]]), rows, said.append)
    leave_out_creases(levels, np.array([[0.0], [0.5]]), rows, said.append)
    assert [lv.left_out for lv in levels] == [(1,)] * 3
    assert [row["contraction"] for row in rows] == [[0.5]] and rows[0]["nodes"] == 400
    assert len(said) == 1 and "[0.5]" in said[0] and "contact.self" in said[0]
    estimate_levels(levels)
    assert np.isfinite(levels[1].estimate) and levels[1].estimate < 0.2
    assert levels[0].bound is not None and levels[0].bound > 1.0


def test_where_every_contraction_crosses_itself_none_is_left_out():
    levels = [_level([[0, 0]], 100, ("a fold",)), _level([[1, 0]], 400, (None,))]
    rows = []
    leave_out_creases(levels, np.array([[0.5]]), rows)
    assert [lv.left_out for lv in levels] == [(), ()] and rows == []


def test_the_standing_hexapod_sweep_leaves_out_the_one_legged_probes_where_a_leg_folds_through_itself():
    scene = load_scene(ROOT / "problems" / "hexapod_stand.yaml")
    best, computed, report = choose_levels(scene, 1.0)
    assert sorted(row["contraction"] for row in report["left_out"]) == [[0.0, 10.0], [10.0, 0.0]]
    assert all(lv.left_out == (1, 2) for lv in computed)
    assert report["reached"] and report["estimated_error"] < 0.05
    assert "creases through itself" in report["summary"]


@pytest.mark.slow        # control on the file's mesh, then a P2 solve of about 12,000 nodes
def test_the_shipped_standing_hexapod_asks_for_a_pose_below_its_fold():
    """The file's targets are reached where a fine mesh does not fold yet
    (they once asked for 18 mm of lift, about 11 mm of each winch, where
    the feet fold through the body on every finer mesh): control's answer
    solved again on a P2 mesh of about 12,000 nodes does not cross itself
    and puts the targets within 1 mm of where the file's mesh does."""
    from plush_opt.fem.contact_boundary import crossings
    from plush_opt.problem import from_scene, load
    problem = load(ROOT / "problems" / "hexapod_stand.yaml")
    result = problem.control()
    assert result.equilibrium.converged, result.status
    fine = from_scene(dataclasses.replace(problem.scene, element="P2"), max_area=1.25)
    eq = fine.equilibrium(result.contractions)
    assert eq.converged, eq.status
    assert crossings(fine.model, [eq.x]) == (None,)
    assert np.abs(fine.targets.y(eq.x) - problem.targets.y(result.equilibrium.x)).max() <= 1.0


def test_a_result_whose_leg_folds_through_the_body_says_so(tmp_path):
    import json

    import yaml
    from cli_helpers import cli
    doc = yaml.safe_load((ROOT / "problems" / "hexapod_stand.yaml").read_text())
    doc["mesh"]["element"] = "P2"
    path = tmp_path / "stand.yaml"
    path.write_text(yaml.safe_dump(doc))
    out = tmp_path / "r.json"
    p = cli("solve", str(path), "--method", "forward", "-c", "a=14", "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert "cross near" in json.loads(out.read_text())["self_crossing"]
    assert "warning: the returned pose crosses itself" in p.stderr and "contact.self" in p.stderr
    # with self-contact the same pose is not one the body may take: nothing to say of it
    from plush_opt.fem.model import build_model
    from plush_opt.solve.result_file import crossing_of
    x = np.array(json.loads(out.read_text())["nodes"]).ravel()
    doc["contact"]["self"] = True
    path.write_text(yaml.safe_dump(doc))
    scene = load_scene(path)
    model = build_model(scene, build_mesh(scene))
    assert not model.admissible(x) and crossing_of(model, x) is None


@pytest.mark.slow        # the strip's pose by continuation: about 3 s
def test_the_thin_strip_curled_over_its_base_overlaps_and_does_not_crease():
    """tests/data/thin_strip.yaml at 30 mm: the strip curls until its end
    lies over its base (a scene without self-contact allows it). Its
    levels converge there, so the accuracy check must not take it for a
    fold: the two crossing parts are about a third of the outline apart."""
    from plush_opt.fem.contact_boundary import crossings
    from plush_opt.problem import load
    from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
    model = load(ROOT / "tests" / "data" / "thin_strip.yaml").model
    eq = solve_equilibrium(model, [30.0], options=EquilibriumOptions(eigenvalue=False, continuation=4))
    assert eq.converged, eq.status
    (where,) = crossings(model, [eq.x])
    assert where is not None and "an overlap" in where
    apart = float(where.split("an overlap, ")[1].split(" apart")[0])
    assert 90.0 <= apart <= 130.0 and "along a boundary of 306" in where
    assert crossings(model, [eq.x], creases_only=True) == (None,)


def test_a_mesh_boundary_is_built_once_while_the_mesh_lives():
    """Crossing tests on one mesh share its boundary (building it costs
    about 25 crossing tests); it goes with the mesh."""
    import gc
    from plush_opt.fem import contact_boundary as cb
    from plush_opt.fem.mesh import build_mesh
    from plush_opt.io import load_scene
    from pathlib import Path
    scene = load_scene(Path(__file__).resolve().parents[1] / "problems" / "gripper.yaml")
    mesh = build_mesh(scene)
    first = cb.boundary_of(mesh)
    assert cb.boundary_of(mesh) is first
    assert np.array_equal(first.segments, cb.build_boundary(mesh).segments)
    key = id(mesh)
    del mesh
    gc.collect()
    assert key not in cb._BOUNDARIES
