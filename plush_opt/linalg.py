"""Sparse symmetric factorisation: an LDL^T with the symbolic analysis done
once per sparsity pattern, a positive-definiteness test for free, and a
cheap smallest-eigenvalue estimate from the factor.

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

from .errors import SolverError

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


# Above this many unknowns CHOLMOD's supernodal LL^T (dense BLAS on the
# supernodes) beats its simplicial LDL^T on these meshes when the BLAS is an
# optimised one (OpenBLAS, which `make` installs): break-even near 20,000
# unknowns, 1.2x at 30,000, 1.3-1.4x at 40,000-60,000, slower below
# (docs/benchmarks.md, "Large meshes"). With the reference BLAS it wins less.
SUPERNODAL_MIN_DOFS = 25_000
# ... or above this many Hessian entries per unknown at any size: finite
# tendon attachments on a mesh that resolves their discs make each tendon's
# Hessian block dense over all its discs' nodes, and there supernodal wins
# by far (a P2 gripper at 11,400 unknowns, 700 entries per unknown: 3 s
# against 65 s). A plain P2 mesh has about 30 per unknown.
SUPERNODAL_MIN_DENSITY = 150
#: CHOLMOD factorisation modes: "auto" picks by size (SUPERNODAL_MIN_DOFS)
CHOLMOD_MODES = ("auto", "simplicial", "supernodal")

# Relative pivot margin: round-off in a factorisation is ~1e-16 |H|; a
# thousand times that is still far below the softest physical mode of the
# shipped robots (lambda_min / |H| ~ 1e-8).
PIVOT_MARGIN = 1e-13


class NotPositiveDefinite(Exception):
    """The matrix has a non-positive pivot: it is not positive definite."""


def _checked_backend(name: str) -> str:
    if name not in BACKENDS:
        raise SolverError(f"{ENV_VAR}={name!r}: expected one of {', '.join(BACKENDS)}")
    if name == "cholmod" and not _cholmod_installed():
        raise SolverError(f"{ENV_VAR}=cholmod: scikit-sparse (CHOLMOD) is not installed; install "
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

    The fill-reducing ordering (AMD) and symbolic analysis are computed on
    the first call and reused for every later matrix with the same pattern.
    Both backends factor without pivoting. QDLDL is a simplicial LDL^T;
    CHOLMOD is a simplicial LDL^T below :data:`SUPERNODAL_MIN_DOFS`
    unknowns (about twice as fast there as its supernodal LL^T) and a
    supernodal LL^T above (BLAS-3 on dense supernodes wins on large meshes).
    The matrix counts as positive definite when every pivot of D exceeds
    ``PIVOT_MARGIN`` times the largest: a matrix singular to round-off (a
    free rigid mode, a bifurcation point) can factor with tiny positive
    pivots, and must not be certified.

    ``backend``: one of :data:`BACKENDS`; default :data:`BACKEND`.
    ``mode``: CHOLMOD's factorisation, one of :data:`CHOLMOD_MODES`
    (ignored by QDLDL); :attr:`mode_used` says which one the last
    factorisation took.
    """

    def __init__(self, backend: str | None = None, mode: str = "auto"):
        self.backend = _checked_backend(BACKEND if backend is None else backend)
        if mode not in CHOLMOD_MODES:
            raise SolverError(f"factorisation mode {mode!r}: expected one of {', '.join(CHOLMOD_MODES)}")
        self.mode = mode
        self.mode_used = None
        self._symbolic = None
        self._pattern = None
        self._spare: list = []      # qdldl: solvers of this pattern no live Factor holds

    def factor(self, H: sp.csc_matrix, shift: float = 0.0) -> "Factor":
        """LDL^T of ``H + shift I``; raises :class:`NotPositiveDefinite`."""
        pattern = (H.shape, H.indptr.tobytes(), H.indices.tobytes())
        if self._symbolic is None or pattern != self._pattern:
            self._symbolic = None
            self._spare = []
            self._pattern = pattern
        if self.backend == "cholmod":
            return self._factor_cholmod(H, shift)
        self.mode_used = "simplicial"
        return self._factor_qdldl(H, shift)

    def _factor_cholmod(self, H, shift) -> "Factor":
        from sksparse.cholmod import CholmodNotPositiveDefiniteError, analyze
        if self._symbolic is None:
            self.mode_used = self.mode
            if self.mode == "auto":
                dense = H.nnz >= SUPERNODAL_MIN_DENSITY * H.shape[0]
                big = H.shape[0] >= SUPERNODAL_MIN_DOFS
                self.mode_used = "supernodal" if big or dense else "simplicial"
            self._symbolic = analyze(H, mode=self.mode_used, ordering_method="amd")
        try:
            f = self._symbolic.cholesky(H, beta=shift)
        except CholmodNotPositiveDefiniteError as exc:
            raise NotPositiveDefinite(f"non-positive pivot ({exc})") from None
        # D of a supernodal LL^T is diag(L)^2 (read off a simplicial copy of
        # the factor: a few ms at 60,000 dofs against ~200 ms to factor)
        _check_pivots(f.D())
        return Factor(f, H, shift)

    def _factor_qdldl(self, H, shift) -> "Factor":
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
        try:
            _check_pivots(solver.factors()[1])
        except NotPositiveDefinite:
            self._spare.append(solver)
            raise
        f = Factor(_columnwise(solver.solve), H, shift)
        weakref.finalize(f, self._give_back, self._pattern, solver).atexit = False
        return f

    def _give_back(self, pattern, solver):
        if pattern == self._pattern:
            self._spare.append(solver)


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


class Factor:
    """An LDL^T factor of ``H + shift I``: solve, and the smallest eigenvalue."""

    def __init__(self, chol, H, shift):
        self._chol = chol
        self.H = H
        self.shift = shift

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._chol(b)

    def min_eigenvalue(self) -> float:
        """Smallest eigenvalue of ``H`` (shift-invert Lanczos around 0 using
        this factor; a few solves). Only meaningful for ``shift == 0``."""
        n = self.H.shape[0]
        if n <= 200:
            return float(np.linalg.eigvalsh(self.H.toarray())[0])
        op = spla.LinearOperator((n, n), matvec=lambda v: self._chol(v), dtype=np.float64)
        try:
            vals = spla.eigsh(self.H, k=1, sigma=0.0, which="LM", OPinv=op,
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
            w, V = spla.eigsh(self.H, k=1, sigma=-self.shift, which="LM", OPinv=op, tol=1e-10,
                              maxiter=1000, v0=np.ones(n))
        except spla.ArpackNoConvergence:
            return None
        return (float(w[0]), V[:, 0]) if w[0] < 0 else None


def smallest_eigenpair(H: sp.csc_matrix) -> tuple[float, np.ndarray]:
    """Smallest (algebraic) eigenvalue of a symmetric sparse H and its unit
    eigenvector. Used to escape saddles, where H is indefinite."""
    n = H.shape[0]
    if n <= 400:
        import scipy.linalg as sla
        w, V = sla.eigh(H.toarray(), subset_by_index=[0, 0], driver="evr")
        return float(w[0]), V[:, 0]
    # the negative eigenvalues of a near-saddle are small: look around 0
    # first (shift-invert, LU of the indefinite H); if none found below 0
    # there, look at the far end of the spectrum
    try:
        w, V = spla.eigsh(H, k=min(4, n - 1), sigma=-1e-12, which="LM", tol=1e-10, v0=np.ones(n))
        if w.min() < 0:
            k = int(np.argmin(w))
            return float(w[k]), V[:, k]
    except (RuntimeError, spla.ArpackNoConvergence):
        pass
    try:
        w, V = spla.eigsh(H, k=1, which="SA", tol=1e-10, maxiter=50 * n, v0=np.ones(n))
    except spla.ArpackNoConvergence as exc:
        if not len(exc.eigenvalues):
            raise SolverError("smallest Hessian eigenvalue: ARPACK did not converge") from None
        w, V = exc.eigenvalues, exc.eigenvectors
    k = int(np.argmin(w))
    return float(w[k]), V[:, k]
