"""Sparse symmetric factorisation: an LDL^T with the symbolic analysis done
once per sparsity pattern, a positive-definiteness test for free, and a
cheap smallest-eigenvalue estimate from the factor. A matrix given as a
sparse part plus a low-rank term (:class:`LowRankHessian`) is factored
through its sparse part and the Woodbury identity, or (where that part
alone is not positive definite, or the term's rank is high) through its
sparse augmented matrix, never assembled.

Two backends, the same results to round-off:

- ``cholmod``: CHOLMOD (scikit-sparse, the ``[cholmod]`` extra; needs the
  SuiteSparse headers to build). Used when installed.
- ``qdldl``: QDLDL (a wheel on every platform, a normal dependency). Used
  when CHOLMOD is not installed, or when forced.

The environment variable ``PLUSH_OPT_LINALG`` (``cholmod`` or ``qdldl``)
forces one; :data:`BACKEND` names the one in use.
"""

from __future__ import annotations

import logging
import os
import weakref

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import SettingError, SolverError
from .low_rank import LowRankHessian, assembled, eigen_blocks, in_span, with_fast_rows

log = logging.getLogger(__name__)

#: the backends, fastest first
BACKENDS = ("cholmod", "qdldl")
#: environment variable forcing a backend (empty: the fastest installed)
ENV_VAR = "PLUSH_OPT_LINALG"


def _cholmod_installed() -> bool:
    try:
        import sksparse.cholmod  # noqa: F401
    except ImportError:
        return False
    return True


def _default_backend() -> str:
    forced = os.environ.get(ENV_VAR, "").strip().lower()
    if forced:
        return forced           # checked when a Factorizer is made: an error there is one line
    return "cholmod" if _cholmod_installed() else "qdldl"


#: name of the backend new :class:`Factorizer` objects use
BACKEND = _default_backend()


# From this many entries of the matrix factored CHOLMOD's supernodal LL^T
# (dense BLAS on the supernodes) beats its simplicial LDL^T on these meshes
# when the BLAS is an optimised one (OpenBLAS, which `make` installs); below
# it the simplicial factor is faster, its solves too. Counted in entries, not
# unknowns: a P2 row holds about 30, a P1 row 14-20, and whole forward solves
# timed in both modes cross over between 1.0 and 1.4 million entries for both
# (docs/benchmarks.md, "Large meshes"). The crossover moves with the
# machine's caches and BLAS.
SUPERNODAL_MIN_ENTRIES = 1_200_000
# ... or above this many Hessian entries per unknown at any size: finite
# tendon attachments on a mesh much finer than their discs make each
# tendon's Hessian block dense over all its discs' nodes, and there
# supernodal wins by far (docs/benchmarks.md, "Large meshes"). A plain P2
# mesh has about 30 entries per unknown.
SUPERNODAL_MIN_DENSITY = 150
# The supernodal factor's fill-reducing ordering: METIS's nested dissection
# leaves less fill than AMD on these 2D meshes and factors about a sixth
# faster at 30,000 nodes (docs/notes/benchmarks-history.md, "At the
# factorisation floor"); AMD where CHOLMOD was built without METIS, and
# for the simplicial factor (no faster there).
SUPERNODAL_ORDERING = "metis"
#: CHOLMOD factorisation modes: "auto" picks by size (SUPERNODAL_MIN_ENTRIES)
CHOLMOD_MODES = ("auto", "simplicial", "supernodal")
#: how a LowRankHessian is factored: its sparse part and Woodbury, or its
#: augmented matrix (:func:`augmented_factor`)
LOW_RANK_FACTORS = ("woodbury", "augmented")

# Relative pivot margin: round-off in a factorisation is ~1e-16 |H|; a
# thousand times that is still far below the softest physical mode of the
# shipped robots (lambda_min / |H| ~ 1e-8).
PIVOT_MARGIN = 1e-13
# A Woodbury solve is refined once by the residual it leaves when that is
# above this fraction of the right-hand side (the update loses digits when
# the sparse part is much softer than the whole: a stiff tendon on a soft body).
REFINE_ABOVE = 1e-10
# The Woodbury set-up by forward substitution of the sparse low-rank factor
# alone (CHOLMOD); False forms Y = A^-1 G with k full solves, as with QDLDL
# (the reference path: tools/bench_newton.py times the two).
WOODBURY_HALVES = True


class NotPositiveDefinite(Exception):
    """The matrix has a non-positive pivot: it is not positive definite."""


def _checked_backend(name: str) -> str:
    if name not in BACKENDS:
        raise SettingError(f"{ENV_VAR}={name!r}: expected one of {', '.join(BACKENDS)}")
    if name == "cholmod" and not _cholmod_installed():
        raise SettingError(f"{ENV_VAR}=cholmod: scikit-sparse (CHOLMOD) is not installed; install "
                          "libsuitesparse-dev, then `pip install 'plush_opt[cholmod]'`")
    if name == "qdldl":
        try:
            import qdldl  # noqa: F401
        except ImportError:
            raise SolverError("qdldl is not installed (a dependency of plush_opt): "
                              "`pip install qdldl`") from None
    return name


class Factorizer:
    """LDL^T factorisations of matrices sharing one sparsity pattern.

    The fill-reducing ordering (AMD; METIS for a supernodal factor) and
    symbolic analysis are computed on the first call and reused for every
    later matrix with the same pattern.
    Both backends factor without pivoting. QDLDL is a simplicial LDL^T;
    CHOLMOD is a simplicial LDL^T below :data:`SUPERNODAL_MIN_ENTRIES`
    matrix entries (up to about twice as fast there as its supernodal
    LL^T) and a supernodal LL^T from there on, or where the matrix has more than
    :data:`SUPERNODAL_MIN_DENSITY` entries per unknown (BLAS-3 on dense
    supernodes wins on large meshes and on dense tendon blocks).
    The matrix counts as positive definite when every pivot of D exceeds
    ``PIVOT_MARGIN`` times the largest: a matrix singular to round-off (a
    free rigid mode, a bifurcation point) can factor with tiny positive
    pivots, and must not be certified.

    ``backend``: one of :data:`BACKENDS`; default :data:`BACKEND`.
    ``mode``: CHOLMOD's factorisation, one of :data:`CHOLMOD_MODES`
    (ignored by QDLDL); :attr:`mode_used` says which one the last
    factorisation took.
    ``low_rank``: how a :class:`LowRankHessian` is factored, one of
    :data:`LOW_RANK_FACTORS`: "woodbury" (its sparse part, then the
    update; a kept factor can take a newer update, :meth:`Factor.with_low_rank_of`),
    or "augmented" (one LDL^T of its augmented matrix: faster where the
    update's rank is high).
    """

    def __init__(self, backend: str | None = None, mode: str = "auto", low_rank: str = "woodbury"):
        self.backend = _checked_backend(BACKEND if backend is None else backend)
        if mode not in CHOLMOD_MODES:
            raise SolverError(f"factorisation mode {mode!r}: expected one of {', '.join(CHOLMOD_MODES)}")
        if low_rank not in LOW_RANK_FACTORS:
            raise SolverError(f"low-rank factor {low_rank!r}: expected one of {', '.join(LOW_RANK_FACTORS)}")
        self.mode, self.low_rank = mode, low_rank
        self.mode_used = None
        self._symbolic = None
        self._pattern = None
        self._spare: list = []      # qdldl: solvers of this pattern no live Factor holds
        self._parts: dict[str, Factorizer] = {}    # low-rank form: its body's, its augmented matrix's

    def factor(self, H, shift: float = 0.0, definite: bool = True) -> "Factor":
        """LDL^T of ``H + shift I``; raises :class:`NotPositiveDefinite`.
        ``H``: a CSC matrix, or a :class:`LowRankHessian`. ``definite=False``
        (a CSC matrix, a Factorizer of mode "simplicial"): any inertia, its
        pivots in ``Factor.pivots``; refused only on a zero pivot (there is
        no pivoting)."""
        if isinstance(H, LowRankHessian):
            return self._factor_low_rank(H, shift)
        pattern = (H.shape, H.indptr.tobytes(), H.indices.tobytes())
        if self._symbolic is None or pattern != self._pattern:
            self._symbolic = None
            self._spare = []
            self._pattern = pattern
        if self.backend == "cholmod":
            return self._factor_cholmod(H, shift, definite)
        self.mode_used = "simplicial"
        return self._factor_qdldl(H, shift, definite)

    def _factor_cholmod(self, H, shift, definite) -> "Factor":
        from sksparse.cholmod import CholmodNotPositiveDefiniteError
        if self._symbolic is None:
            self.mode_used = self.mode
            if self.mode == "auto":
                dense = H.nnz >= SUPERNODAL_MIN_DENSITY * H.shape[0]
                big = H.nnz >= SUPERNODAL_MIN_ENTRIES
                self.mode_used = "supernodal" if big or dense else "simplicial"
            self._symbolic = _analyze(H, self.mode_used)
        try:
            f = self._symbolic.cholesky(H, beta=shift)
        except CholmodNotPositiveDefiniteError as exc:
            raise NotPositiveDefinite(f"non-positive pivot ({exc})") from None
        # D of a supernodal LL^T is diag(L)^2 (read off a simplicial copy of
        # the factor: a small fraction of the factorisation's cost)
        d = f.D()
        if definite:
            _check_pivots(d)
        return Factor(f, H, shift, _CholmodHalves(f, d, self.mode_used == "simplicial"), d)

    def _factor_qdldl(self, H, shift, definite) -> "Factor":
        # One qdldl solver holds one numeric factor, refactored in place;
        # a Factor handed out must stay valid, so each live Factor owns its
        # solver and gives it back (to be refactored) when it is dropped.
        import qdldl
        if self._symbolic is None:
            self._symbolic = _UpperPattern(H)
        U = self._symbolic.upper(H, shift)
        if self._spare:
            solver = self._spare.pop()
            solver.update(U, upper=True)
        else:
            solver = qdldl.Solver(U, upper=True)       # AMD + symbolic + numeric
        d = solver.factors()[1]
        try:
            if definite:
                _check_pivots(d)
        except NotPositiveDefinite:
            self._spare.append(solver)
            raise
        f = Factor(_columnwise(solver.solve), H, shift, pivots=d.copy())
        weakref.finalize(f, self._give_back, self._pattern, solver).atexit = False
        return f

    def _part(self, name: str, mode: str | None = None) -> "Factorizer":
        if name not in self._parts:
            self._parts[name] = Factorizer(self.backend, mode or self.mode)
        return self._parts[name]

    def _factor_low_rank(self, H: "LowRankHessian", shift) -> "Factor":
        """Factor of body + shift I, then Woodbury for the low-rank term
        (which also decides whether H + shift I is positive definite).
        Where the body alone is not positive definite, H is decided on its
        sparse augmented matrix (:func:`augmented_factor`, never assembled:
        the tendons' blocks are dense over their discs), so that certification
        never depends on the split (with a regularising shift > 0 that is
        refused instead: the caller tries a larger shift, and a larger
        shift is all it needs). With ``low_rank="augmented"``, always on
        the augmented matrix."""
        if self.low_rank == "augmented":
            return self._factor_augmented(H, shift)
        try:
            body = self._part("body").factor(H.body, shift)
        except NotPositiveDefinite:
            if shift > 0:
                raise       # a regularising shift: a larger one will do
            return self._factor_augmented(H, shift)
        self.mode_used = self._part("body").mode_used
        return Factor(_WoodburySolve(body, H, shift), H, shift)

    def _factor_augmented(self, H: "LowRankHessian", shift) -> "Factor":
        f, negative, singular = augmented_factor(H, shift, self._part("augmented", "simplicial"))
        if negative or singular:
            raise NotPositiveDefinite(f"augmented matrix: {negative} negative eigenvalue(s) of H, "
                                      "or a pivot near zero")
        self.mode_used = "simplicial"
        return f

    def _give_back(self, pattern, solver):
        if pattern == self._pattern:
            self._spare.append(solver)


def _analyze(H, mode: str):
    """CHOLMOD's symbolic analysis of H in ``mode``, ordered by
    :data:`SUPERNODAL_ORDERING` (supernodal) or AMD."""
    from sksparse.cholmod import CholmodError, analyze
    if mode == "supernodal" and SUPERNODAL_ORDERING != "amd":
        try:
            return analyze(H, mode=mode, ordering_method=SUPERNODAL_ORDERING)
        except CholmodError:          # (built without METIS)
            pass
    return analyze(H, mode=mode, ordering_method="amd")


def _check_pivots(d: np.ndarray):
    if not np.all(np.isfinite(d)) or not np.min(d) > PIVOT_MARGIN * np.max(np.abs(d)):
        raise NotPositiveDefinite(f"LDL^T pivot {float(np.min(d)):.3g} not above "
                                  f"{PIVOT_MARGIN:g} x {float(np.max(np.abs(d))):.3g}")


def _columnwise(solve):
    """A solve of one vector extended to the columns of a matrix."""
    def f(b):
        b = np.asarray(b, dtype=np.float64)
        if b.ndim == 1:
            return solve(b)
        return np.column_stack([solve(np.ascontiguousarray(b[:, j])) for j in range(b.shape[1])])
    return f


class _UpperPattern:
    """The upper triangle of a symmetric CSC pattern, diagonal included
    (QDLDL reads the upper triangle), with where each entry of H goes: the
    pattern is built once, then each matrix costs one scatter."""

    def __init__(self, H: sp.csc_matrix):
        n = H.shape[0]
        cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(H.indptr))
        rows = H.indices.astype(np.int64)
        self._keep = np.flatnonzero(rows <= cols)
        diag = np.arange(n, dtype=np.int64)
        key = np.concatenate([cols[self._keep] * n + rows[self._keep], diag * n + diag])
        ukey = np.unique(key)          # column-major order: a canonical CSC
        self._shape = H.shape
        self._indices = (ukey % n).astype(np.int32)
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(ukey // n, minlength=n))]).astype(np.int32)
        where = np.searchsorted(ukey, key)
        self._src, self._diag = where[:len(self._keep)], where[len(self._keep):]

    def upper(self, H: sp.csc_matrix, shift: float) -> sp.csc_matrix:
        data = np.bincount(self._src, weights=H.data[self._keep], minlength=len(self._indices))
        data[self._diag] += shift
        return sp.csc_matrix((data, self._indices, self._indptr), shape=self._shape)


class _CholmodHalves:
    """The two triangular halves of a CHOLMOD factor A = P^T L D L^T P
    (a supernodal LL^T: D = I): ``forward(B)`` = L^-1 P B (B dense or
    sparse), ``backward(V)`` = P^T L^-T D^-1 V, and ``dinv`` = 1 / diag(D);
    so A^-1 = backward o forward and B^T A^-1 B = Z^T diag(dinv) Z with
    Z = forward(B)."""

    def __init__(self, f, d: np.ndarray, simplicial: bool):
        self._f, self._ldl = f, simplicial
        self.dinv = 1.0 / d if simplicial else np.ones_like(d)

    def forward(self, B):
        return self._f.solve_L(self._f.apply_P(B), use_LDLt_decomposition=self._ldl)

    def backward(self, V: np.ndarray) -> np.ndarray:
        f = self._f
        return f.apply_Pt(f.solve_DLt(V) if self._ldl else f.solve_Lt(V, use_LDLt_decomposition=False))


class _RefinedSolve:
    """A solve with ``_H`` + ``_shift`` I (the subclass's ``_once``)
    refined once by its residual where the first solve with this factor
    left one above ``REFINE_ABOVE`` of its right-hand side (after a first
    solve that did not, later ones skip the residual)."""

    _checked = False       # the first solve's residual decides on refinement
    _refine = True

    def __call__(self, b: np.ndarray) -> np.ndarray:
        """(H + shift I)^-1 b, b (n,) or (n, m)."""
        b = np.asarray(b, dtype=np.float64)
        x = self._once(b)
        if self._checked and not self._refine:
            return x
        r = b - (self._H @ x + self._shift * x)
        size = np.linalg.norm(b, axis=0)
        refine = bool(np.any(np.linalg.norm(r, axis=0) > REFINE_ABOVE * size))
        if not self._checked:
            self._checked, self._refine = True, refine
        return x + self._once(r) if refine else x


class _WoodburySolve(_RefinedSolve):
    """Solves with H + shift I = A + G D G^T, A = body + shift I factored,
    G D G^T = Q^T M Q (M's eigenpairs, those below round-off dropped).
    With Y = A^-1 G |D|^1/2 and T = sign(D) + |D|^1/2 G^T A^-1 G |D|^1/2:
    x = A^-1 b - Y T^-1 Y^T b.

    With a CHOLMOD body factor (:class:`_CholmodHalves`) the set-up is k
    forward substitutions of G alone, Z = L^-1 P G |D|^1/2 (kept on its
    nonzero rows) and T = sign(D) + Z^T D_A^-1 Z, and a solve is one forward and one
    backward substitution: x = P^T L^-T D_A^-1 (y - Z T^-1 Z^T D_A^-1 y),
    y = L^-1 P b (the cost of one plain solve). Otherwise Y is formed
    (k solves).

    Inertia (Haynsworth, A positive definite): H + shift I has
    #pos(T) - #pos(D) negative eigenvalues and #zero(T) zero ones, so it is
    positive definite exactly when T has as many positive eigenvalues as D.
    T is scaled so that 1 is its size where the update changes little: an
    eigenvalue below ``PIVOT_MARGIN`` of its largest is a zero (the test
    of the sparse factor's pivots). Otherwise :class:`NotPositiveDefinite`."""

    def __init__(self, body: "Factor", H: LowRankHessian, shift: float, kept: "_WoodburySolve | None" = None):
        self._body, self._H, self._shift = body, H, shift
        self._halves = body._halves if WOODBURY_HALVES else None
        D, V, self._where = eigen_blocks(H.M)
        scale = np.sqrt(np.abs(D))
        n = H.shape[0]
        if self._halves is not None:
            self._Z, self._rows = self._substituted(H, D, V, scale, kept)
            self._WT = (self._halves.dinv[self._rows, None] * self._Z).T.copy()
            T = np.diag(np.sign(D)) + self._Z.T @ self._WT.T
        else:
            G = np.asarray(H.QT @ V) * scale if D.size else np.zeros((n, 0))
            self._Y = body.solve(G).reshape(n, -1)
            T = np.diag(np.sign(D)) + G.T @ self._Y
        t, self._U = np.linalg.eigh((T + T.T) / 2)
        if D.size and (np.count_nonzero(t > 0) != np.count_nonzero(D > 0)
                       or not np.min(np.abs(t)) > PIVOT_MARGIN * np.max(np.abs(t))):
            raise NotPositiveDefinite(f"low-rank update: {np.count_nonzero(t > 0) - np.count_nonzero(D > 0)} "
                                      "negative eigenvalue(s), or one near zero")
        self._t = t

    def _substituted(self, H: LowRankHessian, D, V, scale, kept: "_WoodburySolve | None"):
        """Z = L^-1 P G on its nonzero rows, and those rows. The columns of
        M's pairs outside ``H.fast`` are ``kept``'s where it factored the same
        sparse part with the same such pairs (a refreshed tendon term:
        :meth:`Factor.with_low_rank_of`; only its own columns are
        substituted), else every column is. Z is forward-substituted dense
        (CHOLMOD's dense solve beats its sparse one on these columns), then
        kept on its nonzero rows alone (the paths of G's rows up the
        elimination tree)."""
        if not D.size:
            return np.zeros((0, 0)), np.zeros(0, np.int64)
        new = np.ones(len(self._where), bool)                # the columns substituted here
        if kept is not None and kept._halves is self._halves and H.fast is not None:
            new = in_span(self._where, H.fast)
            if not (new.any() and np.array_equal(kept._where[~in_span(kept._where, H.fast)], self._where[~new])):
                new[:] = True
        Zn = self._halves.forward(np.asarray(H.QT @ (V[:, new] * scale[new])))
        rows = np.flatnonzero(np.any(Zn != 0.0, axis=1))
        if new.all():
            return np.ascontiguousarray(Zn[rows]), rows
        if not np.all(np.isin(rows, kept._rows, assume_unique=True)):    # (beyond the kept rows)
            return self._substituted(H, D, V, scale, None)
        Z = np.empty((len(kept._rows), len(self._where)))
        Z[:, ~new], Z[:, new] = kept._Z[:, ~in_span(kept._where, H.fast)], Zn[kept._rows]
        return Z, kept._rows

    def _inner(self, w: np.ndarray) -> np.ndarray:
        """T^-1 w (k,) or (k, m)."""
        return self._U @ ((self._U.T @ w).T / self._t).T

    def _once(self, b: np.ndarray) -> np.ndarray:
        if self._halves is not None:
            y = self._halves.forward(b)
            y[self._rows] -= self._Z @ self._inner(self._WT @ y[self._rows])
            return self._halves.backward(y)
        u = self._body.solve(b)
        return u - self._Y @ self._inner(self._Y.T @ b)


class _AugmentedSolve(_RefinedSolve):
    """Solves with H + shift I (a :class:`LowRankHessian` of any inertia)
    through an LDL^T of its augmented matrix (:meth:`LowRankHessian.augmented`),
    made by ``factorizer`` (mode "simplicial": the inertia is read off D).
    ``negative``: how many negative eigenvalues H + shift I has;
    ``singular``: a pivot of K below ``PIVOT_MARGIN`` of the largest (a
    zero eigenvalue, or a factor without pivoting that cannot be trusted).
    Solves are refined as :class:`_RefinedSolve` says. Raises
    :class:`NotPositiveDefinite` on a zero pivot."""

    def __init__(self, factorizer: Factorizer, H: LowRankHessian, shift: float = 0.0):
        K, positive = H.augmented(shift)
        try:
            self._factor = factorizer.factor(K, definite=False)
        except (RuntimeError, ValueError) as exc:       # (QDLDL on a zero pivot)
            raise NotPositiveDefinite(f"augmented matrix: {exc}") from None
        d = self._factor.pivots
        self.negative = int(np.count_nonzero(d < 0)) - positive
        self.singular = not (np.all(np.isfinite(d)) and np.min(np.abs(d)) > PIVOT_MARGIN * np.max(np.abs(d)))
        self._H, self._shift, self._extra = H, shift, K.shape[0] - H.shape[0]

    def _once(self, b: np.ndarray) -> np.ndarray:
        padded = np.concatenate([b, np.zeros((self._extra,) + b.shape[1:])])
        return self._factor.solve(padded)[:b.shape[0]]


def augmented_factor(H: LowRankHessian, shift: float = 0.0,
                     factorizer: Factorizer | None = None) -> tuple["Factor", int, bool]:
    """A factor of H + shift I (any inertia) through its augmented matrix,
    how many negative eigenvalues H + shift I has, and whether a pivot was
    near zero (:class:`_AugmentedSolve`); :class:`NotPositiveDefinite`
    where one is zero. ``factorizer``: of mode "simplicial" (default: a
    new one)."""
    solve = _AugmentedSolve(factorizer or Factorizer(mode="simplicial"), H, shift)
    return Factor(solve, H, shift), solve.negative, solve.singular


def product_operator(H) -> spla.LinearOperator:
    """v -> H v as a SciPy operator (H sparse, or a :class:`LowRankHessian`)."""
    n = H.shape[0]
    return spla.LinearOperator((n, n), matvec=lambda v: H @ v, dtype=np.float64)


class Factor:
    """An LDL^T factor of ``H + shift I``: solve, and the smallest eigenvalue.
    ``H`` is a CSC matrix or a :class:`LowRankHessian`."""

    def __init__(self, chol, H, shift, halves: "_CholmodHalves | None" = None, pivots=None):
        self._chol = chol
        self.H = H
        self.shift = shift
        self._halves = halves
        self.pivots = pivots        # D of the LDL^T (a factor of a sparse matrix)

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._chol(b)

    def with_low_rank_of(self, H) -> "Factor | None":
        """For a factor of a :class:`LowRankHessian`: the factor of its
        sparse part (kept, not refactored) plus the low-rank term of ``H``
        (a LowRankHessian of the same size), of its ``fast`` rows alone
        where it names them (the rest of the low-rank term kept: in the
        split form a segment's coupling there pairs with its diagonal
        blocks in the kept sparse part): one low-rank set-up, no sparse
        factorisation. None for a factor of an assembled matrix, for an
        assembled ``H``, or where that sum is not positive definite."""
        chol = self._chol
        if not (isinstance(chol, _WoodburySolve) and isinstance(H, LowRankHessian)
                and H.shape == self.H.shape):
            return None
        mixed, rest_kept = with_fast_rows(chol._H, H)
        try:
            return Factor(_WoodburySolve(chol._body, mixed, self.shift, chol if rest_kept else None), mixed,
                          self.shift)
        except NotPositiveDefinite:
            return None

    def min_eigenvalue(self) -> float:
        """Smallest eigenvalue of ``H`` (shift-invert Lanczos around 0 using
        this factor; a few solves). Only meaningful for ``shift == 0``."""
        n = self.H.shape[0]
        if n <= 200:
            return float(np.linalg.eigvalsh(assembled(self.H).toarray())[0])
        op = spla.LinearOperator((n, n), matvec=lambda v: self._chol(v), dtype=np.float64)
        try:
            vals = spla.eigsh(product_operator(self.H), k=1, sigma=0.0, which="LM", OPinv=op,
                              tol=1e-8, maxiter=2000, return_eigenvectors=False,
                              v0=np.ones(n))
        except spla.ArpackNoConvergence as exc:
            if len(exc.eigenvalues):
                return float(np.min(exc.eigenvalues))
            raise SolverError("smallest Hessian eigenvalue: ARPACK did not converge") from None
        return float(vals[0])


    def most_negative_eigenpair(self) -> tuple[float, np.ndarray] | None:
        """For a factor of ``H + shift I`` (shift > 0, made positive definite
        by it): the most negative eigenvalue of H and its unit eigenvector,
        by shift-invert Lanczos around -shift with this factor; None if
        none is found below zero."""
        n = self.H.shape[0]
        if self.shift <= 0:
            return None
        op = spla.LinearOperator((n, n), matvec=lambda v: self._chol(v), dtype=np.float64)
        try:
            w, V = spla.eigsh(product_operator(self.H), k=1, sigma=-self.shift, which="LM", OPinv=op, tol=1e-10,
                              maxiter=1000, v0=np.ones(n))
        except spla.ArpackNoConvergence:
            return None
        return (float(w[0]), V[:, 0]) if w[0] < 0 else None
