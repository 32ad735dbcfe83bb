"""Rigid motions that contact leaves free (a body without pins).

A body that only contact holds may keep some rigid motions free: on a
frictionless floor it slides, and nothing but the floor's own slope picks
a place. Along such a motion r the energy is flat (H r = 0, grad E . r = 0),
so the Hessian is singular and no pose is isolated. The certificate
excludes these motions (docs/problem-format.md, "Contact"): the Hessian
the solvers factor gets a gauge, a stiffness on a few dofs that move along
r, which leaves the step on the other motions unchanged and fixes the body
where it is along r (for a singular H with null space N and a gradient
orthogonal to N, (H + a sum_j e_j e_j^T) dx = -g is the solution of
H dx = -g that does not move those dofs).

A rigid motion with H r = 0 but a net force along it is not free: the
body falls or slides (:func:`split_motions` tells the two kinds apart; an
evaluation reports the second in ``unbalanced``). A body that falls onto
something is moved onto it before Newton (plush_opt/solve/free_fall.py);
where nothing holds it, the Hessian stays singular and the solver's
regularised steps follow the force (:func:`unbalanced` says so when no
equilibrium is found).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from ..base.linalg import Factorizer

#: a rigid motion r (unit) is flat when |H r| is below this fraction of the
#: Hessian's largest diagonal entry: round-off of a translation-invariant
#: energy is ~1e-16 of it, the softest contact or elastic mode far above
FLAT = 1e-9
#: ... and balanced when |grad E . r| is below this fraction of the force
#: scale: below any residual Newton stops at (gtol 1e-10), since a gauged
#: motion keeps its net force (its steps are projected off it), yet above the
#: round-off of a net force that is zero (~1e-16-1e-14 of the scale). With
#: friction every contact node can slide at once, leaving a translation flat
#: under a tiny net force: gauged at 1e-6, its 1e-5 N held Newton there for
#: 500 iterations; left free, regularised steps slide the body until a node sticks
BALANCED = 1e-12
#: the motions' names, in the order of :func:`rigid_motions`
NAMES = ("translation in x", "translation in y", "rotation")


def rigid_motions(x: np.ndarray) -> np.ndarray:
    """(n_dofs, 3) orthonormal rigid motions of the pose ``x``: translations
    in x and y, rotation about its centroid (orthogonal to both: the
    centred positions sum to zero)."""
    n = x.size // 2
    px, py = x[0::2], x[1::2]
    # (sums over 1-d views: several times cheaper than means over the first
    # axis of the (n, 2) positions, which this runs on every gauged Hessian)
    dx = px - float(np.add.reduce(px)) / n
    dy = py - float(np.add.reduce(py)) / n
    norm = 1.0 / math.sqrt(float(dx @ dx + dy @ dy))
    V = np.empty((n, 6))          # per node: its x dof's (tx, ty, rot), its y dof's
    V[:, 0] = V[:, 4] = 1.0 / math.sqrt(n)
    V[:, 1] = V[:, 3] = 0.0
    np.multiply(dy, -norm, out=V[:, 2])
    np.multiply(dx, norm, out=V[:, 5])
    return V.reshape(2 * n, 3)


def flat_motions(H, x: np.ndarray, diagonal: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motions along which ``H`` (the Hessian at flat pose ``x``;
    ``diagonal`` its diagonal, if known) is flat: (n_dofs, k) orthonormal
    combinations of :func:`rigid_motions`, and (k, 3) their coordinates in
    them."""
    V = rigid_motions(x)
    HV = H @ V
    lam, Q = np.linalg.eigh(HV.T @ HV)          # |H V q|^2 over unit q
    diagonal = H.diagonal() if diagonal is None else diagonal
    scale = float(np.max(np.abs(diagonal), initial=0.0))
    flat = np.sqrt(np.maximum(lam, 0.0)) <= FLAT * max(scale, 1e-300)
    Qf = Q[:, flat]
    return V @ Qf, Qf.T                          # orthonormal: V's columns and Qf's are


def free_motions(H, x: np.ndarray, g: np.ndarray, force_scale: float) -> np.ndarray:
    """(n_dofs, k) the flat rigid motions with no net force along them."""
    return split_motions(H, x, g, force_scale)[0]


def split_motions(H, x: np.ndarray, g: np.ndarray, force_scale: float,
                  diagonal: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The flat rigid motions of ``H`` at ``x`` (gradient ``g``; ``diagonal``
    H's, if known), split: (n_dofs, k) those with no net force along them
    (free), and (n_dofs, j) those with one (the body falls or slides along
    them)."""
    R, _ = flat_motions(H, x, diagonal)
    if R.shape[1] == 0:
        return R, R
    balanced = np.abs(R.T @ g) <= BALANCED * max(force_scale, 1e-300)
    return R[:, balanced], R[:, ~balanced]


def gauge(H: sp.csc_matrix, R: np.ndarray, diagonal: np.ndarray | None = None, *, owned: bool = False,
          diagonal_slots: np.ndarray | None = None) -> sp.csc_matrix:
    """H plus a stiffness on one dof per free motion in ``R`` (n_dofs, k):
    the dofs (greedy pivots of R) make R's rows there invertible.
    ``diagonal``: H's diagonal, if known; ``diagonal_slots`` (n_dofs,):
    where it sits in ``H.data`` (-1 where H's pattern lacks an entry), if
    known. ``owned``: the caller gives H up (a fresh assembly that nothing
    else holds), and the stiffness is added to its data in place where its
    pattern holds those diagonal entries (no copy); else H is left as it is
    and a new matrix returned."""
    if R.shape[1] == 0:
        return H
    dofs = []
    rest = R.copy()
    for j in range(R.shape[1]):
        i = int(np.argmax(np.abs(rest[:, j])))
        dofs.append(i)
        if j + 1 < R.shape[1]:
            # eliminate dof i from the remaining motions (Gaussian pivoting)
            rest[:, j + 1:] -= np.outer(rest[:, j] / rest[i, j], rest[i, j + 1:])
    diagonal = H.diagonal() if diagonal is None else diagonal
    stiffness = float(np.mean(np.abs(diagonal)))
    slots = _diagonal_slots(H, dofs) if diagonal_slots is None else diagonal_slots[dofs]
    if np.all(slots >= 0):
        G = H if owned else H.copy()          # the same pattern
        G.data[slots] += stiffness
    else:
        G = (H + sp.csc_matrix((np.full(len(dofs), stiffness), (dofs, dofs)), shape=H.shape)).tocsc()
        G.sort_indices()
    G.free_motions = R           # what GaugedFactorizer projects its solves on
    return G


def _diagonal_slots(H: sp.csc_matrix, dofs) -> np.ndarray:
    """Where the diagonal entries (j, j) of ``dofs`` sit in ``H.data``
    (sorted CSC indices), -1 where the pattern lacks one."""
    out = np.full(len(dofs), -1, dtype=np.int64)
    for k, j in enumerate(dofs):
        lo, hi = H.indptr[j], H.indptr[j + 1]
        i = lo + int(np.searchsorted(H.indices[lo:hi], j))
        if i < hi and H.indices[i] == j:
            out[k] = i
    return out


class GaugedFactorizer(Factorizer):
    """A :class:`~plush_opt.base.linalg.Factorizer` whose factors of a
    gauged Hessian (:func:`gauge`) return the solution that does not move
    the body along its free motions: each solve is projected off them, so
    Newton steps, sensitivities and adjoints leave the pose's place along a
    free motion (its mean displacement) where it was."""

    def factor(self, H, shift: float = 0.0):
        f = super().factor(H, shift)
        R = getattr(H, "free_motions", None)
        return f if R is None else ProjectedFactor(f, R)


class ProjectedFactor:
    """A factor whose :meth:`solve` is projected off the free motions ``R``
    (n_dofs, k orthonormal); everything else is the wrapped factor's."""

    def __init__(self, factor, R: np.ndarray):
        self._factor, self.R = factor, R

    def solve(self, b: np.ndarray) -> np.ndarray:
        y = self._factor.solve(b)
        return y - self.R @ (self.R.T @ y)

    def __getattr__(self, name):
        return getattr(self._factor, name)


def describe(R: np.ndarray, x: np.ndarray) -> list[str]:
    """Each free motion in ``R`` in words ("translation in x", or a
    combination such as "translation along (0.966, 0.259)")."""
    V = rigid_motions(x)
    out = []
    for r in R.T:
        q = V.T @ r
        q = q / np.linalg.norm(q)
        if abs(q[2]) > 0.99:
            out.append("rotation")
        elif abs(q[2]) < 1e-6:
            t = q[:2] / np.linalg.norm(q[:2])
            if abs(t[1]) < 1e-9:
                out.append("translation in x")
            elif abs(t[0]) < 1e-9:
                out.append("translation in y")
            else:
                t = t if t[0] > 0 else -t
                out.append(f"translation along ({t[0]:.3f}, {t[1]:.3f})")
        else:
            out.append("a combined translation and rotation")
    return out


def unbalanced(H, x: np.ndarray, g: np.ndarray, force_scale: float) -> str | None:
    """Why there is no equilibrium near ``x``, if a rigid motion has a net
    force along it that its stiffness could not balance within the body's
    size (the body falls or slides), in words; else None.

    A motion counts when |grad E . r| exceeds ``BALANCED`` times the force
    scale and |H r| times the body's size (its bounding box's diagonal)
    is below |grad E . r|: flat motions (|H r| at round-off, the gauge's
    :data:`FLAT`), and also one that a sliding contact resists only by
    the tiny stiffness of a node in its friction's smoothing window."""
    V = rigid_motions(x)
    HV = H @ V
    lam, Q = np.linalg.eigh(HV.T @ HV)          # |H V q|^2 over unit q
    P = x.reshape(-1, 2)
    size = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    R = V @ Q
    for r, stiffness in zip(R.T, np.sqrt(np.maximum(lam, 0.0))):
        push = abs(float(r @ g))
        if push > BALANCED * max(force_scale, 1e-300) and stiffness * size < push:
            name = describe(r[:, None], x)[0]
            return (f"no equilibrium: nothing holds the body against a net force along a free "
                    f"{name} (it slides or falls)")
    return None
