"""The energy model: derivatives against central differences, the patch
test, the two evaluators against each other, invariances."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plush_opt.base.linalg import NotPositiveDefinite
from plush_opt.fem import elements
from plush_opt.fem import tendon_law
from plush_opt.io import scene_from_dict
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from shipped import PROBLEMS, built

SQRT_EPS = np.sqrt(np.finfo(float).eps)


def random_state(model, rng, amplitude=0.03, margin=2e-3):
    """An admissible pose near a real equilibrium, and contractions that
    leave some tendons slack, some in the smoothing zone, some taut.

    No tendon stretch lies within ``margin`` of +-epsilon, where the third
    derivative of U jumps and central differences of the gradient would
    straddle the joint (the joints themselves are tested on the kernel).
    """
    from plush_opt.solve.equilibrium import solve_equilibrium
    h = np.sqrt(np.mean(model.rest_area))
    eps = model.tendon_smoothing
    for _ in range(50):
        c = rng.uniform(model.lower, model.lower + 0.5 * (model.upper - model.lower))
        eq = solve_equilibrium(model, c)
        x = eq.x + amplitude * h * rng.standard_normal(model.n_dofs)
        G = model.tendon_state(x, c)["stretch"]
        if model.admissible(x) and np.all(np.abs(np.abs(G) - eps) > margin):
            return x, c
    raise AssertionError("no admissible perturbed pose away from the tendon joints")


def assert_close(actual, expected, rel, what):
    err = np.linalg.norm(np.asarray(actual) - np.asarray(expected))
    ref = max(np.linalg.norm(expected), 1e-300)
    assert err <= rel * ref, f"{what}: relative error {err / ref:.3e} > threshold {rel:.1e}"


@pytest.mark.slow
@pytest.mark.parametrize("name", PROBLEMS)
def test_gradient_hessian_mixed_against_central_differences(name):
    _, _, model, _ = built(name)
    rng = np.random.default_rng(1)
    x, c = random_state(model, rng)
    ev = model.evaluate(x, c)
    G = model.tendon_state(x, c)["stretch"]
    eps = model.tendon_smoothing
    print(f"{name}: tendons slack {np.sum(G <= -eps)}, smoothing zone {np.sum(np.abs(G) < eps)}, "
          f"taut {np.sum(G >= eps)}")
    h = 1e-4 * np.sqrt(np.mean(model.rest_area))
    # gradient: central differences of E, every coordinate
    g_fd = np.empty(model.n_dofs)
    for i in range(model.n_dofs):
        e = np.zeros(model.n_dofs)
        e[i] = h
        g_fd[i] = (model.energy(x + e, c) - model.energy(x - e, c)) / (2 * h)
    assert_close(ev.gradient, g_fd, 1e-6, f"{name} gradient")
    # Hessian: central differences of the gradient, every column
    H = ev.hessian.toarray()
    H_fd = np.empty_like(H)
    for i in range(model.n_dofs):
        e = np.zeros(model.n_dofs)
        e[i] = h
        H_fd[:, i] = (model.evaluate(x + e, c, 1).gradient - model.evaluate(x - e, c, 1).gradient) / (2 * h)
    assert_close(H, H_fd, 1e-6, f"{name} Hessian")
    assert np.allclose(H, H.T, rtol=0, atol=1e-12 * np.abs(H).max())
    # mixed derivative d2E/dx dc
    M = model.mixed(x, c)
    hc = 1e-4 * float(np.mean(model.upper - model.lower))
    M_fd = np.empty_like(M)
    for w in range(model.n_winches):
        e = np.zeros(model.n_winches)
        e[w] = hc
        M_fd[:, w] = (model.evaluate(x, c + e, 1).gradient - model.evaluate(x, c - e, 1).gradient) / (2 * hc)
    assert_close(M, M_fd, 1e-6, f"{name} mixed derivative")


@pytest.mark.slow
@pytest.mark.parametrize("name", PROBLEMS)
def test_fast_evaluator_matches_casadi_expression(name):
    _, _, model, _ = built(name)
    x, c = random_state(model, np.random.default_rng(2))
    ev = model.evaluate(x, c)
    assert abs(ev.energy - float(model.E(x, c))) <= 1e-12 * max(1.0, abs(ev.energy)) + 1e-12
    assert_close(ev.gradient, np.array(model.grad_E(x, c)).ravel(), 1e-12, "gradient")
    H_ca = model.hess_E(x, c).sparse()
    assert abs(ev.hessian - H_ca).max() <= 1e-11 * abs(H_ca).max()
    assert_close(model.mixed(x, c), np.array(model.mixed_E(x, c)), 1e-12, "mixed")
    # the fixed pattern holds every structural nonzero of CasADi's Hessian
    ca_rows, ca_cols = H_ca.nonzero()
    pattern = ev.hessian.copy()
    pattern.data[:] = 1
    assert np.all(pattern[ca_rows, ca_cols] == 1)


def _fd_kernel(fn, x0, args, h=1e-6):
    """Central-difference gradient and Hessian of a scalar CasADi kernel."""
    def f(x):
        return float(np.asarray(fn(x, *args)).ravel()[0])
    n = x0.size
    g = np.empty(n)
    for i in range(n):
        e = np.zeros(n)
        e[i] = h
        g[i] = (f(x0 + e) - f(x0 - e)) / (2 * h)
    return g


def test_element_kernel_alone():
    rng = np.random.default_rng(3)
    Dm = np.array([[10.0, 3.0], [0.5, 8.0]])
    Dinv = np.linalg.inv(Dm).T.reshape(-1)   # column-major
    X = np.array([0, 0, 10, 0.5, 3, 8.0])
    xe = X + rng.normal(scale=0.8, size=6)
    args = (Dinv, 4.0, 0.01, 0.02)
    psi, g, H = (np.array(v) for v in elements.P1_PSI_DERIVS(xe, *args))
    g_fd = _fd_kernel(lambda x, *a: elements.P1_PSI(x, *a), xe, args)
    assert_close(g.ravel(), g_fd, 1e-6, "element gradient")
    H_fd = np.empty((6, 6))
    for i in range(6):
        e = np.zeros(6)
        e[i] = 1e-6
        H_fd[:, i] = (np.array(elements.P1_PSI_DERIVS(xe + e, *args)[1]).ravel()
                      - np.array(elements.P1_PSI_DERIVS(xe - e, *args)[1]).ravel()) / 2e-6
    assert_close(H, H_fd, 1e-6, "element Hessian")
    # no deformation, no energy; rigid rotation neither
    assert abs(float(elements.P1_PSI(X, *args))) < 1e-14
    R = np.array([[np.cos(0.7), -np.sin(0.7)], [np.sin(0.7), np.cos(0.7)]])
    assert abs(float(elements.P1_PSI((X.reshape(3, 2) @ R.T).ravel() + 5, *args))) < 1e-12


def test_segment_kernel_alone():
    xs = np.array([1.0, 2.0, 4.0, -2.0])
    length, g, H = (np.array(v) for v in tendon_law.SEG_DERIVS(xs))
    assert abs(length.item() - 5.0) < 1e-14
    assert_close(g.ravel(), _fd_kernel(lambda x: tendon_law.SEG(x), xs, ()), 1e-8, "segment gradient")
    H_fd = np.empty((4, 4))
    for i in range(4):
        e = np.zeros(4)
        e[i] = 1e-6
        H_fd[:, i] = (np.array(tendon_law.SEG_DERIVS(xs + e)[1]).ravel()
                      - np.array(tendon_law.SEG_DERIVS(xs - e)[1]).ravel()) / 2e-6
    assert_close(H, H_fd, 1e-6, "segment Hessian")


@pytest.mark.parametrize("G", [-0.2, -0.05, -0.03, 0.0, 0.02, 0.05, 0.3])
def test_tendon_energy_at_below_and_above_epsilon(G):
    K, eps = 50.0, 0.05
    U, dU, d2U = (float(v) for v in tendon_law.U_DERIVS(G, K, eps))
    # the spec's piecewise definition
    if G <= -eps:
        assert U == 0 and dU == 0 and d2U == 0
    elif G < eps:
        assert U == pytest.approx(K * (G + eps) ** 3 / (6 * eps), rel=1e-14)
    else:
        assert U == pytest.approx(K * G**2 + K * eps**2 / 3, rel=1e-14)
    # derivatives against central differences, away from the joints
    h = 1e-7
    f = lambda g: float(tendon_law.U(g, K, eps))  # noqa: E731
    df = lambda g: float(tendon_law.U_DERIVS(g, K, eps)[1])  # noqa: E731
    if abs(abs(G) - eps) > 2 * h:
        assert dU == pytest.approx((f(G + h) - f(G - h)) / (2 * h), rel=1e-6, abs=1e-9)
        assert d2U == pytest.approx((df(G + h) - df(G - h)) / (2 * h), rel=1e-6, abs=1e-7)


@pytest.mark.parametrize("joint", [-0.05, 0.05])
def test_tendon_energy_is_c2_at_the_joints(joint):
    K, eps = 50.0, 0.05
    below = np.array([float(v) for v in tendon_law.U_DERIVS(joint - 1e-12, K, eps)])
    above = np.array([float(v) for v in tendon_law.U_DERIVS(joint + 1e-12, K, eps)])
    assert np.allclose(below, above, rtol=1e-9, atol=1e-9)


def _square_scene(n=4):
    return scene_from_dict({
        "format": "plush-opt/1", "name": "patch",
        "mesh": {"outline": [[0, 0], [10, 0], [10, 10], [0, 10]], "max_area": 100.0 / (n * n)},
        "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                     "thickness": 3.0},
        "pins": {"stiffness": 1000.0, "at": [[0, 0], [10, 0]]},
        "winches": [{"name": "w", "bounds": [-2.0, 1.0]}],
        "tendons": {"stiffness": 50.0, "smoothing": 0.05,
                    "list": [{"name": "t", "winch": "w", "path": [[5, 5], [5.5, 5]]}]},
    }, "patch.yaml")


@pytest.mark.parametrize("F", [np.array([[1.2, 0.0], [0.0, 0.9]]),
                               np.array([[1.1, 0.3], [-0.1, 0.95]])])
def test_patch_uniform_stretch_gives_analytic_piola_stress(F):
    scene = _square_scene()
    model = build_model(scene, build_mesh(scene))
    X = model.X.reshape(-1, 2)
    x = (X @ F.T).reshape(-1)
    c = np.array([-2.0])                     # tendon slack: elastic and pin forces only
    assert model.tendon_state(x, c)["tension"].max() == 0
    g = model.evaluate(x, c, 1).gradient.reshape(-1, 2)
    pins = model.pin_nodes
    g_el = g.copy()
    g_el[pins] -= scene.pin_stiffness * (x.reshape(-1, 2)[pins] - X[pins])
    # dE/dF = sum_i f_i (x) X_i ; P = dE/dF / volume
    P_model = g_el.T @ X / (scene.material.thickness * 100.0)
    mu, lam = scene.material.mu, scene.material.lam
    J = np.linalg.det(F)
    FinvT = np.linalg.inv(F).T
    P = mu * (F - FinvT) + lam * np.log(J) * FinvT
    assert np.allclose(P_model, P, rtol=1e-10, atol=1e-13)
    # interior nodes feel no force in a homogeneous deformation
    interior = np.all((X > 1e-9) & (X < 10 - 1e-9), axis=1)
    assert interior.any()
    assert np.abs(g_el[interior]).max() <= 1e-12 * np.abs(g_el).max()


def test_no_actuation_leaves_the_body_at_rest():
    from plush_opt.solve.equilibrium import solve_equilibrium
    _, _, model, _ = built("gripper")
    c = np.full(model.n_winches, -2 * model.tendon_smoothing)   # every tendon slack
    ev = model.evaluate(model.X, c)
    # zero up to rounding: the fillet's vertices are not binary fractions, so F = I
    # only to 1e-16 (2 mm of contraction stores 0.16 N mm)
    assert abs(ev.energy) < 1e-12 and np.abs(ev.gradient).max() < 1e-14
    assert np.all(model.tendon_state(model.X, c)["tension"] == 0)
    eq = solve_equilibrium(model, c)
    assert eq.converged and eq.iterations == 0 and np.array_equal(eq.x, model.X)


@pytest.mark.slow
@settings(max_examples=25, deadline=None)
@given(angle=st.floats(-np.pi, np.pi), tx=st.floats(-50, 50), ty=st.floats(-50, 50))
def test_energy_without_pins_is_invariant_under_rigid_motion(angle, tx, ty):
    _, _, model, _ = built("gripper")
    x, c = random_state(model, np.random.default_rng(4))
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    y = (x.reshape(-1, 2) @ R.T + [tx, ty]).reshape(-1)

    def without_pins(z):
        dp = z[model.pin_dofs] - model.X[model.pin_dofs]
        return model.energy(z, c) - 0.5 * model.pin_stiffness * dp @ dp

    assert without_pins(y) == pytest.approx(without_pins(x), rel=1e-9, abs=1e-12)


def test_inverted_pose_is_not_admissible():
    _, _, model, _ = built("gripper")
    x = model.X.copy().reshape(-1, 2)
    x[:, 0] *= -1                                   # mirror: every element inverted
    ev = model.evaluate(x.reshape(-1), np.zeros(model.n_winches))
    assert not ev.admissible and ev.energy == np.inf and ev.gradient is None


def test_gravity_term_only_when_the_scene_has_gravity():
    assert built("hexapod_leg")[2].has_gravity
    for name in ("gripper", "hexapod"):
        _, _, model, _ = built(name)
        assert not model.has_gravity and model.f_gravity is None
        assert "mtimes" not in str(model.E)  # no gravity dot product in the expression


# -- the model as a sum of terms -------------------------------------------------

@pytest.mark.parametrize("name", PROBLEMS)
def test_the_model_is_the_sum_of_its_terms(name):
    """The terms a scene has, in their order; E, its gradient, d2E/dx dc and
    the CasADi expression are the sums of the terms'."""
    import casadi as ca
    _, _, model, _ = built(name)
    expected = ("elastic", "pins") + (("gravity",) if model.has_gravity else ()) + ("tendons",)
    assert tuple(t.name for t in model.terms) == expected
    x, c = random_state(model, np.random.default_rng(12))
    parts = [t.evaluate(x, c, 1) for t in model.terms]
    ev = model.evaluate(x, c, 1)
    assert ev.energy == pytest.approx(sum(p.energy for p in parts), rel=1e-14)
    assert_close(ev.gradient, sum(p.gradient for p in parts), 1e-14, "gradient")
    assert ev.force_scale == max(p.force_scale for p in parts)
    assert_close(model.mixed(x, c), model.tendons.mixed(x, c), 1e-14, "mixed")
    xs, cs = ca.MX.sym("x", model.n_dofs), ca.MX.sym("c", model.n_winches)
    each = ca.Function("each", [xs, cs], [t.expression(xs, cs) for t in model.terms])(x, c)
    assert float(sum(float(v) for v in each)) == pytest.approx(ev.energy, rel=1e-12)


def test_models_share_the_compiled_kernels(monkeypatch):
    """A second model of the same kind compiles nothing: its element and
    tendon kernels are the ones their owners already hold."""
    from plush_opt.fem import kernel_set
    scene, mesh, model, _ = built("gripper")
    assert model.elastic.element.kernels is elements.named(str(mesh.element)).kernels
    calls = []
    monkeypatch.setattr(kernel_set, "compiled", lambda fn: calls.append(fn.name()) or fn)
    again = build_model(scene, mesh)
    again.evaluate(again.X, np.zeros(again.n_winches))
    assert calls == []


# -- the Hessian's forms: one matrix, or tendon terms kept as low rank --------

@pytest.fixture(scope="module")
def large_discs():
    """The gripper (attachment radius 2) on a P2 mesh fine enough that its
    discs hold more than SPLIT_MIN_DISC_NODES nodes: one model per form."""
    from plush_opt.fem.mesh import mesh_for_nodes
    from plush_opt.fem.model import Model
    from plush_opt.problem import load
    from shipped import ROOT
    scene = load(ROOT / "problems" / "gripper.yaml").scene.replace(element="P2")
    mesh = mesh_for_nodes(scene, 700)
    models = {form: Model(scene, mesh, hessian=form) for form in ("auto", "assembled", "rank_one", "split")}
    # every disc large enough for a stand-in on its heaviest node
    from plush_opt.fem import hessian_layout
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(hessian_layout, "STANDIN_MIN_DISC_NODES", 4)
        models["standin"] = Model(scene, mesh, hessian="split")
    return models


@pytest.mark.slow
def test_auto_splits_where_the_discs_are_large(large_discs, monkeypatch):
    from plush_opt.fem import model as model_module
    from plush_opt.fem.model import SPLIT_MIN_DISC_NODES, Model
    auto = large_discs["auto"]
    assert auto.tendon_points.mean_disc_nodes() >= SPLIT_MIN_DISC_NODES
    assert auto.low_rank and auto.split_segments
    assert not large_discs["assembled"].low_rank
    assert large_discs["rank_one"].low_rank and not large_discs["rank_one"].split_segments
    coarse = built("gripper")[2]            # its file mesh: small discs
    assert coarse.tendon_points.mean_disc_nodes() < SPLIT_MIN_DISC_NODES and not coarse.low_rank
    # an update of high rank: split, factored through its augmented matrix
    assert auto.factorizer.low_rank == "woodbury"
    monkeypatch.setattr(model_module, "SPLIT_MAX_RANK", auto.split_rank - 1)
    many = Model(auto.scene, auto.mesh)
    assert many.low_rank and many.split_segments and many.factorizer.low_rank == "augmented"


@pytest.mark.slow
def test_hessian_forms_agree_and_match_differences(large_discs):
    """Every form gives the same Hessian (assembled) and the same solves,
    at poses with slack, smoothing-zone and taut tendons; the split form's
    product with a direction matches central differences of the gradient."""
    ref = large_discs["assembled"]
    rng = np.random.default_rng(11)
    x, c = random_state(ref, rng)
    H = ref.evaluate(x, c).hessian
    scale = abs(H).max()
    v = rng.standard_normal(ref.n_dofs)
    for form in ("rank_one", "split", "standin"):
        model = large_discs[form]
        ev = model.evaluate(x, c)
        assert type(ev.hessian_form).__name__ == "LowRankHessian"
        assert abs(ev.hessian - H).max() <= 1e-12 * scale, form
        assert_close(ev.hessian_form @ v, H @ v, 1e-12, f"{form}: H v")
    model = large_discs["split"]
    h = 1e-6 * np.sqrt(np.mean(model.rest_area))
    fd = (model.evaluate(x + h * v, c, 1).gradient - model.evaluate(x - h * v, c, 1).gradient) / (2 * h)
    assert_close(model.evaluate(x, c).hessian_form @ v, fd, 1e-6, "split: H v against differences")


def test_a_large_disc_has_a_stand_in_in_the_sparse_part(large_discs):
    """With stand-ins the sparse part holds no disc's dense block: the
    element pattern alone (a stand-in's 2 x 2 block sits on one node); each
    large disc adds rank 4 to the low-rank term."""
    split, standin = large_discs["split"], large_discs["standin"]
    n_large = len(standin.hessian_layout._standin_dofs) // 2
    assert n_large == standin.tendon_points.n_extra > 0
    assert standin.hessian_layout.nnz < split.hessian_layout.nnz
    assert standin.hessian_layout.nnz == element_and_pin_nnz(standin)
    rng = np.random.default_rng(5)
    x, c = random_state(split, rng)
    a, b = split.evaluate(x, c).hessian_form, standin.evaluate(x, c).hessian_form
    assert b.Q.shape[0] == a.Q.shape[0] + 4 * n_large
    assert b.body.nnz == standin.hessian_layout.nnz


def element_and_pin_nnz(model) -> int:
    """Entries of the element and pin pattern alone."""
    from plush_opt.fem.hessian_layout import HessianLayout
    return HessianLayout(model.n_dofs, model.elem_dofs, model.pin_dofs, model.tendon_points,
                         np.zeros((0, 4), np.int64), np.zeros((0, 1), np.int64), "assembled").nnz


@pytest.mark.slow
def test_equilibria_agree_across_hessian_forms(large_discs):
    from plush_opt.base.linalg import Factorizer
    from plush_opt.fem.model import Model
    from plush_opt.solve.equilibrium import solve_equilibrium
    model = large_discs["assembled"]
    c = model.lower + 0.6 * (model.upper - model.lower)
    ref = solve_equilibrium(model, c)
    assert ref.converged
    augmented = Model(model.scene, model.mesh, hessian="split")      # factored through its augmented matrix
    augmented.factorizer = Factorizer(low_rank="augmented")
    for form, m in [(f, large_discs[f]) for f in ("rank_one", "split", "standin")] + [("augmented", augmented)]:
        eq = solve_equilibrium(m, c)
        assert eq.converged and eq.positive_definite, form
        assert np.abs(eq.x - ref.x).max() <= 1e-9 * np.abs(ref.x).max(), form
        assert eq.min_eigenvalue == pytest.approx(ref.min_eigenvalue, rel=1e-6), form


class _BodyRefused:
    """A body factorizer that calls every unshifted body not positive
    definite: the low-rank factor then decides H on its augmented matrix."""

    def __init__(self, inner):
        self.inner = inner

    @property
    def mode_used(self):
        return self.inner.mode_used

    def factor(self, H, shift=0.0, definite=True):
        if shift == 0.0:
            raise NotPositiveDefinite("refused by the test")
        return self.inner.factor(H, shift, definite)


@pytest.mark.slow
def test_equilibria_agree_when_the_body_alone_is_not_definite(large_discs, monkeypatch):
    """Where the sparse part alone is not positive definite (a body held
    by its tendons), Newton factors, certifies and finds the smallest
    eigenvalue on the augmented matrix, never assembling H: the same
    equilibrium as the assembled form."""
    from plush_opt.base import linalg, low_rank
    from plush_opt.solve.equilibrium import solve_equilibrium
    model = large_discs["assembled"]
    c = model.lower + 0.6 * (model.upper - model.lower)
    ref = solve_equilibrium(model, c)
    part = linalg.Factorizer._part
    monkeypatch.setattr(linalg.Factorizer, "_part",
                        lambda self, name, mode=None: (_BodyRefused(part(self, name, mode)) if name == "body"
                                                       else part(self, name, mode)))
    monkeypatch.setattr(low_rank.LowRankHessian, "assemble", lambda self: pytest.fail("H assembled"))
    for form in ("split", "standin"):
        eq = solve_equilibrium(large_discs[form], c)
        assert eq.converged and eq.positive_definite, form
        assert np.abs(eq.x - ref.x).max() <= 1e-9 * np.abs(ref.x).max(), form
        assert eq.min_eigenvalue == pytest.approx(ref.min_eigenvalue, rel=1e-6), form
