"""Finite tendon attachments (attachment_radius): the disc-average weights
against analytic cases, the model's derivatives with attachments against
central differences and the CasADi expression, control and result files."""

import json

import numpy as np
import pytest

import plush_opt
from plush_opt.fem.attachments import AttachmentWeights
from plush_opt.base.errors import SceneError
from plush_opt.io import scene_from_dict
from plush_opt.fem.mesh import build_mesh
from plush_opt.solve.result_file import result_dict
from spec_checker import check_result
from test_model import assert_close, random_state

W, H = 20.0, 10.0


def _data(element="P1", radius=1.5, max_area=2.0, targets=True, **tendon):
    data = {
        "format": "plush-opt/1", "name": "strip",
        "mesh": {"outline": [[0, 0], [W, 0], [W, H], [0, H]], "max_area": max_area,
                 "element": element},
        "material": {"model": "neo_hookean", "youngs_modulus": 0.05, "poisson_ratio": 0.3,
                     "thickness": 5.0},
        "pins": {"stiffness": 100.0, "at": [[0, 0], [0, H], [0, H / 2]]},
        "winches": [{"name": "pull", "bounds": [0.0, 4.0]}, {"name": "lift", "bounds": [0.0, 3.0]}],
        "tendons": {"stiffness": 5.0, "smoothing": 0.05, "attachment_radius": radius, "list": [
            {"name": "low", "winch": "pull", "path": [[W, 2], [12, 2.5], [5, 2], [0.0, 2]], **tendon},
            {"name": "high", "winch": "lift", "path": [[W - 3, H], [10, 7], [0.0, 8]],
             "attachment_radius": 0.0}]},
    }
    if targets:
        data["targets"] = [{"at": [W, H / 2], "to": [W - 1.5, H / 2 + 1.0]}]
    return data


def _problem(element="P1", **kw):
    scene = scene_from_dict(_data(element, **kw), "strip.yaml")
    return plush_opt.problem.from_scene(scene)


# -- weights -------------------------------------------------------------------

@pytest.mark.parametrize("element", ["P1", "P2"])
@pytest.mark.parametrize("r", [0.4, 2.2])
def test_disc_inside_reproduces_linear_fields_and_area(element, r):
    mesh = build_mesh(scene_from_dict(_data(element), "strip.yaml"))
    finder = AttachmentWeights(mesh)
    p = np.array([9.3, 4.8])
    nodes, w = finder.weights(p, r, 0)
    assert abs(w.sum() - 1.0) <= 1e-15
    np.testing.assert_allclose(w @ mesh.X[nodes], p, rtol=0, atol=1e-6 * r)
    _, integral, area = finder.integrals(p, r)
    assert abs(area / (np.pi * r * r) - 1) < 1e-5
    assert abs(integral.sum() / area - 1) < 1e-12          # the N_i sum to 1


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_half_disc_at_a_straight_boundary_has_its_centroid_inward(element):
    mesh = build_mesh(scene_from_dict(_data(element), "strip.yaml"))
    finder = AttachmentWeights(mesh)
    r = 1.5
    for p, inward in (((12.0, 0.0), (0, 1)), ((W, 5.0), (-1, 0)), ((7.0, H), (0, -1))):
        nodes, w = finder.weights(np.array(p), r, 0)
        expected = np.array(p) + 4 * r / (3 * np.pi) * np.array(inward)
        np.testing.assert_allclose(w @ mesh.X[nodes], expected, rtol=0, atol=1e-5 * r)
        _, _, area = finder.integrals(np.array(p), r)
        assert abs(area / (np.pi * r * r / 2) - 1) < 1e-5


def test_quarter_disc_at_a_corner():
    mesh = build_mesh(scene_from_dict(_data(), "strip.yaml"))
    r = 1.2
    nodes, w = AttachmentWeights(mesh).weights(np.array([W, 0.0]), r, 0)
    c = 4 * r / (3 * np.pi)
    np.testing.assert_allclose(w @ mesh.X[nodes], [W - c, c], rtol=0, atol=1e-5 * r)
    _, _, area = AttachmentWeights(mesh).integrals(np.array([W, 0.0]), r)
    assert abs(area / (np.pi * r * r / 4) - 1) < 1e-5


def test_zero_radius_is_the_node_and_the_model_keeps_it():
    scene = scene_from_dict(_data(radius=0.0), "strip.yaml")
    mesh = build_mesh(scene)
    nodes, w = AttachmentWeights(mesh).weights(np.array([W, 2.0]), 0.0, 7)
    assert nodes.tolist() == [7] and w.tolist() == [1.0]
    model = plush_opt.problem.from_scene(scene).model
    for W_t, path in zip(model.via_weights, mesh.tendon_nodes):
        assert W_t.shape == (len(path), mesh.n_nodes)
        assert W_t.indices.tolist() == path.tolist() and np.all(W_t.data == 1.0)
    assert model.n_z == model.n_dofs


def test_model_weights_sum_to_one_and_the_assembly_length_uses_the_points():
    model = _problem().model
    W_low, W_high = model.via_weights
    assert np.all(np.abs(np.asarray(W_low.sum(axis=1)).ravel() - 1) < 1e-14)
    assert W_low.nnz > W_low.shape[0] and W_high.nnz == W_high.shape[0]
    P = W_low @ model.X.reshape(-1, 2)
    expected = np.linalg.norm(np.diff(P, axis=0), axis=1).sum()
    assert model.assembly_length[0] == pytest.approx(expected, rel=1e-14)
    # the boundary ends are pulled inward by 4 r / (3 pi): shorter than the path
    assert model.assembly_length[0] < 20.0 + 2 * 0.5


# -- the model ---------------------------------------------------------------------

@pytest.mark.parametrize("element", ["P1", "P2"])
def test_gradient_hessian_mixed_against_central_differences(element):
    model = _problem(element, max_area=6.0).model
    x, c = random_state(model, np.random.default_rng(3))
    ev = model.evaluate(x, c)
    h = 1e-4 * np.sqrt(np.mean(model.rest_area))
    n = model.n_dofs
    g_fd, H_fd = np.empty(n), np.empty((n, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = h
        g_fd[i] = (model.energy(x + e, c) - model.energy(x - e, c)) / (2 * h)
        H_fd[:, i] = (model.evaluate(x + e, c, 1).gradient - model.evaluate(x - e, c, 1).gradient) / (2 * h)
    assert_close(ev.gradient, g_fd, 1e-6, "gradient")
    assert_close(ev.hessian.toarray(), H_fd, 1e-6, "Hessian")
    M_fd = np.empty((n, model.n_winches))
    for w in range(model.n_winches):
        e = np.zeros(model.n_winches)
        e[w] = 1e-4
        M_fd[:, w] = (model.evaluate(x, c + e, 1).gradient - model.evaluate(x, c - e, 1).gradient) / 2e-4
    assert_close(model.mixed(x, c), M_fd, 1e-6, "mixed")
    # calibration's d2E/dx dd (assembly offsets) and the routing matrix
    D_fd = np.empty((n, model.n_tendons))
    base = model.assembly_length.copy()
    for t in range(model.n_tendons):
        grads = []
        for sign in (1, -1):
            model.assembly_length = base.copy()
            model.assembly_length[t] += sign * 1e-4
            grads.append(model.evaluate(x, c, 1).gradient)
        D_fd[:, t] = (grads[0] - grads[1]) / 2e-4
    model.assembly_length = base
    assert_close(model.parameter_mixed(x, c)["assembly_offset"], D_fd, 1e-6, "offset mixed")
    A = model.length_gradient(x)
    for t in range(model.n_tendons):
        l_fd = np.array([(model.tendon_state(x + e, c)["length"][t]
                          - model.tendon_state(x - e, c)["length"][t]) / (2 * h)
                         for e in np.eye(n) * h])
        assert_close(A[:, t], l_fd, 1e-6, "length gradient")


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_fast_evaluator_matches_casadi_expression(element):
    model = _problem(element, max_area=6.0).model
    x, c = random_state(model, np.random.default_rng(4))
    ev = model.evaluate(x, c)
    assert abs(ev.energy - float(model.E(x, c))) <= 1e-12 * max(1.0, abs(ev.energy))
    assert_close(ev.gradient, np.array(model.grad_E(x, c)).ravel(), 1e-12, "gradient")
    H_ca = model.hess_E(x, c).sparse()
    assert abs(ev.hessian - H_ca).max() <= 1e-11 * abs(H_ca).max()
    assert_close(model.mixed(x, c), np.array(model.mixed_E(x, c)), 1e-12, "mixed")
    pattern = ev.hessian.copy()
    pattern.data[:] = 1
    rows, cols = H_ca.nonzero()
    assert np.all(pattern[rows, cols] == 1)


# -- control and results ------------------------------------------------------------

@pytest.mark.parametrize("method", ["reparam", "bilevel"])
def test_control_runs_with_attachments(method):
    problem = _problem(max_area=4.0)
    start = problem.equilibrium()
    res = problem.control(method)
    assert res.converged, res.status
    assert problem.targets.value(res.x) < 0.1 * problem.targets.value(start.x)


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_result_file_round_trip_through_the_spec_checker(element):
    problem = _problem(element, max_area=8.0)
    eq = problem.equilibrium({"pull": 2.0, "lift": 1.0})
    assert eq.converged
    doc = json.loads(json.dumps(result_dict(
        problem.model, problem.targets, eq, method="forward", converged=eq.converged,
        status=eq.status, total_s=0.0, solve_s=0.0, iterations=eq.iterations)))
    low, high = doc["model"]["tendons"]["list"]
    assert "points" not in high
    assert len(low["points"]) == len(low["nodes"]) == 4
    for point, node in zip(low["points"], low["nodes"]):
        assert node in point["nodes"] and abs(sum(point["weights"]) - 1) < 1e-12
    check_result(doc)


# -- the reader ----------------------------------------------------------------------

@pytest.mark.parametrize("where, value, message", [
    ("all", -1.0, r"strip\.yaml: tendons\.attachment_radius: must be >= 0"),
    ("all", True, r"strip\.yaml: tendons\.attachment_radius: expected a number"),
    ("all", "2mm", r"strip\.yaml: tendons\.attachment_radius: expected a number"),
    ("all", float("inf"), r"strip\.yaml: tendons\.attachment_radius: expected a finite number"),
    ("one", -0.5, r"strip\.yaml: tendons\.list\[0\]\.attachment_radius: must be >= 0"),
    ("one", False, r"strip\.yaml: tendons\.list\[0\]\.attachment_radius: expected a number"),
    ("one", float("nan"), r"strip\.yaml: tendons\.list\[0\]\.attachment_radius: expected a finite"),
])
def test_reader_refuses_bad_radii(where, value, message):
    data = _data(radius=1.0) if where == "one" else _data(radius=value)
    if where == "one":
        data["tendons"]["list"][0]["attachment_radius"] = value
    with pytest.raises(SceneError, match=message) as e:
        scene_from_dict(data, "strip.yaml")
    assert "\n" not in str(e.value)


def test_reader_default_and_per_tendon_override():
    data = _data(radius=1.0)
    del data["tendons"]["attachment_radius"]
    scene = scene_from_dict(data, "strip.yaml")
    assert [t.attachment_radius for t in scene.tendons] == [0.0, 0.0]
    data["tendons"]["attachment_radius"] = 2
    data["tendons"]["list"][0]["attachment_radius"] = 0.5
    scene = scene_from_dict(data, "strip.yaml")
    assert [t.attachment_radius for t in scene.tendons] == [0.5, 0.0]
