"""Hessians of any inertia: a low-rank Hessian decided and solved without
assembling it, and the smallest eigenpair that escapes a saddle.

A :class:`~.linalg.LowRankHessian` H = body + Q^T M Q, M = V D V^T, is the
Schur complement of its sparse augmented matrix

    K = [[body + shift I, G], [G^T, -sign(D)]],   G = Q^T V |D|^1/2,

so (Sylvester's law of inertia) K has #pos(D) + #neg(H + shift I) negative
eigenvalues, and K [x; y] = [b; 0] gives (H + shift I) x = b. An LDL^T of
K costs the body's factor plus G's columns, where the assembled H is dense
over every node of a tendon's attachment discs (hundreds of millions of
entries on a fine mesh). Unlike the Woodbury form it needs no definite
body: a body that would buckle alone, held by its tendons.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import SolverError
from .linalg import (PIVOT_MARGIN, REFINE_ABOVE, Factorizer, LowRankHessian, NotPositiveDefinite, _low_rank_eigen,
                     _operator, assembled)

# Below this many unknowns an eigenpair is found dense.
DENSE_EIGEN_MAX = 400
# Shift-invert looks for the eigenvalues next to this one: the negative
# eigenvalues of a near-saddle are small.
NEAR_ZERO = -1e-12


def augmented(H: LowRankHessian, shift: float = 0.0) -> tuple[sp.csc_matrix, int]:
    """K of H + shift I (module docstring), and #pos(D): the count of its
    negative eigenvalues that are not H's."""
    D, V, _ = _low_rank_eigen(H.M)
    n = H.shape[0]
    G = (H.QT @ sp.csr_matrix(V * np.sqrt(np.abs(D)))).tocsc()
    A = (H.body + shift * sp.identity(n, format="csc")) if shift else H.body
    K = sp.bmat([[A, G], [G.T, sp.diags(-np.sign(D))]], format="csc")
    K.sort_indices()
    return K, int(np.count_nonzero(D > 0))


class AugmentedSolve:
    """Solves with H + shift I (a :class:`~.linalg.LowRankHessian` of any
    inertia) through an LDL^T of its augmented matrix, made by
    ``factorizer`` (mode "simplicial": LDL^T reads the inertia off D).
    ``negative``: how many negative eigenvalues H + shift I has;
    ``singular``: a pivot of K below ``PIVOT_MARGIN`` of the largest (a
    zero eigenvalue, or a factor without pivoting that cannot be trusted).
    A solve is refined once where its residual is above ``REFINE_ABOVE``
    of the right-hand side. Raises :class:`~.linalg.NotPositiveDefinite`
    on a zero pivot."""

    def __init__(self, factorizer: Factorizer, H: LowRankHessian, shift: float = 0.0):
        K, positive = augmented(H, shift)
        try:
            self._factor = factorizer.factor(K, definite=False)
        except (RuntimeError, ValueError) as exc:       # (QDLDL on a zero pivot)
            raise NotPositiveDefinite(f"augmented matrix: {exc}") from None
        d = self._factor.pivots
        self.negative = int(np.count_nonzero(d < 0)) - positive
        self.singular = not (np.all(np.isfinite(d)) and np.min(np.abs(d)) > PIVOT_MARGIN * np.max(np.abs(d)))
        self._H, self._shift, self._extra = H, shift, K.shape[0] - H.shape[0]

    def _once(self, b: np.ndarray) -> np.ndarray:
        n = b.shape[0]
        padded = np.concatenate([b, np.zeros((self._extra,) + b.shape[1:])])
        return self._factor.solve(padded)[:n]

    def __call__(self, b: np.ndarray) -> np.ndarray:
        """(H + shift I)^-1 b, b (n,) or (n, m)."""
        b = np.asarray(b, dtype=np.float64)
        x = self._once(b)
        r = b - (self._H @ x + self._shift * x)
        if np.any(np.linalg.norm(r, axis=0) > REFINE_ABOVE * np.linalg.norm(b, axis=0)):
            x = x + self._once(r)
        return x


def smallest_eigenpair(H: sp.csc_matrix | LowRankHessian) -> tuple[float, np.ndarray]:
    """Smallest (algebraic) eigenvalue of a symmetric H and its unit
    eigenvector. Used to escape saddles, where H is indefinite. A
    :class:`~.linalg.LowRankHessian` is never assembled above
    ``DENSE_EIGEN_MAX`` unknowns (shift-invert through its augmented
    matrix)."""
    n = H.shape[0]
    if n <= DENSE_EIGEN_MAX:
        w, V = sla.eigh(assembled(H).toarray(), subset_by_index=[0, 0], driver="evr")
        return float(w[0]), V[:, 0]
    A = _operator(H) if isinstance(H, LowRankHessian) else H
    # look around 0 first (shift-invert: an LU of the indefinite H, or the
    # augmented matrix's LDL^T); if none is found below 0 there, look at the
    # far end of the spectrum
    try:
        near = {}
        if isinstance(H, LowRankHessian):
            solve = AugmentedSolve(Factorizer(mode="simplicial"), H, -NEAR_ZERO)
            near["OPinv"] = spla.LinearOperator((n, n), matvec=solve, dtype=np.float64)
        w, V = spla.eigsh(A, k=min(4, n - 1), sigma=NEAR_ZERO, which="LM", tol=1e-10, v0=np.ones(n), **near)
        if w.min() < 0:
            k = int(np.argmin(w))
            return float(w[k]), V[:, k]
    except (RuntimeError, NotPositiveDefinite, spla.ArpackNoConvergence):
        pass
    try:
        w, V = spla.eigsh(A, k=1, which="SA", tol=1e-10, maxiter=50 * n, v0=np.ones(n))
    except spla.ArpackNoConvergence as exc:
        if not len(exc.eigenvalues):
            raise SolverError("smallest Hessian eigenvalue: ARPACK did not converge") from None
        w, V = exc.eigenvalues, exc.eigenvectors
    k = int(np.argmin(w))
    return float(w[k]), V[:, k]
