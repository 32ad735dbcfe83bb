"""Mesh resolution from a tolerance: choose_mesh and transfer_pose."""

import numpy as np
import pytest

from plush_opt.accuracy import choose_mesh, default_levels, probe_contractions, transfer_pose
from plush_opt.errors import SceneError
from plush_opt.io import load_scene, scene_from_dict
from plush_opt.mesh import build_mesh
from shipped import ROOT


def _leg():
    return load_scene(ROOT / "problems" / "hexapod_leg.yaml")


def test_looser_tolerances_pick_coarser_meshes():
    scene = _leg()
    levels = [scene.max_area * f for f in (8, 4, 2, 1, 0.5)]
    picks = {}
    for tol in (5.0, 1.0, 0.05):
        mesh, report = choose_mesh(scene, tol, levels=levels)
        picks[tol] = report
        row = report["levels"][report["picked"]]
        assert mesh.n_nodes == row["n_nodes"] == report["n_nodes"]
        assert report["summary"]
    assert picks[5.0]["n_nodes"] < picks[1.0]["n_nodes"] <= picks[0.05]["n_nodes"]
    # a picked level really meets the tolerance against the next finer one
    for tol in (5.0, 1.0):
        r = picks[tol]
        assert r["reached"] and r["levels"][r["picked"]]["difference_to_next"] < tol
    # an unreachable tolerance says so and returns the finest level computed
    r = picks[0.05]
    assert not r["reached"] and r["picked"] == len(r["levels"]) - 1
    assert "not reached" in r["summary"]


def test_levels_that_are_not_finer_are_skipped():
    scene = load_scene(ROOT / "problems" / "gripper.yaml")
    # 400 and 200 give the same mesh (forced points and the angle bound rule)
    _, report = choose_mesh(scene, 100.0, levels=[400.0, 200.0, 50.0, 25.0])
    nodes = [row["n_nodes"] for row in report["levels"]]
    assert all(b >= 1.3 * a for a, b in zip(nodes, nodes[1:]))


def test_transfer_pose_reproduces_affine_motions_exactly():
    scene = _leg()
    coarse = build_mesh(scene, max_area=24.0)
    fine = build_mesh(scene, max_area=3.0)
    A = np.array([[0.9, 0.2], [-0.1, 1.1]])
    b = np.array([3.0, -2.0])
    x_coarse = (coarse.X @ A.T + b).reshape(-1)
    x_fine = transfer_pose(coarse, x_coarse, fine)
    assert np.abs(x_fine - (fine.X @ A.T + b).reshape(-1)).max() <= 1e-9
    # onto the same mesh it is the identity
    assert np.abs(transfer_pose(coarse, x_coarse, coarse) - x_coarse).max() <= 1e-9


def test_control_problems_are_also_compared_mid_range():
    scene = _leg()
    cs = probe_contractions(scene)
    assert cs.shape == (2, 1) and cs[1, 0] == pytest.approx(7.5)
    assert len(default_levels(scene)) >= 5


def test_bad_tolerance_and_levels_are_refused():
    scene = _leg()
    with pytest.raises(SceneError, match="tol"):
        choose_mesh(scene, -1.0)
    with pytest.raises(SceneError, match="levels"):
        choose_mesh(scene, 1.0, levels=[2.0, 4.0])


def test_explicit_mesh_is_returned_as_is():
    doc = {"format": "plush-opt/1", "name": "square",
           "mesh": {"nodes": [[0, 0], [10, 0], [10, 10], [0, 10]], "triangles": [[0, 1, 2], [0, 2, 3]]},
           "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                        "thickness": 1.0},
           "pins": {"stiffness": 1000.0, "at": [[0, 0], [10, 0]]},
           "winches": [{"name": "w", "bounds": [0.0, 1.0]}],
           "tendons": {"stiffness": 50.0, "smoothing": 0.01,
                       "list": [{"name": "t", "winch": "w", "path": [[10, 10], [0, 0]]}]}}
    mesh, report = choose_mesh(scene_from_dict(doc), 0.1)
    assert mesh.n_nodes == 4 and "explicit" in report["note"]
