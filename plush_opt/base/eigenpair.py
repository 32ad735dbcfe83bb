"""The smallest eigenpair of a symmetric Hessian of any inertia: the
direction that escapes a saddle. A :class:`~.low_rank.LowRankHessian` is
never assembled (its tendons' blocks are dense over their discs): its
shift-invert goes through its augmented matrix
(:func:`~.linalg.augmented_factor`)."""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import SolverError
from .linalg import NotPositiveDefinite, augmented_factor, product_operator
from .low_rank import LowRankHessian, assembled

# Up to this many unknowns an eigenpair is found dense.
DENSE_EIGEN_MAX = 400
# Shift-invert looks for the eigenvalues next to this one: the negative
# eigenvalues of a near-saddle are small.
NEAR_ZERO = -1e-12


def smallest_eigenpair(H: sp.csc_matrix | LowRankHessian) -> tuple[float, np.ndarray]:
    """Smallest (algebraic) eigenvalue of a symmetric H and its unit
    eigenvector. Used to escape saddles, where H is indefinite."""
    n = H.shape[0]
    if n <= DENSE_EIGEN_MAX:
        w, V = sla.eigh(assembled(H).toarray(), subset_by_index=[0, 0], driver="evr")
        return float(w[0]), V[:, 0]
    low_rank = isinstance(H, LowRankHessian)
    A = product_operator(H) if low_rank else H
    # look around 0 first (shift-invert: an LU of the indefinite H, or an
    # LDL^T of its augmented matrix); if none is found below 0 there, look
    # at the far end of the spectrum, unless the augmented matrix's inertia
    # says there is none: the one nearest 0 is then the smallest
    try:
        near, negative = {}, None
        if low_rank:
            factor, negative, _ = augmented_factor(H, -NEAR_ZERO)
            near["OPinv"] = spla.LinearOperator((n, n), matvec=factor.solve, dtype=np.float64)
        w, V = spla.eigsh(A, k=min(4, n - 1), sigma=NEAR_ZERO, which="LM", tol=1e-10, v0=np.ones(n), **near)
        if w.min() < 0 or negative == 0:
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
