"""Mesher: forced nodes, orientation, quality and size, point location,
explicit meshes, determinism."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plush_opt.base.errors import SceneError
from plush_opt.io import load_scene, scene_from_dict
from plush_opt.fem.mesh import Mesh, area_for_nodes, build_mesh, mesh_for_nodes, refine_uniformly


def problem(**mesh):
    """A 80 x 20 bar with a hole; ``mesh`` overrides mesh keys."""
    m = {"outline": [[0, 0], [80, 0], [80, 20], [0, 20]],
         "holes": [[[30, 8], [40, 8], [40, 12], [30, 12]]],
         "max_area": 10.0, "min_angle": 28.0}
    m.update(mesh)
    return {
        "format": "plush-opt/1",
        "name": "bar",
        "mesh": {k: v for k, v in m.items() if v is not None},
        "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                     "thickness": 30.0},
        "pins": {"stiffness": 1000.0, "at": [[0, 10]], "box": [0, 0, 0, 20]},
        "winches": [{"name": "grip", "bounds": [0.0, 25.0]}],
        "tendons": {"stiffness": 50.0, "smoothing": 0.05, "list": [
            {"name": "lower", "winch": "grip", "path": [[80, 2], [55.5, 2.7], [30, 10], [1.3, 2.1]]},
            {"name": "upper", "winch": "grip", "path": [[80, 18], [20.25, 17.125]]}]},
        "targets": [{"at": [80, 10], "to": [70, 30]}, {"at": [35, 8], "to": [0, 0]},
                    {"at": [12.3, 4.56], "to": [0, 0]}],
        "points": [[50, 10], [50, 0], [61.7, 13.3]],
    }


def scene(**mesh):
    return scene_from_dict(problem(**mesh), "bar.yaml")


@pytest.fixture(scope="module")
def bar():
    s = scene()
    return s, build_mesh(s)


def angles(mesh):
    p = mesh.X[mesh.triangles]
    out = []
    for i in range(3):
        a, b, c = p[:, i], p[:, (i + 1) % 3], p[:, (i + 2) % 3]
        u, v = b - a, c - a
        cos = np.einsum("ij,ij->i", u, v) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
        out.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.stack(out, axis=1)


def boundary_edges(mesh):
    e = np.sort(mesh.triangles[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    return uniq[count == 1]


def test_forced_points_are_nodes_at_their_exact_position(bar):
    s, mesh = bar
    for tendon, nodes in zip(s.tendons, mesh.tendon_nodes):
        np.testing.assert_array_equal(mesh.X[nodes], tendon.path)
    np.testing.assert_array_equal(mesh.X[mesh.point_nodes], s.points)
    pin = np.flatnonzero((mesh.X == s.pin_points[0]).all(axis=1))
    assert pin.size == 1 and pin[0] in mesh.pin_nodes


def test_triangles_ccw_positive_area_and_all_nodes_used(bar):
    _, mesh = bar
    assert np.all(mesh.areas > 0)
    assert np.array_equal(np.unique(mesh.triangles), np.arange(mesh.n_nodes))


def test_min_angle_and_max_area_respected(bar):
    _, mesh = bar
    assert angles(mesh).min() >= 28.0 - 1e-6
    assert mesh.areas.max() <= 10.0 * (1 + 1e-9)
    assert mesh.areas.sum() == pytest.approx(80 * 20 - 10 * 4, rel=1e-12)


def test_hole_is_empty_and_its_corners_are_nodes(bar):
    _, mesh = bar
    centroids = mesh.X[mesh.triangles].mean(axis=1)
    in_hole = ((centroids[:, 0] > 30) & (centroids[:, 0] < 40)
               & (centroids[:, 1] > 8) & (centroids[:, 1] < 12))
    assert not in_hole.any()
    for corner in [[30, 8], [40, 8], [40, 12], [30, 12]]:
        assert (mesh.X == corner).all(axis=1).any()


def test_max_area_override():
    s = scene()
    fine = build_mesh(s, max_area=2.0)
    assert fine.areas.max() <= 2.0 * (1 + 1e-9)
    assert fine.n_nodes > build_mesh(s).n_nodes
    for bad in (0.0, -1.0, math.nan, "1"):
        with pytest.raises(SceneError, match=r"^bar\.yaml: max_area: must be a finite number > 0"):
            build_mesh(s, max_area=bad)


def test_absurdly_fine_mesh_refused():
    with pytest.raises(SceneError, match=r"mesh\.max_area: .* triangles \(limit"):
        build_mesh(scene(), max_area=1e-6)


def test_pin_nodes_are_at_nodes_and_box_nodes_sorted_unique(bar):
    s, mesh = bar
    left = np.flatnonzero(mesh.X[:, 0] == 0)
    assert left.size > 3
    assert set(left) <= set(mesh.pin_nodes)
    assert np.all(np.diff(mesh.pin_nodes) > 0)
    assert set(mesh.pin_nodes) == set(left)        # pins.at (0, 10) is on that edge


def test_box_catching_no_node_is_an_error():
    d = problem()
    d["pins"]["box"] = [10.1, 10.1, 10.2, 10.2]
    s = scene_from_dict(d, "bar.yaml")
    with pytest.raises(SceneError, match=r"^bar\.yaml: pins\.box: catches no mesh node"):
        build_mesh(s)


def test_target_weights_reproduce_the_point(bar):
    s, mesh = bar
    beta = mesh.target_beta
    assert beta.shape == (3, 3) and np.allclose(beta.sum(axis=1), 1.0)
    corners = mesh.X[mesh.triangles[mesh.target_triangles]]
    at = np.array([t.at for t in s.targets])
    np.testing.assert_allclose(np.einsum("kj,kjd->kd", beta, corners), at, atol=1e-12)
    assert np.all(beta >= -1e-12)


def test_locate_helper_and_outside_points(bar):
    _, mesh = bar
    tri, beta = mesh.locate([[12.3, 4.56], [35, 10], [-1, 0]])
    assert tri[0] >= 0 and tri[1] == -1 and tri[2] == -1
    assert np.isnan(beta[1]).all()
    np.testing.assert_allclose(beta[0] @ mesh.X[mesh.triangles[tri[0]]], [12.3, 4.56])


def test_boundary_point_splits_the_segment():
    # no quality or area refinement: without the forced point the bottom
    # edge would stay one segment
    s = scene(max_area=None, min_angle=0.0, holes=None)
    mesh = build_mesh(s)
    node = int(np.flatnonzero((mesh.X == [50, 0]).all(axis=1))[0])
    edges = boundary_edges(mesh)
    touching = edges[(edges == node).any(axis=1)]
    assert len(touching) == 2
    others = {tuple(mesh.X[a if a != node else b]) for a, b in touching}
    assert all(y == 0 for _, y in others)            # both neighbours on the bottom edge
    assert (80.0, 0.0) in others or any(x > 50 for x, _ in others)


def test_boundary_is_the_outline(bar):
    _, mesh = bar
    a, b = mesh.X[boundary_edges(mesh)].transpose(1, 0, 2)
    mid = (a + b) / 2
    on_outer = (np.isclose(mid[:, 0], 0) | np.isclose(mid[:, 0], 80)
                | np.isclose(mid[:, 1], 0) | np.isclose(mid[:, 1], 20))
    on_hole = (np.isclose(mid[:, 0], 30) | np.isclose(mid[:, 0], 40)
               | np.isclose(mid[:, 1], 8) | np.isclose(mid[:, 1], 12))
    assert np.all(on_outer | on_hole)


def test_point_within_tolerance_of_a_node_is_that_node():
    d = problem()
    d["points"] = [[80 + 1e-12, 20], [50, 10], [50, 10 + 1e-12]]
    mesh = build_mesh(scene_from_dict(d, "bar.yaml"))
    assert mesh.point_nodes[1] == mesh.point_nodes[2]
    np.testing.assert_array_equal(mesh.X[mesh.point_nodes[0]], [80, 20])
    np.testing.assert_array_equal(mesh.X[mesh.point_nodes[1]], [50, 10])


def test_either_outline_orientation_gives_the_same_nodes():
    a = build_mesh(scene())
    b = build_mesh(scene(outline=[[0, 20], [80, 20], [80, 0], [0, 0]]))
    assert a.n_elems > 0 and b.n_elems > 0
    assert np.all(b.areas > 0)


def test_deterministic():
    assert build_mesh(scene()) == build_mesh(scene())
    assert build_mesh(scene(), max_area=3.0) == build_mesh(scene(), max_area=3.0)


def test_arrays_contiguous_read_only_and_typed(bar):
    _, mesh = bar
    arrays = [mesh.X, mesh.triangles, mesh.pin_nodes, mesh.target_triangles,
              mesh.target_beta, mesh.point_nodes, *mesh.tendon_nodes]
    for a in arrays:
        assert a.flags.c_contiguous and not a.flags.writeable
    assert mesh.X.dtype == np.float64 and mesh.triangles.dtype == np.int64
    with pytest.raises(ValueError):
        mesh.X[0, 0] = 1.0


def test_explicit_mesh_passthrough_and_reorientation():
    d = problem()
    d["mesh"] = {"nodes": [[0, 0], [10, 0], [10, 10], [0, 10], [5, 5]],
                 "triangles": [[0, 1, 4], [1, 4, 2], [2, 3, 4], [3, 4, 0]]}   # 2nd, 4th clockwise
    d["pins"] = {"stiffness": 1.0, "at": [[0, 0]], "box": [0, 0, 0, 10]}
    d["tendons"]["list"] = [{"name": "a", "winch": "grip", "path": [[10, 0], [5, 5], [0, 10]]}]
    d["targets"] = [{"at": [5, 1], "to": [0, 0]}, {"at": [5, 5], "to": [0, 0]}]
    d["points"] = [[10, 10]]
    s = scene_from_dict(d, "x.yaml")
    mesh = build_mesh(s)
    np.testing.assert_array_equal(mesh.X, s.nodes)
    assert mesh.triangles.tolist() == [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]
    assert np.all(mesh.areas > 0)
    assert mesh.tendon_nodes[0].tolist() == [1, 4, 3]
    assert mesh.point_nodes.tolist() == [2]
    assert mesh.pin_nodes.tolist() == [0, 3]
    assert mesh.target_triangles[0] == 0
    np.testing.assert_allclose(mesh.target_beta[0] @ mesh.X[mesh.triangles[0]], [5, 1])
    # the mesh size options do not apply to an explicit mesh
    assert build_mesh(s, max_area=0.01) == mesh
    with pytest.raises(SceneError, match=r"^x\.yaml: mesh: an explicit mesh cannot be resized"):
        mesh_for_nodes(s, 100)


@pytest.mark.parametrize("target", [300, 1000])
def test_mesh_for_nodes(target):
    mesh = mesh_for_nodes(scene(), target)
    assert abs(mesh.n_nodes - target) <= 0.05 * target
    with pytest.raises(SceneError, match="target_nodes must be an integer >= 3"):
        mesh_for_nodes(scene(), 2)


def test_area_for_nodes_on_a_graded_mesh():
    area, mesh = area_for_nodes(scene(), 600, graded=True, rel_tol=0.1)
    assert abs(mesh.n_nodes - 600) <= 0.1 * 600
    assert mesh == build_mesh(scene(), max_area=area, graded=True)


def test_uniform_refinement_is_nested(bar):
    s, coarse = bar
    fine = build_mesh(s, refinements=1)
    # every coarse node keeps its number and place; 4x the triangles, same area, same orientation
    assert np.array_equal(fine.X[:coarse.n_nodes], coarse.X)
    assert fine.n_elems == 4 * coarse.n_elems
    def areas(m):
        p = m.X[m.triangles]
        d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    assert (areas(fine) > 0).all() and areas(fine).sum() == pytest.approx(areas(coarse).sum())
    assert areas(fine).max() <= areas(coarse).max() / 4 * (1 + 1e-12)
    # same angles: each child is similar to its parent
    assert angles(fine).min() == pytest.approx(angles(coarse).min())
    # forced points are the same nodes; targets still located exactly
    assert np.array_equal(fine.point_nodes, coarse.point_nodes)
    assert all(np.array_equal(a, b) for a, b in zip(fine.tendon_nodes, coarse.tendon_nodes))
    at = np.array([t.at for t in s.targets])
    w = np.einsum("kj,kjd->kd", fine.target_beta, fine.X[fine.triangles[fine.target_triangles]])
    assert np.abs(w - at).max() < 1e-9
    # the pin box catches the new boundary nodes on its edge too
    assert len(fine.pin_nodes) == 2 * len(coarse.pin_nodes) - 1
    # X, triangles of the refinement itself: the midside nodes follow the corners
    X, tris = refine_uniformly(coarse.X, coarse.triangles)
    assert np.array_equal(X, fine.X) and len(tris) == fine.n_elems


def test_refined_p2_mesh_and_bad_refinements():
    import dataclasses
    s = dataclasses.replace(scene(), element="P2")
    p2 = build_mesh(s, refinements=1)
    assert p2.elements.shape == (p2.n_elems, 6) and p2.n_elems == 4 * build_mesh(s).n_elems
    # refused from the count alone, before the triangles are made
    with pytest.raises(SceneError, match=r"^bar\.yaml: mesh\.max_area: .* triangles \(limit"):
        build_mesh(s, refinements=8)
    no_area = dataclasses.replace(scene(max_area=None), element="P2")      # the angle bound only
    with pytest.raises(SceneError, match=r"^bar\.yaml: mesh\.max_area: the mesher's default refined 8 "
                                         r"times gives \d+ triangles \(limit"):
        build_mesh(no_area, refinements=8)
    for bad in (-1, 1.5, 9, True):
        with pytest.raises(SceneError, match=r"^bar\.yaml: mesh: refinements must be an integer 0..8"):
            build_mesh(s, refinements=bad)


def test_shipped_problems_mesh(problems_dir):
    for path in sorted(problems_dir.glob("*.yaml")):
        s = load_scene(path)
        mesh = build_mesh(s)
        assert isinstance(mesh, Mesh) and np.all(mesh.areas > 0), path.name
        assert len(mesh.tendon_nodes) == len(s.tendons)


@settings(max_examples=25, deadline=None)
@given(st.data())
def test_explicit_mesh_from_any_orientation_and_order(data):
    base = build_mesh(scene(max_area=40.0, holes=None))
    flips = np.array(data.draw(st.lists(st.booleans(), min_size=base.n_elems,
                                        max_size=base.n_elems)))
    rolls = np.array(data.draw(st.lists(st.integers(0, 2), min_size=base.n_elems,
                                        max_size=base.n_elems)))
    tris = base.triangles.copy()
    tris[flips] = tris[flips][:, [0, 2, 1]]
    tris = np.array([np.roll(t, r) for t, r in zip(tris, rolls)])
    d = problem()
    d["mesh"] = {"nodes": base.X.tolist(), "triangles": tris.tolist()}
    mesh = build_mesh(scene_from_dict(d, "x.yaml"))
    np.testing.assert_array_equal(mesh.X, base.X)
    assert np.all(mesh.areas > 0)
    # the same triangles, each counter-clockwise (up to a rotation of its corners)
    assert np.array_equal(np.sort(mesh.triangles, axis=1), np.sort(tris, axis=1))
    np.testing.assert_allclose(mesh.areas, base.areas, rtol=1e-12)
    for a, b in zip(mesh.tendon_nodes, base.tendon_nodes):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(mesh.pin_nodes, base.pin_nodes)
    np.testing.assert_allclose(
        np.einsum("kj,kjd->kd", mesh.target_beta, mesh.X[mesh.triangles[mesh.target_triangles]]),
        [t["at"] for t in d["targets"]], atol=1e-12)
