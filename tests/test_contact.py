"""Contact (docs/problem-format.md, "Contact"): the term's derivatives,
known answers, the result's contact block, control through contact, and
one clear error for each bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from plush_opt.base.errors import SceneError
from plush_opt.fem import contact_report
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import Model
from plush_opt.io.problem_file import load_scene, scene_from_dict
from plush_opt.solve.equilibrium import solve_equilibrium

from shipped import ROOT

PROBLEMS = ROOT / "problems"

BLOCK = {
    "format": "plush-opt/1", "name": "block",
    "mesh": {"outline": [[0, 0.5], [10, 0.5], [10, 5.5], [0, 5.5]], "max_area": 1.0},
    "material": {"model": "neo_hookean", "youngs_modulus": 0.05, "poisson_ratio": 0.3,
                 "thickness": 10.0, "density": 1e-6},
    "gravity": [0.0, -9810.0],
    "winches": [{"name": "w", "bounds": [0.0, 3.0]}],
    "tendons": {"stiffness": 1.0, "smoothing": 0.05,
                "list": [{"name": "t", "winch": "w", "path": [[1, 4.5], [9, 4.5]]}]},
    "contact": {"ground": {"height": 0.0}, "distance": 1.0},
}


def _block(**changes):
    doc = json.loads(json.dumps(BLOCK))
    for key, value in changes.items():
        doc[key] = value
    return scene_from_dict(doc, "block.yaml")


def _model(scene):
    return Model(scene, build_mesh(scene))


def test_a_body_resting_on_the_floor_carries_its_weight():
    model = _model(_block())
    eq = solve_equilibrium(model, np.zeros(1))
    assert eq.converged, eq.status
    rep = contact_report.report(model.contact, eq.x)
    weight = model.f_gravity.reshape(-1, 2).sum(axis=0)
    total = np.asarray(rep["total_force"])
    assert total[1] == pytest.approx(-weight[1], rel=1e-6)
    assert abs(total[0]) <= 1e-9 * abs(weight[1])
    assert 0 < rep["min_gap"] < model.contact.distance
    assert model.free_motions(eq.x, eq.contraction) == ["translation in x"]


def test_the_contact_forces_balance_the_other_terms_node_by_node():
    model = _model(_block())
    eq = solve_equilibrium(model, np.array([2.0]))
    assert eq.converged, eq.status
    others = np.zeros(model.n_dofs)
    for term in model.terms:
        if term is not model.contact:
            others += term.evaluate(eq.x, eq.contraction, 1).gradient
    forces = np.zeros((model.n_nodes, 2))
    for entry in contact_report.node_forces(model.contact, eq.x):
        forces[entry["node"]] += entry["normal_force"]
    scale = np.abs(forces).max()
    assert np.abs(others.reshape(-1, 2) - forces).max() <= 1e-8 * scale


def _fd_check(term, x, c, h=1e-6, seed=0):
    rng = np.random.default_rng(seed)
    ev = term.evaluate(x, c, 2)
    H = ev.hessian["contact_hess"].tocsr()
    for _ in range(3):
        v = rng.standard_normal(x.size)
        ep, em = term.evaluate(x + h * v, c, 1), term.evaluate(x - h * v, c, 1)
        assert (ep.energy - em.energy) / (2 * h) == pytest.approx(ev.gradient @ v, rel=1e-6, abs=1e-12)
        fd = (ep.gradient - em.gradient) / (2 * h)
        assert np.linalg.norm(fd - H @ v) <= 1e-5 * max(np.linalg.norm(H @ v), 1e-12)


@pytest.mark.parametrize("slope", [0.0, 20.0])
def test_floor_gradient_and_hessian_match_finite_differences(slope):
    model = _model(_block(contact={"ground": {"height": -20.0, "slope": slope}, "distance": 1.0}))
    # the block turned onto the floor, its bottom 0.7 above it (within d_hat)
    a = np.radians(slope)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    normal = np.array([-np.sin(a), np.cos(a)])
    P = (model.X.reshape(-1, 2) - [0.0, 0.5]) @ R.T + [0.0, -20.0] + 0.7 * normal
    x = P.ravel() + 1e-3 * np.random.default_rng(1).standard_normal(model.n_dofs)
    assert model.contact.admissible(x)
    _fd_check(model.contact, x, np.zeros(1))


def test_a_step_never_passes_through_the_floor():
    model = _model(_block())
    x = model.X.copy()
    rng = np.random.default_rng(2)
    for _ in range(50):
        dx = rng.standard_normal(x.size) * 5.0
        dx[1::2] -= 10.0                  # down through the floor
        t = model.max_step(x, dx)
        assert 0 < t <= 1
        assert np.all(model.contact.ground_gaps(x + t * dx) > 0)


def test_the_hexapod_stands_up_and_its_result_says_what_holds_it(tmp_path):
    from plush_opt.problem import load
    from plush_opt.solve.result_file import control_result_dict
    problem = load(PROBLEMS / "hexapod_stand.yaml")
    result = problem.control()
    assert result.equilibrium.converged, result.status
    X = problem.model.X.reshape(-1, 2)
    top = [int(np.argmin(np.linalg.norm(X - p, axis=1))) for p in ([-40, 30.5], [40, 30.5])]
    P = result.equilibrium.x.reshape(-1, 2)
    assert np.all(P[top, 1] > 37.0)              # risen from 30.5 towards 38.5
    doc = control_result_dict(result)
    assert doc["model"]["contact"]["distance"] == 1.0
    assert doc["model"]["contact"]["stiffness_chosen"] is True
    assert doc["contact"]["free_motions"] == ["translation in x"]
    weight = problem.model.f_gravity.reshape(-1, 2).sum(axis=0)
    assert doc["contact"]["total_force"][1] == pytest.approx(-weight[1], rel=1e-6)
    assert doc["contact"]["min_gap"] > 0


def test_sensitivity_through_contact_matches_resolving():
    scene = load_scene(PROBLEMS / "hexapod_stand.yaml")
    model = _model(scene)
    c = np.array([8.0, 6.0])
    eq = solve_equilibrium(model, c)
    assert eq.converged, eq.status
    from plush_opt.solve.sensitivity import state_sensitivity
    dxdc = state_sensitivity(model, eq)
    h = 1e-4
    for w in range(2):
        dc = np.zeros(2)
        dc[w] = h
        xp = solve_equilibrium(model, c + dc, eq.x).x
        xm = solve_equilibrium(model, c - dc, eq.x).x
        fd = (xp - xm) / (2 * h)
        assert np.linalg.norm(fd - dxdc[:, w]) <= 1e-4 * np.linalg.norm(fd)


@pytest.mark.parametrize("contact, key, words", [
    ({"ground": {"height": 1.0}, "distance": 1.0}, "contact.ground", "on or below the ground"),
    ({"ground": {}, "distance": 0.0}, "contact.distance", "must be > 0"),
    ({"ground": {}, "distance": 100.0}, "contact.distance", "larger than the body"),
    ({"ground": {}, "distance": 1.0, "friction": -0.1}, "contact.friction", ">= 0"),
    ({"ground": {}, "distance": 1.0, "stiffness": 0}, "contact.stiffness", "must be > 0"),
    ({"distance": 1.0}, "contact", "nothing to touch"),
    ({"ground": {"slope": 90}, "distance": 1.0}, "contact.ground.slope", "at most"),
    ({"obstacles": [{"outline": [[20, 0], [30, 10], [30, 0], [20, 10]]}], "distance": 1.0},
     "contact.obstacles[0].outline", "not a simple polygon"),
    ({"obstacles": [{"name": "ground", "outline": [[20, 0], [30, 0], [30, 10]]}], "distance": 1.0},
     "contact.obstacles[0].name", "reserved"),
    ({"ground": {}, "distance": 1.0, "bogus": 1}, "contact.bogus", "unknown key"),
])
def test_bad_contact_sections_get_one_clear_line(contact, key, words):
    with pytest.raises(SceneError) as err:
        _model(_block(contact=contact))
    message = str(err.value)
    assert message.startswith(f"block.yaml: {key}"), message
    assert words in message
    assert "\n" not in message


def test_a_body_without_pins_needs_contact():
    doc = json.loads(json.dumps(BLOCK))
    del doc["contact"]
    with pytest.raises(SceneError, match=r"block.yaml: pins: missing required key"):
        scene_from_dict(doc, "block.yaml")


def test_the_shipped_contact_problem_reads_as_the_spec_says():
    raw = yaml.safe_load((PROBLEMS / "hexapod_stand.yaml").read_text())
    scene = load_scene(PROBLEMS / "hexapod_stand.yaml")
    assert scene.contact.distance == raw["contact"]["distance"]
    assert scene.contact.ground.height == raw["contact"]["ground"]["height"]
    assert len(scene.pin_points) == 0


def test_a_rest_pose_inside_an_obstacle_is_refused_naming_it():
    with pytest.raises(SceneError) as err:
        _model(_block(contact={"distance": 0.5, "obstacles": [
            {"name": "peg", "outline": [[4, 2], [6, 2], [5, 4]]}]}))       # inside the block
    assert str(err.value).startswith("block.yaml: contact.obstacles[0]: obstacle 'peg' overlaps")
    with pytest.raises(SceneError, match=r"contact.obstacles\[0\]: obstacle 'wall' overlaps"):
        _model(_block(contact={"distance": 0.5, "obstacles": [
            {"name": "wall", "outline": [[-5, 2], [5, 2], [5, 3], [-5, 3]]}]}))   # across its edge


def test_the_command_line_says_one_line_for_a_bad_contact_file(tmp_path):
    from cli_helpers import cli, one_error_line
    doc = json.loads(json.dumps(BLOCK))
    doc["contact"] = {"ground": {"height": 2.0}, "distance": 1.0}
    path = tmp_path / "sunk.yaml"
    path.write_text(yaml.safe_dump(doc))
    line = one_error_line(cli("solve", str(path)))
    assert "sunk.yaml: contact.ground: the body starts on or below the ground" in line


@pytest.mark.parametrize("name, args", [
    ("hexapod_stand", []),
    ("hexapod_stand", ["--method", "bilevel"]),
    ("gripper_object", ["--method", "forward", "-c", "grip=15"]),
])
def test_contact_results_pass_the_independent_checker(tmp_path, name, args):
    from cli_helpers import cli
    from spec_checker import check_result
    out = tmp_path / "r.json"
    p = cli("solve", PROBLEMS / f"{name}.yaml", *args, "--out", out, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    doc = check_result(out)
    assert doc["contact"]["min_gap"] > 0 and doc["contact"]["nodes"]


def test_a_friction_result_passes_the_independent_checker(tmp_path):
    from cli_helpers import cli
    from spec_checker import check_result
    doc = json.loads(json.dumps(BLOCK))
    doc["contact"] = {"ground": {"height": 0.0}, "distance": 1.0, "friction": 0.3}
    path = tmp_path / "block.yaml"
    path.write_text(yaml.safe_dump(doc))
    out = tmp_path / "r.json"
    p = cli("solve", path, "-c", "w=2", "--out", out, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    result = check_result(out)
    assert any(np.any(np.asarray(n["friction_force"]) != 0) for n in result["contact"]["nodes"])
    assert result["contact"]["path"]["steps_done"] == result["contact"]["path"]["steps"]
