"""Meshes graded towards reentrant corners and the ends of pinned boundary
(plush_opt.fem.grading): which points are singular, the sizes the mesh gets,
and that grading buys accuracy where a uniform mesh converges slowly."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from plush_opt.solve.accuracy import equilibrium_at
from plush_opt.solve.equilibrium import EquilibriumOptions
from plush_opt.base.errors import SceneError
from plush_opt.fem.grading import G_MIN, GAMMA, grading_radii, singular_points, size_factor
from plush_opt.io import load_scene, scene_from_dict
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from plush_opt.fem.objective import Targets
from shipped import ROOT

L_OUTLINE = [[0, 0], [40, 0], [40, 10], [10, 10], [10, 40], [0, 40]]
TIP = np.array([[40.0, 5.0]])


def _scene(outline=L_OUTLINE, box=(0, 40, 10, 40), holes=(), element="P2", max_area=4.0):
    """A felt body hanging from a pinned edge, under gravity."""
    doc = {"format": "plush-opt/1", "name": "shape",
           "mesh": {"outline": outline, "max_area": max_area, "min_angle": 28.0, "element": element},
           "material": {"model": "neo_hookean", "youngs_modulus": 1.0, "poisson_ratio": 0.3,
                        "thickness": 10.0, "density": 1.0e-9},
           "gravity": [0.0, -98.1],
           "pins": {"stiffness": 1000.0, "at": [], "box": list(box)},
           "winches": [{"name": "w", "bounds": [0.0, 1.0]}],
           "tendons": {"stiffness": 1e-6, "smoothing": 0.01,
                       "list": [{"name": "t", "winch": "w", "path": [[5, 30], [5, 20]]}]}}
    if holes:
        doc["mesh"]["holes"] = [list(map(list, h)) for h in holes]
    return scene_from_dict(doc)


def _sorted(points):
    return sorted(map(tuple, np.round(points, 9).tolist()))


# --- the singular points ----------------------------------------------------

def test_an_l_shape_has_its_reentrant_corner_and_the_ends_of_its_pinned_edge():
    assert _sorted(singular_points(_scene())) == [(0, 40), (10, 10), (10, 40)]


def test_orientation_of_the_outline_does_not_matter():
    assert _sorted(singular_points(_scene(outline=L_OUTLINE[::-1]))) == [(0, 40), (10, 10), (10, 40)]


def test_a_convex_body_pinned_along_a_whole_edge_has_the_edge_ends_only():
    square = [[0, 0], [40, 0], [40, 40], [0, 40]]
    assert _sorted(singular_points(_scene(outline=square, box=(0, 40, 40, 40)))) == [(0, 40), (40, 40)]


def test_a_pinned_stretch_across_a_corner_ends_where_the_box_leaves_the_boundary():
    square = [[0, 0], [40, 0], [40, 40], [0, 40]]
    # the box holds the corner (0, 40) and 10 mm of each edge beside it
    assert _sorted(singular_points(_scene(outline=square, box=(-1, 30, 10, 41)))) == [(0, 30), (10, 40)]


def test_every_vertex_of_a_convex_polygonal_hole_is_reentrant_for_the_body():
    square = [[0, 0], [40, 0], [40, 40], [0, 40]]
    hole = [[15, 15], [25, 15], [25, 25], [15, 25]]
    pts = singular_points(_scene(outline=square, box=(0, 40, 40, 40), holes=[hole]))
    assert _sorted(pts) == sorted([(0, 40), (40, 40)] + [tuple(map(float, p)) for p in hole])


def test_the_shipped_gripper_grades_its_t_junction_and_its_base():
    scene = load_scene(ROOT / "problems" / "gripper.yaml")
    pts = _sorted(singular_points(scene))
    # the base's ends, and every vertex of the junction's two filleted
    # corners (each chord turns the boundary inwards by 15 degrees)
    junction = [p for p in map(tuple, scene.outline) if p[1] >= 115 and abs(p[0]) <= 25]
    assert len(junction) == 14
    assert pts == sorted([(-20.0, 0.0), (20.0, 0.0)] + junction)


# --- the sizes --------------------------------------------------------------

def test_size_factor_follows_the_grading_function_between_its_floor_and_one():
    singular = np.array([[0.0, 0.0]])
    radii = np.array([10.0])
    d = np.array([0.0, 1e-3, 2.5, 5.0, 10.0, 20.0])
    g = size_factor(np.c_[d, np.zeros_like(d)], singular, radii, "P2")
    expected = np.clip((d / 10.0) ** GAMMA["P2"], G_MIN, 1.0)
    np.testing.assert_allclose(g, expected)
    assert g[0] == G_MIN and g[-1] == 1.0 and np.all(np.diff(g) >= 0)


def test_grading_radii_are_at_most_half_the_distance_between_singular_points():
    radii = grading_radii(np.array([[0.0, 0.0], [4.0, 0.0], [100.0, 0.0]]), size=80.0)
    np.testing.assert_allclose(radii, [2.0, 2.0, 20.0])


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_graded_mesh_meets_its_local_size_bound_and_keeps_the_forced_nodes(element):
    scene = _scene(element=element)
    area = 4.0
    uniform, graded = build_mesh(scene, max_area=area), build_mesh(scene, max_area=area, graded=True)
    singular = singular_points(scene)
    radii = grading_radii(singular, np.sqrt(700.0))
    p = graded.X[graded.triangles]
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    tri_area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    g = size_factor(p.mean(axis=1), singular, radii, element)
    # Triangle meets each bound at the triangle it refined; the centroid of
    # a child moves, so allow the grading's change over one element
    assert np.all(tri_area <= area * (1 + 1e-9))
    assert np.mean(tri_area <= 2.0 * area * g ** 2) > 0.98
    near = np.linalg.norm(p.mean(axis=1) - [10.0, 10.0], axis=1) < 0.5
    assert near.any() and tri_area[near].max() < (0.25 if element == "P1" else 0.05) * area
    assert uniform.n_nodes < graded.n_nodes < 3 * uniform.n_nodes
    np.testing.assert_array_equal(graded.X[graded.tendon_nodes[0]], [[5, 30], [5, 20]])
    assert np.all(np.isclose(graded.X[graded.pin_nodes, 1], 40.0))
    assert build_mesh(scene, max_area=area, graded=True) == graded          # deterministic


def test_attachment_discs_get_elements_a_quarter_of_h():
    square = [[0, 0], [40, 0], [40, 40], [0, 40]]
    scene = _scene(outline=square, box=(0, 40, 40, 40))
    tendon = dataclasses.replace(scene.tendons[0], attachment_radius=2.0)
    scene = dataclasses.replace(scene, tendons=(tendon,))
    area = 16.0
    mesh = build_mesh(scene, max_area=area, graded=True)
    p = mesh.X[mesh.triangles]
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    tri_area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    for centre in ([5, 30], [5, 20]):
        inside = np.linalg.norm(p.mean(axis=1) - centre, axis=1) < 2.0
        assert inside.sum() >= 8 and tri_area[inside].max() <= area / 16 * (1 + 1e-9)
    far = np.linalg.norm(p.mean(axis=1) - [30, 10], axis=1) < 5
    assert tri_area[far].max() > area / 4                  # the rest stays coarse


def test_a_graded_mesh_needs_a_max_area():
    scene = dataclasses.replace(_scene(), max_area=None)
    with pytest.raises(SceneError, match="graded mesh needs max_area"):
        build_mesh(scene, graded=True)


# --- what it is for -----------------------------------------------------------

def _tip(scene, mesh):
    model = build_model(scene, mesh)
    eq = equilibrium_at(model, np.zeros(1), None, EquilibriumOptions(eigenvalue=False))
    assert eq.converged
    return Targets.at_points(mesh, TIP, TIP).y(eq.x)[0]


@pytest.mark.slow
def test_grading_beats_uniform_refinement_at_a_reentrant_corner():
    """The L-shape's arm tip under gravity: the P2 error of a graded mesh is
    several times below that of uniform meshes with more nodes, and the
    uniform meshes converge at the corner's reduced rate. (Measured: graded
    1,024 nodes 5e-6; uniform 2,300 and 4,501 nodes 4.0e-5 and 2.8e-5, and
    still 7.6e-6 at 36,698 nodes.)"""
    scene = _scene()
    reference = _tip(scene, build_mesh(scene, max_area=0.25, graded=True))
    check = _tip(scene, build_mesh(scene, max_area=0.5, graded=True))
    graded = build_mesh(scene, max_area=4.0, graded=True)
    e_graded = np.linalg.norm(_tip(scene, graded) - reference)
    uniform = [build_mesh(scene, max_area=a) for a in (1.0, 0.5)]
    e_uniform = [np.linalg.norm(_tip(scene, m) - reference) for m in uniform]
    # the reference is converged well below the errors compared
    assert np.linalg.norm(check - reference) < 0.1 * e_graded
    assert uniform[0].n_nodes > graded.n_nodes
    assert e_graded < 0.25 * e_uniform[0]
    assert e_graded < e_uniform[1]
    # uniform: halving the area (h / sqrt 2) cuts the error by far less than
    # P2's h^3 (2.8x) would
    assert e_uniform[0] / e_uniform[1] < 2.0


def test_a_pinned_end_is_graded_to_the_floor_even_on_a_mesh_coarser_than_its_radius():
    # h (20 mm) above the grading radius (10 mm): the centroid's bound alone
    # stops far above the floor at the clamped root; a triangle touching a
    # pinned end takes the floor
    strip = [[0, 15], [80, 15], [80, 35], [0, 35]]
    scene = _scene(outline=strip, box=(0, 15, 0, 35), max_area=200.0)
    mesh = build_mesh(scene, max_area=200.0, graded=True)
    p = mesh.X[mesh.triangles]
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    tri_area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    for end in ([0.0, 15.0], [0.0, 35.0]):
        touching = np.any(np.linalg.norm(p - end, axis=2) < 1e-9, axis=1)
        assert touching.any() and tri_area[touching].max() <= 200.0 * G_MIN ** 2 * (1 + 1e-9)
