"""Sparse symmetric factorisation: CHOLMOD with the symbolic analysis done
once per sparsity pattern, a positive-definiteness test for free, and a
cheap smallest-eigenvalue estimate from the factor."""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import SolverError

try:
    from sksparse.cholmod import CholmodNotPositiveDefiniteError, analyze
except ImportError as exc:  # pragma: no cover - a broken install
    raise SolverError(
        "scikit-sparse (CHOLMOD) is not installed; run `make test` or "
        "`pip install scikit-sparse` after installing libsuitesparse-dev") from exc

log = logging.getLogger(__name__)


# Relative pivot margin: round-off in a factorisation is ~1e-16 |H|; a
# thousand times that is still far below the softest physical mode of the
# shipped robots (lambda_min / |H| ~ 1e-8).
PIVOT_MARGIN = 1e-13


class NotPositiveDefinite(Exception):
    """The matrix has a non-positive pivot: it is not positive definite."""


class Factorizer:
    """Cholesky factorisations of matrices sharing one sparsity pattern.

    The fill-reducing ordering (AMD) and symbolic analysis are computed on
    the first call and reused for every later matrix with the same pattern.
    CHOLMOD's simplicial LDL^T is used: on these meshes it is about twice
    as fast as the supernodal LL^T. The matrix counts as positive definite
    when every pivot of D exceeds ``PIVOT_MARGIN`` times the largest: a
    matrix singular to round-off (a free rigid mode, a bifurcation point)
    can factor with tiny positive pivots, and must not be certified.
    """

    def __init__(self):
        self._symbolic = None
        self._pattern = None

    def factor(self, H: sp.csc_matrix, shift: float = 0.0) -> "Factor":
        """Cholesky of ``H + shift I``; raises :class:`NotPositiveDefinite`."""
        pattern = (H.shape, H.indptr.tobytes(), H.indices.tobytes())
        if self._symbolic is None or pattern != self._pattern:
            self._symbolic = analyze(H, mode="simplicial", ordering_method="amd")
            self._pattern = pattern
        try:
            f = self._symbolic.cholesky(H, beta=shift)
        except CholmodNotPositiveDefiniteError as exc:
            raise NotPositiveDefinite(str(exc)) from None
        d = f.D()
        if not np.all(np.isfinite(d)) or not np.min(d) > PIVOT_MARGIN * np.max(np.abs(d)):
            raise NotPositiveDefinite(f"LDL^T pivot {float(np.min(d)):.3g} not above "
                                      f"{PIVOT_MARGIN:g} x {float(np.max(np.abs(d))):.3g}")
        return Factor(f, H, shift)


class Factor:
    """A Cholesky factor of ``H + shift I``: solve, and the smallest eigenvalue."""

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
