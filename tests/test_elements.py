"""Quadratic (P2) elements: the kernel and the assembled model against
central differences, patch tests (linear and quadratic fields), gravity and
targets through the six shape functions, the reader, the mesh, result
files, and the cantilever against beam theory."""

import json

import numpy as np
import pytest

from plush_opt.fem import elements
from plush_opt.base.errors import SceneError
from plush_opt.io import scene_from_dict
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from plush_opt.fem.objective import Targets
from plush_opt.solve.result_file import model_dict

SIDE = 10.0
THICKNESS = 3.0
DENSITY = 2.0
GRAVITY = [0.3, -1.0]


def _assert_close(actual, expected, rel, what):
    err = np.linalg.norm(np.asarray(actual) - np.asarray(expected))
    ref = max(np.linalg.norm(expected), 1e-300)
    assert err <= rel * ref, f"{what}: relative error {err / ref:.3e} > {rel:.1e}"


def _square(element="P2", n=3, **extra):
    data = {
        "format": "plush-opt/1", "name": "square",
        "mesh": {"outline": [[0, 0], [SIDE, 0], [SIDE, SIDE], [0, SIDE]],
                 "max_area": SIDE * SIDE / (n * n), "element": element},
        "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                     "thickness": THICKNESS, "density": DENSITY},
        "gravity": GRAVITY,
        "pins": {"stiffness": 1000.0, "at": [[0, 0], [SIDE, 0]]},
        "winches": [{"name": "w", "bounds": [-2.0, 1.0]}],
        "tendons": {"stiffness": 50.0, "smoothing": 0.05,
                    "list": [{"name": "t", "winch": "w", "path": [[5, 5], [5.5, 5], [7, 6]]}]},
        "targets": [{"at": [3.3, 7.1], "to": [3.0, 7.0]}],
    }
    data.update(extra)
    return scene_from_dict(data, "square.yaml")


def _built(element="P2", n=3):
    scene = _square(element, n)
    mesh = build_mesh(scene)
    return scene, mesh, build_model(scene, mesh)


def _elastic(model, x, c):
    """E without pins, gravity and tendons (the slack tendon adds nothing)."""
    dp = x[model.pin_dofs] - model.X[model.pin_dofs]
    return (model.energy(x, c) - 0.5 * model.pin_stiffness * dp @ dp + model.f_gravity @ x)


# -- the kernel --------------------------------------------------------------

def test_p2_kernel_gradient_hessian_against_central_differences():
    rng = np.random.default_rng(5)
    corners = np.array([[0, 0], [10, 0.5], [3, 8.0]])
    mids = 0.5 * (corners + corners[[1, 2, 0]])
    X = np.vstack([corners, mids]).reshape(-1)
    Dm = np.stack([corners[1] - corners[0], corners[2] - corners[0]], axis=1)
    args = (np.linalg.inv(Dm).T.reshape(-1), 4.0, 0.01, 0.02)
    xe = X + rng.normal(scale=0.5, size=12)
    psi, g, H = (np.array(v) for v in elements.P2_PSI_DERIVS(xe, *args))
    h = 1e-6
    g_fd = np.array([(float(elements.P2_PSI(xe + h * e, *args)) - float(elements.P2_PSI(xe - h * e, *args)))
                     / (2 * h) for e in np.eye(12)])
    _assert_close(g.ravel(), g_fd, 1e-6, "P2 element gradient")
    H_fd = np.stack([(np.array(elements.P2_PSI_DERIVS(xe + h * e, *args)[1]).ravel()
                      - np.array(elements.P2_PSI_DERIVS(xe - h * e, *args)[1]).ravel()) / (2 * h)
                     for e in np.eye(12)], axis=1)
    _assert_close(H, H_fd, 1e-6, "P2 element Hessian")
    assert abs(float(elements.P2_PSI(X, *args))) < 1e-14
    R = np.array([[np.cos(0.7), -np.sin(0.7)], [np.sin(0.7), np.cos(0.7)]])
    assert abs(float(elements.P2_PSI((X.reshape(6, 2) @ R.T).ravel() + 5, *args))) < 1e-12


def test_shape_functions_partition_unity_and_reproduce_quadratics():
    rng = np.random.default_rng(2)
    beta = rng.dirichlet(np.ones(3), size=20)
    N = elements.shape_values(beta)
    assert np.allclose(N.sum(axis=1), 1.0, atol=1e-15)
    corners = rng.normal(size=(3, 2))
    nodes = np.vstack([corners, 0.5 * (corners + corners[[1, 2, 0]])])
    def field(p):
        return np.stack([p[:, 0] ** 2 - p[:, 1], p[:, 0] * p[:, 1] + 3], axis=1)
    points = beta @ corners
    assert np.allclose(N @ field(nodes), field(points), atol=1e-13)


def test_the_element_is_an_object_on_the_mesh_named_as_in_files():
    import pickle
    p1, p2 = build_mesh(_square("P1")), build_mesh(_square("P2"))
    assert p1.element is elements.P1 and p2.element is elements.P2
    assert (str(p1.element), p2.element.name) == ("P1", "P2")
    assert elements.named("P2") is elements.P2 and elements.with_nodes(3) is elements.P1
    assert pickle.loads(pickle.dumps(p2)).element is elements.P2 and pickle.loads(pickle.dumps(p2)) == p2
    assert p2.elements.shape[1] == elements.P2.nodes and p1.elements is p1.triangles
    beta = np.array([[0.2, 0.3, 0.5]])
    assert np.array_equal(elements.P1.interpolation_weights(beta), beta)
    assert np.array_equal(elements.P2.interpolation_weights(beta), elements.shape_values(beta))
    with pytest.raises(ValueError, match="P3"):
        elements.named("P3")


# -- the model ---------------------------------------------------------------

def test_p2_model_gradient_hessian_mixed_against_central_differences():
    scene, mesh, model = _built()
    assert model.element is elements.P2 and model.elem_dofs.shape[1] == 12
    rng = np.random.default_rng(7)
    h_len = np.sqrt(np.mean(model.rest_area))
    x = model.X + 0.03 * h_len * rng.standard_normal(model.n_dofs)
    c = np.array([0.4])                         # tendon taut: a mixed derivative to test
    assert model.admissible(x) and model.tendon_state(x, c)["stretch"][0] > 0.05
    ev = model.evaluate(x, c)
    h = 1e-4 * h_len
    eye = np.eye(model.n_dofs)
    g_fd = np.array([(model.energy(x + h * e, c) - model.energy(x - h * e, c)) / (2 * h) for e in eye])
    _assert_close(ev.gradient, g_fd, 1e-6, "P2 gradient")
    H_fd = np.stack([(model.evaluate(x + h * e, c, 1).gradient - model.evaluate(x - h * e, c, 1).gradient)
                     / (2 * h) for e in eye], axis=1)
    _assert_close(ev.hessian.toarray(), H_fd, 1e-6, "P2 Hessian")
    hc = 1e-5
    M_fd = (model.evaluate(x, c + hc, 1).gradient - model.evaluate(x, c - hc, 1).gradient) / (2 * hc)
    _assert_close(model.mixed(x, c)[:, 0], M_fd, 1e-6, "P2 mixed derivative")
    # the CasADi expression (IPOPT's) agrees with the fast path
    assert float(model.E(x, c)) == pytest.approx(ev.energy, rel=1e-12)
    _assert_close(np.array(model.grad_E(x, c)).ravel(), ev.gradient, 1e-10, "CasADi gradient")
    _assert_close(np.array(model.hess_E(x, c)), ev.hessian.toarray(), 1e-10, "CasADi Hessian")
    _assert_close(np.array(model.mixed_E(x, c)).ravel(), model.mixed(x, c)[:, 0], 1e-10, "CasADi mixed")


@pytest.mark.parametrize("element", ["P1", "P2"])
@pytest.mark.parametrize("F", [np.array([[1.2, 0.0], [0.0, 0.9]]), np.array([[1.1, 0.3], [-0.1, 0.95]])])
def test_patch_linear_field_exact(element, F):
    scene, mesh, model = _built(element)
    X = model.X.reshape(-1, 2)
    x = (X @ F.T).reshape(-1)
    c = np.array([-2.0])                        # tendon slack
    mu, lam = scene.material.mu, scene.material.lam
    J = np.linalg.det(F)
    psi = mu / 2 * (np.sum(F * F) - 2) - mu * np.log(J) + lam / 2 * np.log(J) ** 2
    assert _elastic(model, x, c) == pytest.approx(psi * THICKNESS * SIDE**2, rel=1e-12)
    g = model.evaluate(x, c, 1).gradient.reshape(-1, 2) + model.f_gravity.reshape(-1, 2)
    pins = model.pin_nodes
    g[pins] -= scene.pin_stiffness * (x.reshape(-1, 2)[pins] - X[pins])
    interior = np.all((X > 1e-9) & (X < SIDE - 1e-9), axis=1)
    assert interior.sum() > 2
    assert np.abs(g[interior]).max() <= 1e-12 * np.abs(g).max()


def _quadratic_field(X, a=0.01):
    return np.stack([X[:, 0] + a * X[:, 0] ** 2, X[:, 1] + a * X[:, 0] * X[:, 1]], axis=1)


def _quadratic_gradient(p, a=0.01):
    return np.array([[[1 + 2 * a * x, 0], [a * y, 1 + a * x]] for x, y in p])


def test_patch_quadratic_field_reproduced_at_the_quadrature_points():
    """A P2 mesh holds a quadratic field exactly: F at every quadrature point
    is the field's own gradient there, so the energy is the 3-point rule of
    the exact Psi, and gravity is the exact integral."""
    scene, mesh, model = _built("P2")
    X = model.X.reshape(-1, 2)
    x = _quadratic_field(X).reshape(-1)
    c = np.array([-2.0])
    corners = X[mesh.triangles]                              # (n_elems, 3, 2)
    mu, lam = scene.material.mu, scene.material.lam
    expected, jmin = 0.0, np.inf
    for lq in elements.P2_QUAD_POINTS:
        F = _quadratic_gradient(np.einsum("j,ejd->ed", lq, corners))
        J = np.linalg.det(F)
        jmin = min(jmin, J.min())
        psi = mu / 2 * (np.sum(F * F, axis=(1, 2)) - 2) - mu * np.log(J) + lam / 2 * np.log(J) ** 2
        expected += THICKNESS * np.sum(model.rest_area * psi) / 3
    assert _elastic(model, x, c) == pytest.approx(expected, rel=1e-12)
    assert model.jacobians(x).min() == pytest.approx(jmin, rel=1e-12)
    # gravity: -rho t g . integral of x over the square, exactly
    a = 0.01
    integral = np.array([SIDE**3 / 2 + a * SIDE**4 / 3, SIDE**3 / 2 + a * SIDE**4 / 4])
    assert model.f_gravity @ x == pytest.approx(DENSITY * THICKNESS * np.dot(GRAVITY, integral), rel=1e-12)
    assert np.all(model.f_gravity.reshape(-1, 2)[: mesh.triangles.max() + 1] == 0)   # corners carry none


def test_admissibility_is_checked_at_every_quadrature_point():
    scene, mesh, model = _built("P2")
    x = model.X.reshape(-1, 2).copy()
    e = 0
    a, b, c_, ab = mesh.elements[e, :4]
    # fold the element through a midside node: corners untouched, J < 0 near ab
    x[ab] = x[c_] + 1.8 * (0.5 * (x[a] + x[b]) - x[c_])
    d1, d2 = x[b] - x[a], x[c_] - x[a]
    assert d1[0] * d2[1] - d1[1] * d2[0] > 0        # the corner triangle is fine
    assert not model.admissible(x.reshape(-1))
    assert model.energy(x.reshape(-1), np.zeros(1)) == np.inf


def test_full_bilevel_jacobian_constraint_matches_the_model():
    import casadi as ca
    _, _, model = _built("P2")
    rng = np.random.default_rng(3)
    x = model.X + 0.05 * rng.standard_normal(model.n_dofs)
    xs = ca.MX.sym("x", model.n_dofs)
    J = ca.Function("J", [xs], [model.jacobian_expression(xs)])(x)
    J = np.array(J).reshape(3, -1).T
    assert J.shape == (model.n_elems, 3)
    assert np.allclose(J.min(axis=1), model.jacobians(x), rtol=1e-12)


# -- mesh, targets, reader, results ------------------------------------------

def test_p2_mesh_keeps_the_p1_corners_and_adds_midpoints():
    p1 = build_mesh(_square("P1"))
    p2 = build_mesh(_square("P2"))
    n = p1.n_nodes
    assert np.array_equal(p2.X[:n], p1.X) and np.array_equal(p2.triangles, p1.triangles)
    assert np.array_equal(p2.elements[:, :3], p1.triangles)
    X = p2.X
    for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        assert np.allclose(X[p2.elements[:, 3 + k]], 0.5 * (X[p2.elements[:, i]] + X[p2.elements[:, j]]))
    edges = {frozenset(e) for t in p1.triangles.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    assert p2.n_nodes == n + len(edges)
    assert all(np.array_equal(a, b) for a, b in zip(p1.tendon_nodes, p2.tendon_nodes))
    boxed = build_mesh(_square("P2", pins={"stiffness": 1000.0, "at": [[0, 0]], "box": [0, 0, SIDE, 0]}))
    on_edge = np.flatnonzero(np.abs(boxed.X[:, 1]) < 1e-9)
    assert np.array_equal(boxed.pin_nodes, on_edge) and on_edge.max() >= n   # midside nodes pinned too


def test_targets_through_the_six_shape_functions():
    scene, mesh, model = _built("P2")
    targets = Targets.from_mesh(mesh, scene)
    assert targets.nodes.shape == (1, 6) and targets.beta.shape == (1, 3)
    assert np.allclose(targets.y(model.X), [[3.3, 7.1]], atol=1e-12)
    x = _quadratic_field(model.X.reshape(-1, 2)).reshape(-1)
    assert np.allclose(targets.y(x), _quadratic_field(np.array([[3.3, 7.1]])), atol=1e-12)
    B = targets.selection(model.n_dofs)
    assert np.allclose(B @ x, targets.y(x).ravel(), atol=1e-12)
    h, g = 1e-6, targets.gradient(x)
    g_fd = [(targets.value(x + h * e) - targets.value(x - h * e)) / (2 * h) for e in np.eye(model.n_dofs)]
    _assert_close(g, g_fd, 1e-7, "objective gradient")


def test_result_file_records_the_element():
    scene, mesh, model = _built("P2")
    d = json.loads(json.dumps(model_dict(model, Targets.from_mesh(mesh, scene))))
    assert d["element"] == "P2" and len(d["triangles"][0]) == 6
    assert len(d["targets"][0]["barycentric"]) == 3
    _, _, p1 = _built("P1")
    d1 = model_dict(p1, Targets.empty())
    assert d1["element"] == "P1" and len(d1["triangles"][0]) == 3


def _explicit(element, triangles, nodes, **extra):
    return scene_from_dict({
        "format": "plush-opt/1", "name": "explicit",
        "mesh": {"nodes": nodes, "triangles": triangles, "element": element},
        "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                     "thickness": 3.0},
        "pins": {"stiffness": 1000.0, "at": [[0, 0], [2, 0]]},
        "winches": [{"name": "w", "bounds": [0.0, 1.0]}],
        "tendons": {"stiffness": 50.0, "smoothing": 0.05,
                    "list": [{"name": "t", "winch": "w", "path": [[0, 0], [0, 2]]}]},
        **extra}, "explicit.yaml")


NODES = [[0, 0], [2, 0], [0, 2], [1, 0], [1, 1], [0, 1]]


def test_explicit_p2_mesh_loads_and_orients():
    scene = _explicit("P2", [[0, 2, 1, 5, 4, 3]], NODES)      # clockwise as given
    mesh = build_mesh(scene)
    assert mesh.elements.tolist() == [[0, 1, 2, 3, 4, 5]]
    model = build_model(scene, mesh)
    assert np.allclose(model.jacobians(model.X), 1.0, rtol=1e-14)
    eps, K = scene.tendon_smoothing, scene.tendon_stiffness
    assert model.energy(model.X, np.zeros(1)) == pytest.approx(K * eps**2 / 6, rel=1e-12)   # U(0)


@pytest.mark.parametrize("element, triangles, nodes, message", [
    ("P3", [[0, 1, 2]], NODES[:3], r"mesh\.element: must be one of P1, P2, got 'P3'"),
    (1, [[0, 1, 2]], NODES[:3], r"mesh\.element: expected a string"),
    ("P2", [[0, 1, 2]], NODES, r"mesh\.triangles\[0\]: expected six node indices"),
    ("P2", [[0, 1, 2, 3, 4, 5]], [*NODES[:4], [1.2, 1], NODES[5]],
     r"mesh\.triangles\[0\]\[4\]: midside node 4 is not at the midpoint of its edge"),
])
def test_reader_refuses_bad_p2_input(element, triangles, nodes, message):
    with pytest.raises(SceneError, match=message):
        _explicit(element, triangles, nodes)


def test_forced_points_must_be_corner_nodes():
    with pytest.raises(SceneError, match=r"points\[0\]: point is a midside node"):
        build_mesh(_explicit("P2", [[0, 1, 2, 3, 4, 5]], NODES, points=[[1, 1]]))


# -- accuracy: the cantilever -------------------------------------------------

def test_cantilever_p2_within_one_percent_of_beam_theory_on_a_coarse_mesh():
    from plush_opt.apps.cantilever import deflection_rows
    rows = {(r["element"], r["max_area"]): r for r in deflection_rows(areas=(16.0, 4.0))}
    assert all(r["converged"] for r in rows.values())
    assert abs(rows["P2", 16.0]["error"]) < 0.01
    # P1 locks in bending: converges from below, slowly
    assert rows["P1", 16.0]["error"] < rows["P1", 4.0]["error"] < -0.05
    # about as many nodes, a tenth of the error
    assert rows["P2", 16.0]["nodes"] < 1.1 * rows["P1", 4.0]["nodes"]
    assert abs(rows["P2", 16.0]["error"]) < 0.1 * abs(rows["P1", 4.0]["error"])


@pytest.mark.parametrize("method", ["reparam", "clip", "bilevel"])
def test_p2_control_result_passes_the_spec_checker(tmp_path, method):
    """Every control method runs on a P2 mesh; the result file rebuilds."""
    import yaml

    from plush_opt import load
    from spec_checker import check_result
    data = {
        "format": "plush-opt/1", "name": "square_p2",
        "mesh": {"outline": [[0, 0], [20, 0], [20, 40], [0, 40]], "max_area": 40.0, "element": "P2"},
        "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                     "thickness": 3.0, "density": 1e-9},
        "gravity": [0.0, -9810.0],
        "pins": {"stiffness": 1000.0, "at": [[0, 0], [20, 0]], "box": [0, 0, 20, 0]},
        "winches": [{"name": "w", "bounds": [0.0, 5.0]}],
        "tendons": {"stiffness": 50.0, "smoothing": 0.05,
                    "list": [{"name": "t", "winch": "w", "path": [[2, 0], [2, 20], [2, 40]]}]},
        "targets": [{"at": [10, 40], "to": [6, 39]}],
    }
    path = tmp_path / "square_p2.yaml"
    path.write_text(yaml.safe_dump(data))
    problem = load(path)
    result = problem.control(method)
    assert result.converged and result.objective < 1.0
    result.save(tmp_path / "r.json")
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["model"]["element"] == "P2"
    if method != "clip":         # the spec checker knows the spec's three method names
        check_result(doc)


def test_transfer_pose_carries_a_quadratic_field_between_p2_meshes():
    from plush_opt.solve.accuracy import transfer_pose
    coarse, fine = build_mesh(_square("P2", 2)), build_mesh(_square("P2", 5))
    x = _quadratic_field(coarse.X).reshape(-1)
    assert np.allclose(transfer_pose(coarse, x, fine), _quadratic_field(fine.X).reshape(-1), atol=1e-12)


@pytest.mark.parametrize("element", ["P1", "P2"])
@pytest.mark.parametrize("count", ["least", 2000, 2100])
def test_kernels_compiled_with_their_loop_compute_what_the_per_element_calls_do(element, count):
    """From COMPILE_MAPPED_MIN elements the mapped kernel runs as a compiled loop in chunks
    (one padded chunk of each size, several small ones): the same numbers, to the last
    bit, as one call per element."""
    from plush_opt.fem.mapped import COMPILE_MAPPED_MIN, COMPILED_CHUNKS, Mapped
    kernels = elements.named(element).kernels
    count = COMPILE_MAPPED_MIN if count == "least" else count
    rng = np.random.default_rng(3)
    rest = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0] + ([0.5, 0.0, 0.5, 0.5, 0.0, 0.5] if element == "P2" else [])
    xe = np.array(rest) + rng.uniform(-0.05, 0.05, (count, len(rest)))
    consts = {1: np.tile([1.0, 0.0, 0.0, 1.0], (count, 1)), 2: np.full(count, 0.5),
              3: np.full(count, 2.0), 4: np.full(count, 5.0)}
    for name, n_out in (("psi", 1), ("psi_grad", 2), ("psi_derivs", 3)):
        whole = Mapped(kernels[name], count, consts, kernels.symbolic[name])
        per_element = Mapped(kernels[name], count, consts)
        assert whole.chunk in COMPILED_CHUNKS          # (the compiled loop)
        for a, b in zip(whole(xe, n_out), per_element(xe, n_out)):
            assert np.all(np.isfinite(a)) and np.array_equal(a, b)


def test_the_compiled_loop_takes_the_chunk_that_costs_least():
    """A small mesh is not padded to the large chunk; a large one is cut into large chunks."""
    from plush_opt.fem.mapped import COMPILED_CHUNKS, chunk_for
    small, large = min(COMPILED_CHUNKS), max(COMPILED_CHUNKS)
    assert chunk_for(300) == small          # one small chunk, not one large one mostly padding
    assert chunk_for(1800) == large         # one large chunk, not four small ones
    assert chunk_for(large + 52) == small   # five small ones, not two large ones half padding
    assert chunk_for(60_000) == large
