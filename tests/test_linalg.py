"""The factorisation backends: CHOLMOD (the optional extra) and QDLDL (the
wheel-only fallback) give the same solves, verdicts and eigenvalues, and
the same forward and control results on a shipped problem."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from plush_opt.base import linalg, low_rank
from plush_opt.control.gradient import solve_control
from plush_opt.base.errors import SolverError
from plush_opt.base.linalg import PIVOT_MARGIN, Factorizer, NotPositiveDefinite
from plush_opt.problem import load

GRIPPER = Path(__file__).resolve().parent.parent / "problems" / "gripper.yaml"
INSTALLED = [b for b in linalg.BACKENDS if b == "qdldl" or linalg._cholmod_installed()]
# (backend, CHOLMOD mode): every factorisation the package can take
FACTORIZATIONS = [("qdldl", "auto")] + ([("cholmod", "simplicial"), ("cholmod", "supernodal")]
                                       if "cholmod" in INSTALLED else [])
needs_both = pytest.mark.skipif(len(INSTALLED) < 2, reason="CHOLMOD (the [cholmod] extra) not installed")

# the two backends factor the same matrix in different orders of operations
# (and read opposite triangles of a Hessian symmetric to round-off)
AGREE = 1e-9


@pytest.fixture(scope="module")
def hessian():
    """The gripper's Hessian at an equilibrium: positive definite, larger
    than the size where min_eigenvalue turns to Lanczos."""
    p = load(GRIPPER)
    eq = p.equilibrium({"left": 10.0})
    H = p.model.evaluate(eq.x, eq.contraction).hessian
    assert H.shape[0] > 200
    return H


def _dense_min_eig(H):
    return float(np.linalg.eigvalsh(H.toarray())[0])


@pytest.mark.parametrize("backend, mode", FACTORIZATIONS)
def test_backend_matches_dense_linear_algebra(hessian, backend, mode):
    H = hessian
    b = np.random.default_rng(3).standard_normal(H.shape[0])
    f = Factorizer(backend, mode).factor(H)
    x = f.solve(b)
    assert np.linalg.norm(H @ x - b) <= 1e-10 * np.linalg.norm(b)
    X = f.solve(np.column_stack([b, 2 * b]))
    # a block solve takes other BLAS paths than a vector solve: equal to round-off
    assert X.shape == (H.shape[0], 2) and np.linalg.norm(X[:, 1] - 2 * x) <= 1e-12 * np.linalg.norm(2 * x)
    assert f.min_eigenvalue() == pytest.approx(_dense_min_eig(H), rel=1e-6)


@pytest.mark.parametrize("backend, mode", FACTORIZATIONS)
def test_backend_refuses_an_indefinite_matrix_and_shifts_it(hessian, backend, mode):
    H = hessian
    lam = _dense_min_eig(H)
    fz = Factorizer(backend, mode)
    indefinite = (H - 2 * lam * sp.identity(H.shape[0], format="csc")).tocsc()
    with pytest.raises(NotPositiveDefinite, match="pivot"):
        fz.factor(indefinite)
    # the regularised shift makes it definite; Lanczos on that factor
    # finds the negative eigenvalue (-lam) of the unshifted matrix
    shifted = fz.factor(indefinite, shift=3 * lam)
    value, vector = shifted.most_negative_eigenpair()
    assert value == pytest.approx(-lam, rel=1e-6)
    assert np.linalg.norm(indefinite @ vector - value * vector) <= 1e-6 * abs(value)


@pytest.mark.parametrize("backend, mode", FACTORIZATIONS)
def test_backend_refuses_a_matrix_singular_to_round_off(backend, mode):
    """Positive pivots, one of them below PIVOT_MARGIN x the largest (in
    either elimination order the pivots multiply to the 2x2 block's
    determinant, 1e-14)."""
    block = sp.csc_matrix([[1.0, 1.0], [1.0, 1.0 + 1e-14]])
    singular = sp.block_diag([block, sp.identity(8)], format="csc")
    assert np.all(np.linalg.eigvalsh(singular.toarray()) > 0)
    with pytest.raises(NotPositiveDefinite, match=f"not above {PIVOT_MARGIN:g}"):
        Factorizer(backend, mode).factor(singular)


@needs_both
def test_cholmod_takes_supernodal_above_its_size(hessian, monkeypatch):
    """``auto`` is simplicial below SUPERNODAL_MIN_ENTRIES entries and
    supernodal from there on; both solve alike (to round-off)."""
    b = np.ones(hessian.shape[0])
    small = Factorizer("cholmod")
    x_small = small.factor(hessian).solve(b)
    assert small.mode_used == "simplicial"
    monkeypatch.setattr(linalg, "SUPERNODAL_MIN_ENTRIES", hessian.nnz)
    large = Factorizer("cholmod")
    x_large = large.factor(hessian).solve(b)
    assert large.mode_used == "supernodal"
    assert np.linalg.norm(x_large - x_small) <= AGREE * np.linalg.norm(x_small)
    monkeypatch.setattr(linalg, "SUPERNODAL_MIN_ENTRIES", 10 * hessian.nnz)
    monkeypatch.setattr(linalg, "SUPERNODAL_MIN_DENSITY", hessian.nnz / hessian.shape[0])
    dense = Factorizer("cholmod")
    dense.factor(hessian)
    assert dense.mode_used == "supernodal"        # dense enough, though small
    with pytest.raises(SolverError, match="factorisation mode 'dense'"):
        Factorizer("cholmod", "dense")


def test_a_factor_stays_valid_after_later_factorisations(hessian):
    """QDLDL refactors one solver in place: a Factor kept (an equilibrium's)
    must not change when the same Factorizer factors other matrices."""
    fz = Factorizer("qdldl")
    b = np.ones(hessian.shape[0])
    kept = fz.factor(hessian)
    x = kept.solve(b)
    for scale in (2.0, 3.0, 5.0):
        fz.factor(scale * hessian).solve(b)      # each dropped at once: its solver reused
    assert np.array_equal(kept.solve(b), x)


@needs_both
def test_backends_agree(hessian):
    H = hessian
    b = np.random.default_rng(5).standard_normal(H.shape[0])
    fa, fb = Factorizer("cholmod").factor(H), Factorizer("qdldl").factor(H)
    xa, xb = fa.solve(b), fb.solve(b)
    assert np.linalg.norm(xa - xb) <= AGREE * np.linalg.norm(xa)
    assert fb.min_eigenvalue() == pytest.approx(fa.min_eigenvalue(), rel=AGREE)
    lam = fa.min_eigenvalue()
    for delta, definite in ((0.5, True), (1.5, False)):
        M = (H - delta * lam * sp.identity(H.shape[0], format="csc")).tocsc()
        verdicts = []
        for backend in ("cholmod", "qdldl"):
            try:
                Factorizer(backend).factor(M)
                verdicts.append(True)
            except NotPositiveDefinite:
                verdicts.append(False)
        assert verdicts == [definite, definite]


def _forward_and_control(monkeypatch, backend):
    monkeypatch.setattr(linalg, "BACKEND", backend)
    p = load(GRIPPER)                      # its model's Factorizer takes BACKEND
    eq = p.equilibrium({"left": 10.0})
    res = solve_control(p.model, p.targets, p.scene.contraction)
    return eq, res


@needs_both
def test_forward_and_control_agree_on_gripper(monkeypatch):
    (eq_a, res_a), (eq_b, res_b) = (_forward_and_control(monkeypatch, b) for b in ("cholmod", "qdldl"))
    assert eq_a.converged and eq_b.converged and eq_a.iterations == eq_b.iterations
    assert np.linalg.norm(eq_b.x - eq_a.x) <= AGREE * np.linalg.norm(eq_a.x)
    assert eq_b.min_eigenvalue == pytest.approx(eq_a.min_eigenvalue, rel=AGREE)
    ca, cb = res_a.equilibrium.contraction, res_b.equilibrium.contraction
    assert np.linalg.norm(cb - ca) <= AGREE * np.linalg.norm(ca)
    assert res_b.objective == pytest.approx(res_a.objective, rel=AGREE)
    xa, xb = res_a.equilibrium.x, res_b.equilibrium.x
    assert np.linalg.norm(xb - xa) <= AGREE * np.linalg.norm(xa)


def test_environment_variable_forces_the_fallback():
    env = dict(os.environ, PLUSH_OPT_LINALG="qdldl")
    code = "from plush_opt.base import linalg; print(linalg.BACKEND, linalg.Factorizer().backend)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["qdldl", "qdldl"]


def test_unknown_backend_is_one_clear_error(monkeypatch):
    monkeypatch.setattr(linalg, "BACKEND", "umfpack")
    with pytest.raises(SolverError, match=r"^PLUSH_OPT_LINALG='umfpack': expected one of cholmod, qdldl$"):
        Factorizer()


def test_unknown_low_rank_factor_is_one_clear_error():
    with pytest.raises(SolverError, match=r"^low-rank factor 'lu': expected one of woodbury, augmented$"):
        Factorizer(low_rank="lu")


# -- the low-rank form: H = body + Q^T M Q ------------------------------------

def _low_rank(n=300, k=8, negative=0.0, seed=7):
    """A sparse SPD body (a 1D Laplacian plus I), a dense-ish Q and a
    symmetric M with both signs: ``negative`` scales its negative part."""
    rng = np.random.default_rng(seed)
    body = (sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(n, n))).tocsc()
    Q = sp.random(k, n, density=0.2, random_state=seed, format="csr")
    V = np.linalg.qr(rng.standard_normal((k, k)))[0]
    lam = np.r_[rng.uniform(0.5, 3.0, k - 2), -negative * np.ones(2)]
    return low_rank.LowRankHessian(body, Q, (V * lam) @ V.T)


@pytest.mark.parametrize("backend, mode", FACTORIZATIONS)
def test_low_rank_factor_solves_and_certifies_like_the_assembled_matrix(backend, mode):
    """Woodbury solves, the smallest eigenvalue, and the verdict, against
    the assembled matrix; M has negative eigenvalues that leave H definite."""
    H = _low_rank(negative=0.05)
    A = H.assemble()
    assert abs(A - A.T).max() == 0.0
    assert np.allclose(A.toarray(), H.body.toarray() + H.Q.T.toarray() @ H.M @ H.Q.toarray(), rtol=0, atol=1e-13)
    assert np.allclose(H.diagonal(), A.diagonal(), rtol=1e-13)
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    assert np.allclose(H @ b, A @ b, rtol=1e-13, atol=1e-13)
    f = Factorizer(backend, mode).factor(H)
    x = f.solve(b)
    assert np.linalg.norm(A @ x - b) <= 1e-12 * np.linalg.norm(b)
    X = f.solve(np.column_stack([b, -b]))
    assert np.linalg.norm(X[:, 1] + x) <= 1e-12 * np.linalg.norm(x)
    assert f.min_eigenvalue() == pytest.approx(_dense_min_eig(A), rel=1e-8)


@pytest.mark.parametrize("backend, mode", FACTORIZATIONS)
def test_a_low_rank_factor_with_another_low_rank_term_keeps_its_sparse_part(backend, mode):
    """``with_low_rank_of``: the kept body factor plus the other Hessian's
    low-rank term solves (body + Q2^T M2 Q2), refuses an indefinite term,
    and is None for an assembled factor or matrix."""
    H1, H2 = _low_rank(seed=7), _low_rank(seed=11, negative=0.05)
    f = Factorizer(backend, mode).factor(H1)
    g = f.with_low_rank_of(H2)
    mixed = (H1.body + H2.Q.T @ sp.csr_matrix(H2.M) @ H2.Q).toarray()
    b = np.random.default_rng(2).standard_normal(H1.shape[0])
    assert np.linalg.norm(mixed @ g.solve(b) - b) <= 1e-12 * np.linalg.norm(b)
    assert g.shift == f.shift and np.array_equal(g.H.body.toarray(), H1.body.toarray())
    assert f.with_low_rank_of(_low_rank(seed=11, negative=40.0)) is None
    assert f.with_low_rank_of(H2.assemble()) is None
    assert Factorizer(backend, mode).factor(H1.assemble()).with_low_rank_of(H2) is None


def _with_fast(n=300, seed=7, tendon=(1.0, 2.0, 3.0)):
    """A low-rank Hessian shaped as the split form's: two 2 x 2 blocks of M
    (segment couplings, rows 0-3), then one diagonal entry per tendon (its
    own row of Q, rows 4-6: ``fast``), then another 2 x 2 block (rows 7-8)."""
    rng = np.random.default_rng(seed)
    body = (sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(n, n))).tocsc()
    Q = sp.random(9, n, density=0.2, random_state=seed, format="csr")
    M = np.zeros((9, 9))
    for a in (0, 2, 7):
        B = rng.standard_normal((2, 2))
        M[a:a + 2, a:a + 2] = 0.005 * (B + B.T)         # (either sign: H stays definite)
    M[4:7, 4:7] = np.diag(tendon)
    return low_rank.LowRankHessian(body, Q, M, (4, 7))


@pytest.mark.parametrize("backend, mode", FACTORIZATIONS)
def test_a_refreshed_low_rank_term_takes_the_fast_rows_alone(backend, mode):
    """Where both Hessians name their ``fast`` rows (the tendons' own
    terms), ``with_low_rank_of`` keeps the factor's sparse part and its
    other low-rank rows and takes the fast rows of the newer Hessian: it
    solves with body1 + (Q, M of H1 with the fast rows of H2), and with a
    CHOLMOD factor its set-up substitutes only those rows' columns, giving
    what a set-up of the whole mixed Hessian gives, bit for bit."""
    H1 = _with_fast(seed=7)
    H2 = _with_fast(seed=11, tendon=(0.5, 4.0, 1e-20))       # (a slack tendon: dropped)
    f = Factorizer(backend, mode).factor(H1)
    g = f.with_low_rank_of(H2)
    Q = sp.vstack([H1.Q[:4], H2.Q[4:7], H1.Q[7:]]).toarray()
    M = H1.M.copy()
    M[4:7, 4:7] = H2.M[4:7, 4:7]
    mixed = H1.body.toarray() + Q.T @ M @ Q
    b = np.random.default_rng(3).standard_normal(H1.shape[0])
    assert np.linalg.norm(mixed @ g.solve(b) - b) <= 1e-12 * np.linalg.norm(b)
    assert g.H.fast == (4, 7) and np.array_equal(g.H.M, M) and np.array_equal(g.H.Q.toarray(), Q)
    whole = linalg.Factor(linalg._WoodburySolve(f._chol._body, g.H, 0.0), g.H, 0.0)
    assert np.array_equal(g.solve(b), whole.solve(b))
    if backend == "cholmod":
        assert np.array_equal(g._chol._Z, whole._chol._Z)
    # a Hessian naming no fast rows, or others: its whole low-rank term
    plain = low_rank.LowRankHessian(H2.body, H2.Q, H2.M)
    h = f.with_low_rank_of(plain)
    assert h.H.fast is None and np.array_equal(h.H.M, H2.M)


@pytest.mark.parametrize("backend, mode", FACTORIZATIONS)
def test_low_rank_factor_refuses_an_indefinite_or_singular_update(backend, mode):
    """A definite body, an update that makes H indefinite: refused, as the
    assembled matrix is; a shift past its negative eigenvalue is accepted,
    and Lanczos on that factor finds the eigenvalue. An update that makes H
    singular to round-off is refused too."""
    H = _low_rank(negative=40.0)
    A = H.assemble()
    lam = _dense_min_eig(A)
    assert lam < 0
    fz = Factorizer(backend, mode)
    with pytest.raises(NotPositiveDefinite, match="low-rank update"):
        fz.factor(H)
    with pytest.raises(NotPositiveDefinite):
        Factorizer(backend, mode).factor(A)
    shifted = fz.factor(H, shift=-2 * lam)
    value, vector = shifted.most_negative_eigenpair()
    assert value == pytest.approx(lam, rel=1e-6)
    # singular: body = I, M = -1 on a unit direction q (H q = 0)
    n = 50
    q = np.zeros(n)
    q[[3, 7]] = np.sqrt(0.5)
    singular = low_rank.LowRankHessian(sp.identity(n, format="csc"), sp.csr_matrix(q[None, :]), np.array([[-1.0]]))
    with pytest.raises(NotPositiveDefinite):
        Factorizer(backend, mode).factor(singular)


def _never_assembled(monkeypatch):
    def refuse(self):
        raise AssertionError("a low-rank Hessian was assembled")
    monkeypatch.setattr(low_rank.LowRankHessian, "assemble", refuse)


@pytest.mark.parametrize("backend, mode", FACTORIZATIONS)
def test_low_rank_with_an_indefinite_body_is_decided_on_the_whole(backend, mode, monkeypatch):
    """A body that is not positive definite on its own, held by a stiff
    positive update (a tendon holding a body that would buckle alone): H is
    definite, decided and solved on its augmented matrix, never assembled;
    a regularising shift is refused instead (a larger shift is all the
    caller needs)."""
    n = 40
    body = sp.diags(np.r_[-1.0, np.ones(n - 1)], 0, format="csc")
    e0 = np.zeros(n)
    e0[0] = 1.0
    H = low_rank.LowRankHessian(body, sp.csr_matrix(e0[None, :]), np.array([[5.0]]))
    _never_assembled(monkeypatch)
    f = Factorizer(backend, mode).factor(H)
    b = np.arange(1.0, n + 1)
    assert np.allclose(f.solve(b), b / np.r_[4.0, np.ones(n - 1)], rtol=1e-14)
    with pytest.raises(NotPositiveDefinite):
        Factorizer(backend, mode).factor(H, shift=0.5)


def _buckling(n=600, hold=(6.0, 6.0, 6.0), seed=3):
    """A body that buckles alone at three places (a 1D Laplacian with three
    soft nodes), each held by a tendon-like positive term spread over 6
    nodes (``hold``: their stiffnesses), plus segment-like 2 x 2 couplings of either sign, and
    the same Hessian assembled (dense, for the reference)."""
    rng = np.random.default_rng(seed)
    diag = np.full(n, 2.5)
    diag[[100, 300, 500]] = 0.2
    body = sp.diags([-1.0, diag, -1.0], [-1, 0, 1], shape=(n, n), format="csc")
    rows = []
    for at in (100, 300, 500, 200, 210):
        q = np.zeros(n)
        q[at - 3:at + 3] = rng.uniform(0.5, 1.0, 6)
        rows.append(q / np.linalg.norm(q))
    M = np.zeros((5, 5))
    M[:3, :3] = np.diag(hold)
    B = rng.standard_normal((2, 2))
    M[3:, 3:] = 0.3 * (B + B.T)
    H = low_rank.LowRankHessian(body, sp.csr_matrix(np.array(rows)), M)
    return H, body.toarray() + np.array(rows).T @ M @ np.array(rows)


@pytest.mark.parametrize("backend, mode", FACTORIZATIONS)
def test_a_buckling_body_held_by_its_tendons_is_certified_without_assembly(backend, mode, monkeypatch):
    """The body alone has three negative eigenvalues; its tendons hold it:
    H is positive definite, its solves and smallest eigenvalue match the
    dense matrix's, and nothing is assembled. Held too weakly, H is
    refused, and ``smallest_eigenpair`` finds its negative eigenvalue
    (through the augmented matrix, also unassembled)."""
    from plush_opt.base.eigenpair import smallest_eigenpair
    H, dense = _buckling()
    assert np.sum(np.linalg.eigvalsh(H.body.toarray()) < 0) == 3 and np.linalg.eigvalsh(dense)[0] > 0
    _never_assembled(monkeypatch)
    f = Factorizer(backend, mode).factor(H)
    b = np.random.default_rng(4).standard_normal(H.shape[0])
    x = f.solve(b)
    assert np.linalg.norm(dense @ x - b) <= 1e-12 * np.linalg.norm(b)
    assert f.min_eigenvalue() == pytest.approx(np.linalg.eigvalsh(dense)[0], rel=1e-8)
    assert smallest_eigenpair(H)[0] == pytest.approx(np.linalg.eigvalsh(dense)[0], rel=1e-8)
    weak, weak_dense = _buckling(hold=(6.0, 0.05, 6.0))
    lam = np.linalg.eigvalsh(weak_dense)
    assert lam[0] < 0 < lam[1]
    with pytest.raises(NotPositiveDefinite, match="1 negative"):
        Factorizer(backend, mode).factor(weak)
    value, vector = smallest_eigenpair(weak)
    assert value == pytest.approx(lam[0], rel=1e-8)
    assert np.linalg.norm(weak_dense @ vector - value * vector) <= 1e-8 * abs(value)
