"""A Hessian kept as a sparse part plus a low-rank symmetric term
(finite tendon attachments), and what is read off its parts: M's
eigenpairs block by block, a term with some of its rows taken from
another, and the sparse augmented matrix whose Schur complement it is.
The factorisations are :mod:`.linalg`'s."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

# Eigenvalues of a low-rank term's M below this fraction of its largest are
# round-off (a slack tendon, a straight segment): left out of the update.
LOW_RANK_DROP = 1e-14


@dataclass(frozen=True)
class LowRankHessian:
    """H = body + Q^T M Q: a sparse part and a low-rank symmetric term.

    Finite tendon attachments make a tendon's Hessian dense over all its
    discs' nodes (its stiffness couples every via point with every other),
    and assembled, those blocks fill the factor. Kept apart, they cost k
    solves with the factor of the mesh-sparse part and k x k dense algebra
    per factorisation.

    body : (n, n) CSC, symmetric; where it is not positive definite H is
        factored through its augmented matrix (:meth:`augmented`).
    Q : (k, n) CSR.
    M : (k, k) dense, symmetric, of any inertia.
    fast : the rows [start, stop) of Q whose terms change fastest with the
        pose (the tendons' own U'' l' l'^T: M is diagonal there and couples
        them with no other row), or None (all rows): what a kept factor
        takes from a newer Hessian (:meth:`.linalg.Factor.with_low_rank_of`).
    """

    body: sp.csc_matrix
    Q: sp.csr_matrix
    M: np.ndarray
    fast: tuple[int, int] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.body.shape

    @functools.cached_property
    def QT(self) -> sp.csr_matrix:
        return self.Q.T.tocsr()

    def __matmul__(self, v: np.ndarray) -> np.ndarray:
        return self.body @ v + self.QT @ (self.M @ (self.Q @ v))

    def diagonal(self) -> np.ndarray:
        return self.body.diagonal() + np.asarray(self.QT.multiply(self.QT @ self.M).sum(axis=1)).ravel()

    def abs_product(self, v: np.ndarray) -> np.ndarray:
        """A bound of |H| v (entrywise |.|, v >= 0): |body| v + |Q|^T |M| |Q| v,
        never assembling the dense tendon blocks."""
        return abs(self.body) @ v + abs(self.QT) @ (np.abs(self.M) @ (abs(self.Q) @ v))

    def assemble(self) -> sp.csc_matrix:
        """The whole matrix, sparse (dense over the tendons' nodes), exactly
        symmetric (the products leave round-off asymmetry; a factorisation
        reads one triangle, Lanczos assumes symmetry)."""
        H = self.body + self.QT @ sp.csr_matrix(self.M) @ self.Q
        return ((H + H.T) * 0.5).tocsc()

    def augmented(self, shift: float = 0.0) -> tuple[sp.csc_matrix, int]:
        """The sparse augmented matrix of H + shift I, and how many of its
        negative eigenvalues are not H's. With M = V D V^T (:func:`eigen_blocks`)
        and G = Q^T V |D|^1/2,

            K = [[body + shift I, G], [G^T, -sign(D)]]

        has H + shift I as its Schur complement, so (Sylvester's law of
        inertia) K has #pos(D) + #neg(H + shift I) negative eigenvalues,
        and K [x; y] = [b; 0] gives (H + shift I) x = b. K is as sparse as
        the body plus G's columns, where the assembled H is dense over every
        node of a tendon's attachment discs."""
        D, V, _ = eigen_blocks(self.M)
        G = (self.QT @ sp.csr_matrix(V * np.sqrt(np.abs(D)))).tocsc()
        A = self.body + shift * sp.identity(self.shape[0], format="csc") if shift else self.body
        K = sp.bmat([[A, G], [G.T, sp.diags(-np.sign(D))]], format="csc")
        K.sort_indices()
        return K, int(np.count_nonzero(D > 0))


def assembled(H) -> sp.csc_matrix:
    """H as one sparse matrix (a :class:`LowRankHessian` assembled)."""
    return H.assemble() if isinstance(H, LowRankHessian) else H


def abs_product(H, v: np.ndarray) -> np.ndarray:
    """|H| v (entrywise |.|, v >= 0), (n,): exact for a sparse H; for a
    :class:`LowRankHessian` a bound from above (the triangle inequality:
    :meth:`LowRankHessian.abs_product`), never assembled."""
    if isinstance(H, LowRankHessian):
        return H.abs_product(v)
    return np.asarray(abs(H) @ v).ravel()


def eigen_blocks(M: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """M's eigenpairs (lam, V) above round-off, block by block: M is block
    diagonal (a segment's 2 x 2 coupling, a tendon's own entry), so V is
    exactly as sparse as its blocks and so is Q^T V. Also the position
    (row of M) each kept pair was found at, ascending: the pairs of one
    block sit at that block's rows."""
    k = M.shape[0]
    lam, V = np.zeros(k), np.zeros((k, k))
    if k:
        _, label = connected_components(sp.csr_matrix(M != 0), directed=False)
        order = np.argsort(label, kind="stable")           # each block's indices, ascending
        starts = np.flatnonzero(np.r_[True, np.diff(label[order]) != 0])
        sizes = np.diff(np.r_[starts, k])
        for size in np.unique(sizes):                      # the blocks of one size in one call
            idx = order[starts[sizes == size][:, None] + np.arange(size)]     # (blocks, size)
            lam[idx], V[idx[:, :, None], idx[:, None, :]] = np.linalg.eigh(M[idx[:, :, None], idx[:, None, :]])
    keep = np.abs(lam) > LOW_RANK_DROP * max(float(np.max(np.abs(lam), initial=0.0)), 1e-300)
    return lam[keep], V[:, keep], np.flatnonzero(keep)


def with_fast_rows(kept: LowRankHessian, H: LowRankHessian) -> tuple[LowRankHessian, bool]:
    """``kept``'s sparse part with the low-rank term of ``H``: its ``fast``
    rows alone (the others ``kept``'s) where both name the same ones on a Q
    of the same shape, else the whole term; and whether the rows outside
    ``fast`` are ``kept``'s."""
    if H.fast is None or H.fast != kept.fast or H.Q.shape != kept.Q.shape:
        return LowRankHessian(kept.body, H.Q, H.M, H.fast), False
    a, b = H.fast
    M = kept.M.copy()
    M[a:b, a:b] = H.M[a:b, a:b]
    Q = sp.vstack([kept.Q[:a], H.Q[a:b], kept.Q[b:]], format="csr")
    return LowRankHessian(kept.body, Q, M, H.fast), True


def in_span(where: np.ndarray, span: tuple[int, int]) -> np.ndarray:
    """Which of the positions ``where`` lie in [start, stop) = ``span``."""
    return (where >= span[0]) & (where < span[1])
