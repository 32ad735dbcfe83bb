"""Contact's known answers: a propped cantilever against beam theory, a
strip curled onto itself, a block on a slope with friction, the gripper
holding a ball; the obstacle and self pairs' derivatives; no step through
an obstacle."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
import yaml

from plush_opt.apps.cantilever import SHEAR_CORRECTION
from plush_opt.base.errors import SceneError
from plush_opt.fem import contact_geometry as geo
from plush_opt.fem import contact_report
from plush_opt.fem.contact import rest_pushes
from plush_opt.fem.contact_boundary import build_boundary
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import Model
from plush_opt.io.problem_file import load_scene, scene_from_dict
from plush_opt.problem import from_scene
from plush_opt.solve.accuracy import level_model
from plush_opt.solve.equilibrium import solve_equilibrium
from plush_opt.solve.plant import make_plant

from shipped import ROOT
from test_contact import BLOCK, _fd_check

PROBLEMS = ROOT / "problems"


def _model(doc, name="scene.yaml"):
    scene = scene_from_dict(doc, name)
    return Model(scene, build_mesh(scene))


def test_a_propped_cantilever_carries_what_beam_theory_says():
    """Timoshenko, plane strain: the prop at a holds the beam at its gap
    below the free sag there; R = (sag(a) - held) / compliance(a)."""
    doc = yaml.safe_load((PROBLEMS / "cantilever.yaml").read_text())
    doc["mesh"].update(element="P2", max_area=16.0)
    mat = scene_from_dict(doc, "cantilever.yaml").material
    nu = mat.lam / (2 * (mat.lam + mat.mu))
    e_plane = 2 * mat.mu * (1 + nu) / (1 - nu ** 2)
    length, height = 200.0, 10.0
    inertia, area = mat.thickness * height ** 3 / 12, height * mat.thickness
    shear = SHEAR_CORRECTION * mat.mu * area
    q = mat.density * 9.81 * area
    # 10 mm in from the free end: the end face's rotation does not move the contact
    a = 190.0
    sag = (q * a ** 2 * (6 * length ** 2 - 4 * length * a + a ** 2) / (24 * e_plane * inertia)
           + q * (length * a - a * a / 2) / shear)
    below = 0.5 * sag
    doc["contact"] = {"obstacles": [{"name": "block", "outline": [[a - 5, -15], [a + 5, -15], [a, -5 - below]]}],
                      "distance": 0.02 * sag}
    model = _model(doc, "cantilever.yaml")
    eq = solve_equilibrium(model, np.zeros(1))
    assert eq.converged, eq.status
    rep = contact_report.report(model.contact, eq.x)
    held = below - rep["min_gap"]               # the beam's bottom rests a gap above the block
    reaction = (sag - held) / (a ** 3 / (3 * e_plane * inertia) + a / shear)
    assert rep["total_force"][1] == pytest.approx(reaction, rel=0.02)
    assert abs(rep["total_force"][0]) < 1e-2 * rep["total_force"][1]
    assert set(rep["total_by"]) == {"block"}


STRIP = {
    "format": "plush-opt/1", "name": "strip",
    "mesh": {"outline": [[0, 0], [100, 0], [100, 4], [0, 4]], "max_area": 1.0},
    "material": {"model": "neo_hookean", "youngs_modulus": 0.05, "poisson_ratio": 0.3, "thickness": 10.0},
    "pins": {"stiffness": 100.0, "box": [0, 0, 0, 4]},
    "winches": [{"name": "curl", "bounds": [0.0, 40.0]}],
    "tendons": {"stiffness": 5.0, "smoothing": 0.05,
                "list": [{"name": "t", "winch": "curl",
                          "path": [[1, 3.6], [25, 3.6], [50, 3.6], [75, 3.6], [99, 3.6]]}]},
}


def _crossings(model, x) -> int:
    b = build_boundary(model.mesh)
    P = x.reshape(-1, 2)
    i, _ = geo.crossing_pairs(P[b.segments[:, 0]], P[b.segments[:, 1]], shared=b.segments)
    return len(i)


@pytest.mark.parametrize("self_contact", [False, True])
def test_a_strip_curled_onto_itself_crosses_itself_only_without_self_contact(self_contact):
    doc = json.loads(json.dumps(STRIP))
    if self_contact:
        doc["contact"] = {"self": True, "distance": 0.5}
    model = _model(doc, "strip.yaml")
    x, crossed = None, []
    for c in np.arange(4.0, 32.1, 4.0):           # a full turn at about 22
        eq = solve_equilibrium(model, np.array([c]), x)
        assert eq.converged, (c, eq.status)
        x = eq.x
        crossed.append(_crossings(model, x))
    if self_contact:
        assert crossed == [0] * len(crossed)
        assert contact_report.min_gap(model.contact, x) > 0
    else:
        assert max(crossed) > 0


def test_self_contact_on_a_boundary_cut_finer_than_its_distance_is_said_to_push_at_rest(caplog):
    """The strip with self-contact at d_hat 0.5: on its file's mesh nothing
    is within reach in the rest pose; on a
    mesh whose boundary segments are shorter than d_hat, a node is within
    d_hat of a segment two along, and the pair pushes the unloaded body
    apart: the contact term says where, a problem built on that mesh warns,
    naming the key, and an accuracy level on it is refused."""
    doc = json.loads(json.dumps(STRIP))
    doc["contact"] = {"self": True, "distance": 0.5}
    scene = scene_from_dict(doc, "strip.yaml")
    model = Model(scene, build_mesh(scene))
    assert rest_pushes(model.contact, model.X) is None
    fine = build_mesh(scene, max_area=0.02)
    model = Model(scene, fine)
    pushes = rest_pushes(model.contact, model.X)
    assert pushes is not None and "within contact.distance 0.5" in pushes, pushes
    with caplog.at_level(logging.WARNING, logger="plush_opt"):
        from_scene(scene, fine)
    assert any("strip.yaml: contact.self" in r.getMessage() and "pushes the unloaded body apart" in r.getMessage()
               for r in caplog.records)
    with pytest.raises(SceneError, match=r"strip.yaml: accuracy: .*contact\.distance below"):
        level_model(scene, fine)


@pytest.mark.slow        # a sweep of mesh levels: about 5 s
def test_the_accuracy_sweep_stops_where_self_contact_would_push_at_rest():
    """The strip with self-contact at d_hat 0.2 and a tolerance no level
    meets: the sweep's finer levels cut the boundary finer than d_hat. It
    ends at the levels that can be used and says which it did not use and
    why, instead of failing after the coarse levels' work; where not even
    the coarsest level can be used (d_hat 1), that is the error."""
    from plush_opt.solve.accuracy import choose_levels
    doc = json.loads(json.dumps(STRIP))
    doc["contact"] = {"self": True, "distance": 0.2}
    doc["targets"] = [{"at": [100, 2], "to": [80, 30]}]
    said = []
    best, computed, report = choose_levels(scene_from_dict(doc, "strip.yaml"), 1e-4, progress=said.append)
    cut = report["not_admissible"]
    assert not report["reached"] and cut and computed
    assert all("pushes the unloaded body apart" in row["why"] for row in cut)
    for row in cut:                 # every level used is coarser than the first one cut from its family
        assert all(lv.mesh.n_nodes < row["nodes"] for lv in computed
                   if lv.element == row["element"] and lv.resolution.family == row["family"])
    assert "levels not used (self-contact pushes in their rest pose)" in report["stopped"]
    assert "levels not used: " in report["summary"] and "contact.distance" in report["summary"]
    assert sum("not used, nor the finer ones of its family" in line for line in said) == len(cut)
    doc["contact"]["distance"] = 1.0
    with pytest.raises(SceneError, match=r"strip.yaml: accuracy: .*pushes the unloaded body apart"):
        choose_levels(scene_from_dict(doc, "strip.yaml"), 1e-4)


def test_obstacle_and_self_pairs_match_finite_differences():
    doc = json.loads(json.dumps(STRIP))
    # a peg 1.5 below the strip (within d_hat): the strip curls up, away from it
    doc["contact"] = {"self": True, "distance": 2.0,
                      "obstacles": [{"name": "peg", "outline": [[40, -5], [44, -5], [42, -1.5]]}]}
    model = _model(doc, "strip.yaml")
    assert model.contact.pairs(model.X).label.max() == 1
    _fd_check(model.contact, model.X + 0.05 * np.random.default_rng(4).standard_normal(model.n_dofs),
              np.zeros(1))
    x = None
    for c in (8.0, 16.0, 24.0):                       # curled: its tip near its root
        eq = solve_equilibrium(model, np.array([c]), x)
        assert eq.converged, eq.status
        x = eq.x
    assert (model.contact.pairs(x).label == 0).any()
    _fd_check(model.contact, x, np.zeros(1))


def test_a_newton_step_never_passes_through_a_thin_obstacle():
    doc = json.loads(json.dumps(BLOCK))
    doc["contact"] = {"distance": 0.5, "obstacles": [{"name": "blade", "outline": [[-5, -1], [15, -1], [15, -0.9]]}]}
    model = _model(doc, "block.yaml")
    rng = np.random.default_rng(3)
    for _ in range(30):
        dx = rng.standard_normal(model.n_dofs)
        dx[1::2] -= 8.0                          # down through the blade
        t = model.max_step(model.X, dx)
        assert 0 <= t <= 1
        x = model.X + t * dx
        if model.elastic.admissible(x):
            assert model.contact.admissible(x)
        assert t < 1        # the blade is in the way: the full step would pass (even through) it


def _block_on(slope: float, friction: float):
    doc = json.loads(json.dumps(BLOCK))
    a = np.radians(slope)
    # the floor tilted up to the right, 0.6 below the block's lower right corner
    doc["contact"] = {"ground": {"height": 0.5 - 10 * np.tan(a) - 0.6 / np.cos(a), "slope": slope},
                      "distance": 1.0, "friction": friction}
    scene = scene_from_dict(doc, "block.yaml")
    model = Model(scene, build_mesh(scene))
    return model, make_plant(model)


def test_a_block_on_a_slope_sticks_below_the_friction_angle():
    model, plant = _block_on(10.0, 0.3)         # friction angle 16.7 degrees
    eq = plant.equilibrium(np.zeros(1), steps=1)
    assert eq.converged, eq.status
    friction = contact_report.ContactFrictionTerm(model.contact, eq.contact.lag)
    rep = contact_report.report(model.contact, eq.x, friction)
    weight = model.f_gravity.reshape(-1, 2).sum(axis=0)
    assert np.allclose(rep["total_force"], -weight, rtol=1e-6, atol=1e-9 * abs(weight[1]))
    tangent = model.contact.ground.tangent
    along = sum(np.dot(n["friction_force"], tangent) for n in rep["nodes"])
    assert along == pytest.approx(-weight @ tangent, rel=1e-6)          # friction holds it
    assert model.free_motions(eq.x, eq.contraction, (friction,)) == []


def test_a_block_on_a_slope_steeper_than_the_friction_angle_slides():
    model, plant = _block_on(25.0, 0.3)
    eq = plant.equilibrium(np.zeros(1), steps=1)
    assert not eq.converged
    assert "slides" in eq.status


def test_the_gripper_holds_the_ball_and_the_forces_balance_node_by_node():
    scene = load_scene(PROBLEMS / "gripper_object.yaml")
    model = Model(scene, build_mesh(scene))
    eq = solve_equilibrium(model, np.array([0.0, 0.0, 15.0]))
    assert eq.converged, eq.status
    rep = contact_report.report(model.contact, eq.x)
    assert set(rep["total_by"]) == {"ball"} and rep["total_force"][1] > 0    # the ball pushes the arm up
    others = np.zeros(model.n_dofs)
    for term in model.terms:
        if term is not model.contact:
            others += term.evaluate(eq.x, eq.contraction, 1).gradient
    forces = np.zeros((model.n_nodes, 2))
    for entry in rep["nodes"]:
        forces[entry["node"]] += entry["normal_force"]
    touched = np.abs(forces).sum(axis=1) > 0
    assert np.abs(others.reshape(-1, 2)[touched] - forces[touched]).max() <= 1e-6 * np.abs(forces).max()


@pytest.mark.parametrize("grip", [14.0, 14.05, 15.0])     # clear of the ball, just touching, pressing
def test_sensitivity_across_a_contact_that_is_just_touching_matches_resolving(grip):
    from plush_opt.solve.sensitivity import state_sensitivity
    scene = load_scene(PROBLEMS / "gripper_object.yaml")
    model = Model(scene, build_mesh(scene))
    c = np.array([0.0, 0.0, grip])
    eq = solve_equilibrium(model, c, solve_equilibrium(model, c - [0, 0, 2.0]).x)
    assert eq.converged, eq.status
    dxdc = state_sensitivity(model, eq)[:, 2]
    h = 1e-3
    xp = solve_equilibrium(model, c + [0, 0, h], eq.x).x
    xm = solve_equilibrium(model, c - [0, 0, h], eq.x).x
    fd = (xp - xm) / (2 * h)
    assert np.linalg.norm(fd - dxdc) <= 1e-4 * np.linalg.norm(fd)


def test_both_control_methods_stand_the_hexapod_up_to_the_same_pose():
    """From rest the loop's first Gauss-Newton step lifts both legs
    together, while IPOPT's first steps off the lower bounds can head for
    a corner (a at its upper bound, another certified local answer, as it
    did at 3,064 nodes with the file's earlier targets, 18 mm up,
    docs/benchmarks.md); from a symmetric start off the
    bounds both methods reach the loop's pose from rest."""
    from plush_opt.problem import load
    problem = load(PROBLEMS / "hexapod_stand.yaml")
    from_rest = problem.control("reparam")
    both = {"a": 4.0, "b": 4.0}
    loop, bilevel = problem.control("reparam", both), problem.control("bilevel", both)
    assert from_rest.equilibrium.converged and loop.equilibrium.converged and bilevel.equilibrium.converged
    for result in (loop, bilevel):
        assert result.objective == pytest.approx(from_rest.objective, rel=1e-4)
        assert np.allclose(result.contraction, from_rest.contraction, atol=1e-3)
