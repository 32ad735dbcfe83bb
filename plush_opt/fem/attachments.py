"""Finite tendon attachments: a via point as a weighted average of nodes.

With attachment radius r > 0 a tendon pulls on the disc D of radius r
around each via point p (a stopper, a hole in felt), not on one node: the
point the tendon follows is x_p = sum_i w_i x_i with
w_i = (integral over D n body of N_i dA) / area(D n body)
(problem-format.md, "Finite tendon attachments"). A point load in 2D has a
displacement that grows like log(1/h) under refinement; the disc average
converges.

The integrals are computed once on the rest mesh, triangle by triangle:
a triangle inside D is integrated exactly (a degree-2 rule on a degree <= 2
integrand); a triangle the circle cuts is split into four, recursively,
until its pieces are at most ``LEAF_FRACTION`` r wide; such a leaf piece is
clipped by the circle's tangent line at the leaf, the clipped polygon
integrated exactly, and the sliver between that line and the arc over the
chord where the line crosses the leaf (its area exact, from the circular
segment formula) taken back out with one point at its middle.
Error control: a leaf of width h departs from the arc by at most
h^2 / (2 r); the tangent clip alone errs by O(h^3 / r) per cut leaf, O(h^2)
in total; the sliver correction leaves O(h^4 / r^2) of it
(docs/model.md, "Finite tendon attachments", has the measured errors);
tests/test_attachments.py pins them below 1e-5, ten times inside the 1e-4
the format asks of each weight.

:class:`TendonPoints` turns these weights into what the model needs: an
extended coordinate vector z = [x; points with r > 0] and the maps between
z-space and node space.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..base.errors import SceneError
from ..base.geometry import triangle_areas
from .mesh import Mesh

# Leaf pieces of a cut triangle are at most this fraction of r wide: the
# corrected tangent-line clip then errs well below 1e-6 of the disc's area.
LEAF_FRACTION = 1.0 / 16
# A weight smaller than this (relative to 1) is round-off of an integral that
# is exactly zero (a P2 corner function over a whole triangle): dropped.
WEIGHT_DROP = 1e-13
# Halvings of a cut triangle before a leaf is LEAF_FRACTION r wide: a
# triangle 2^44 times wider than the disc (far below the problem file's floor
# on r) or a disc below the round-off of its coordinates would never get there.
MAX_SPLIT_DEPTH = 48
# The degree-2 exact rule on a triangle: three interior points, weight A/3 each.
_RULE = np.array([[2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])


def _barycentric(V: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Barycentric weights of point k in triangle k, (m, 3, 2), (m, 2) -> (m, 3)."""
    a, v0, v1 = V[:, 0], V[:, 1] - V[:, 0], V[:, 2] - V[:, 0]
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    w = pts - a
    l1 = (w[:, 0] * v1[:, 1] - w[:, 1] * v1[:, 0]) / det
    l2 = (v0[:, 0] * w[:, 1] - v0[:, 1] * w[:, 0]) / det
    return np.stack([1.0 - l1 - l2, l1, l2], axis=1)


def _distance_to_triangles(V: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Distance from point p_k to (filled) triangle V_k, (m, 3, 2), (m, 2) -> (m,)."""
    inside = np.all(_barycentric(V, p) >= 0, axis=1)
    d = np.full(len(V), np.inf)
    for j in range(3):
        a, b = V[:, j], V[:, (j + 1) % 3]
        ab = b - a
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
        d = np.minimum(d, np.linalg.norm(a + t[:, None] * ab - p, axis=1))
    return np.where(inside, 0.0, d)


def _split(V: np.ndarray) -> np.ndarray:
    """Each triangle into its four midpoint children, (m, 3, 2) -> (4m, 3, 2)."""
    a, b, c = V[:, 0], V[:, 1], V[:, 2]
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    kids = np.stack([np.stack(t, axis=1) for t in
                     ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))], axis=1)
    return kids.reshape(-1, 3, 2)


def _clip_by_tangent(V: np.ndarray, p: np.ndarray, r: np.ndarray):
    """Triangle V_k clipped by the tangent half-plane (X - p_k).u <= r_k, u
    the direction to its centroid: the pieces as triangles and their owners."""
    u = V.mean(axis=1) - p
    u /= np.linalg.norm(u, axis=1)[:, None]
    s = np.einsum("mkj,mj->mk", V - p[:, None], u) - r[:, None]
    m = len(V)
    out = np.zeros((m, 4, 2))
    on_line = np.zeros((m, 4), dtype=bool)
    cnt = np.zeros(m, dtype=np.int64)
    for j in range(3):                      # Sutherland-Hodgman, one plane
        a, b, sa, sb = V[:, j], V[:, (j + 1) % 3], s[:, j], s[:, (j + 1) % 3]
        keep = np.flatnonzero(sa <= 0)
        out[keep, cnt[keep]] = a[keep]
        cnt[keep] += 1
        cross = np.flatnonzero((sa <= 0) != (sb <= 0))
        t = sa[cross] / (sa[cross] - sb[cross])
        out[cross, cnt[cross]] = a[cross] + t[:, None] * (b[cross] - a[cross])
        on_line[cross, cnt[cross]] = True
        cnt[cross] += 1
    first = np.flatnonzero(cnt >= 3)
    second = np.flatnonzero(cnt == 4)
    tris = np.concatenate([out[first][:, [0, 1, 2]], out[second][:, [0, 2, 3]]])
    # the sliver between the clip line and the arc, over the chord where the
    # line crosses the triangle, was counted but lies outside D: one point
    # of weight -(its exact area) at its middle takes it back out
    ends = np.flatnonzero(on_line.sum(axis=1) == 2)
    both, on_line = out[ends], on_line[ends]
    chord = both[on_line].reshape(-1, 2, 2)
    side = np.stack([-u[ends, 1], u[ends, 0]], axis=1)
    lat = np.sort(np.einsum("ekj,ej->ek", chord - p[ends, None], side), axis=1)
    rr = r[ends]
    lat = np.clip(lat, -rr[:, None], rr[:, None])
    F = rr[:, None] * lat - 0.5 * (lat * np.sqrt(rr[:, None] ** 2 - lat ** 2)
                                    + rr[:, None] ** 2 * np.arcsin(lat / rr[:, None]))
    sliver = F[:, 1] - F[:, 0]
    width = lat[:, 1] - lat[:, 0]
    depth = np.divide(sliver, width, out=np.zeros_like(sliver), where=width > 0)   # mean depth
    mid = chord.mean(axis=1) - u[ends] * (depth / 2)[:, None]
    return tris, np.concatenate([first, second]), (mid, -sliver, ends)


class AttachmentWeights:
    """Disc-average weights on one rest mesh (a KD-tree of its triangles is
    built once; each query touches only the triangles near the discs, and
    all discs are integrated together)."""

    def __init__(self, mesh: Mesh):
        self.mesh = mesh
        self.corners = mesh.X[mesh.triangles]                       # (n_elems, 3, 2)
        centroid = self.corners.mean(axis=1)
        self.reach = float(np.max(np.linalg.norm(self.corners - centroid[:, None], axis=2)))
        self.tree = cKDTree(centroid)

    def weights(self, p, r: float, node: int) -> tuple[np.ndarray, np.ndarray]:
        """(nodes, weights) of the via point p at mesh node ``node``: the
        node with weight 1 for r = 0, else the disc average (sum exactly 1)."""
        return self.weights_many([p], [r], [node])[0]

    def weights_many(self, points, radii, nodes) -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`weights` of many via points at once."""
        radii = np.asarray(radii, dtype=np.float64)
        out = [(np.array([v], dtype=np.int64), np.array([1.0])) for v in nodes]
        disc = np.flatnonzero(radii > 0)
        if not len(disc):
            return out
        for k, (ids, integral, area) in zip(disc, self.integrals_many(
                np.asarray(points, dtype=np.float64).reshape(-1, 2)[disc], radii[disc])):
            w = integral / area
            keep = np.abs(w) > WEIGHT_DROP
            ids, w = ids[keep], w[keep] / w[keep].sum()
            w[np.argmax(w)] += 1.0 - w.sum()        # the rounding of the scaling, onto the largest
            out[k] = (ids, w)
        return out

    def integrals(self, p, r: float) -> tuple[np.ndarray, np.ndarray, float]:
        """(nodes, integral of N_i over D n body, area of D n body) for the
        disc D of radius r > 0 around p."""
        return self.integrals_many(np.reshape(p, (1, 2)), np.array([r]))[0]

    def integrals_many(self, P: np.ndarray, R: np.ndarray) -> list:
        """:meth:`integrals` of discs (P[k], R[k]), R > 0, all at once."""
        near = self.tree.query_ball_point(P, R + self.reach)
        point = np.repeat(np.arange(len(P)), [len(c) for c in near])
        cand = np.concatenate([np.asarray(c, dtype=np.int64) for c in near])
        hit = _distance_to_triangles(self.corners[cand], P[point]) <= R[point]
        point, cand = point[hit], cand[hit]
        V, owner = self.corners[cand], np.arange(len(cand))
        pieces, owners = [], []                  # pieces inside D (whole or clipped)
        extra_pts, extra_w, extra_owner = [], [], []    # sliver corrections
        depth = 0
        while len(V):
            depth += 1
            if depth > MAX_SPLIT_DEPTH:
                raise SceneError(f"attachment radius {float(np.min(R)):.3g}: too small to integrate over "
                                 "this mesh (the problem file refuses radii below 1e-6 of the body's size)")
            p, r = P[point[owner]], R[point[owner]]
            inside = np.all(np.linalg.norm(V - p[:, None], axis=2) <= r[:, None], axis=1)
            pieces.append(V[inside])
            owners.append(owner[inside])
            cut = ~inside & (_distance_to_triangles(V, p) <= r)
            V, owner, p, r = V[cut], owner[cut], p[cut], r[cut]
            wide = np.max(np.linalg.norm(V - np.roll(V, 1, axis=1), axis=2), axis=1) > LEAF_FRACTION * r
            tris, which, (mid, wgt, whose) = _clip_by_tangent(V[~wide], p[~wide], r[~wide])
            pieces.append(tris)
            owners.append(owner[~wide][which])
            extra_pts.append(mid)
            extra_w.append(wgt)
            extra_owner.append(owner[~wide][whose])
            V, owner = _split(V[wide]), np.repeat(owner[wide], 4)
        V, owner = np.concatenate(pieces), np.concatenate(owners)
        qpts = np.concatenate([np.einsum("qk,mkj->mqj", _RULE, V).reshape(-1, 2)] + extra_pts)
        qw = np.concatenate([np.repeat(triangle_areas(V) / 3, 3)] + extra_w)
        q_owner = np.concatenate([np.repeat(owner, 3)] + extra_owner)
        elem = cand[q_owner]
        beta = _barycentric(self.corners[elem], qpts)
        N = self.mesh.element.interpolation_weights(beta) * qw[:, None]
        ids = self.mesh.elements[elem]
        pt = np.repeat(point[q_owner], ids.shape[1])
        keys, inv = np.unique(pt * self.mesh.n_nodes + ids.ravel(), return_inverse=True)
        integral = np.bincount(inv, weights=N.ravel(), minlength=len(keys))
        area = np.bincount(point[q_owner], weights=qw, minlength=len(P))
        key_pt, key_node = np.divmod(keys, self.mesh.n_nodes)
        bounds = np.searchsorted(key_pt, np.arange(len(P) + 1))
        return [(key_node[a:b], integral[a:b], float(area[k]))
                for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))]


class TendonPoints:
    """The tendons' via points as z = [x; extra points]: a point of a tendon
    with r = 0 is its node's own coordinates in x; each point with r > 0 is
    an extra pair of coordinates, sum_i w_i x_i.

    ``weights[t]`` : (n_via, n_nodes) CSR, tendon t's via points as weighted
    nodes (a selection for r = 0): the one accessor for via-point weights.
    ``paths[t]`` : indices of tendon t's points in z-space nodes (< n_nodes
    for a node, n_nodes + k for extra point k).
    """

    def __init__(self, mesh: Mesh, tendons):
        n = mesh.n_nodes
        self.n_nodes = n
        radii = [float(t.attachment_radius) for t in tendons]
        flat = []                                # (p, r, node) of every via point
        for tendon, nodes, r in zip(tendons, mesh.tendon_nodes, radii):
            flat += [(p, r, int(v)) for p, v in zip(tendon.path, nodes)]
        if any(r > 0 for r in radii):
            found = AttachmentWeights(mesh).weights_many(*zip(*flat))
        else:
            found = [(np.array([v], dtype=np.int64), np.array([1.0])) for _, _, v in flat]
        self.weights, self.paths, rows = [], [], []
        start = 0
        for nodes, r in zip(mesh.tendon_nodes, radii):
            entries = found[start:start + len(nodes)]
            start += len(nodes)
            indptr = np.concatenate([[0], np.cumsum([len(e[0]) for e in entries])])
            W = sp.csr_matrix((np.concatenate([e[1] for e in entries]),
                               np.concatenate([e[0] for e in entries]), indptr),
                              shape=(len(entries), n))
            self.weights.append(W)
            if r > 0:
                self.paths.append(n + len(rows) + np.arange(len(entries), dtype=np.int64))
                rows.extend(W[k] for k in range(len(entries)))
            else:
                self.paths.append(np.asarray(nodes, dtype=np.int64))
        self.n_extra = len(rows)
        extra = sp.vstack(rows).tocsr() if rows else sp.csr_matrix((0, n))
        # flat (interleaved) version: row 2k+d of point k reads dof 2i+d
        self.extra_dofs = sp.kron(extra, sp.identity(2), format="csr")
        self._extra_T = self.extra_dofs.T      # (a CSC view, built once: to_nodes runs per evaluation)
        # z-dofs -> node dofs: A = [I; extra_dofs], row by row
        self.A = sp.vstack([sp.identity(2 * n, format="csr"), self.extra_dofs]).tocsr()
        self.n_z = 2 * (n + self.n_extra)

    def mean_disc_nodes(self) -> float:
        """Nodes per attachment disc, on average (0 without discs)."""
        return float(self.extra_dofs.getnnz() / (2 * self.n_extra)) if self.n_extra else 0.0

    def points(self, x: np.ndarray) -> np.ndarray:
        """z of the flat pose x (x itself when every radius is 0)."""
        return x if self.n_extra == 0 else np.concatenate([x, self.extra_dofs @ x])

    def to_nodes(self, gz: np.ndarray) -> np.ndarray:
        """Pull a z-space gradient (or columns of them) back to node dofs: A^T gz."""
        if self.n_extra == 0:
            return gz
        n2 = 2 * self.n_nodes
        return gz[:n2] + self._extra_T @ gz[n2:]

    def expand(self, a: np.ndarray, b: np.ndarray, A: sp.csr_matrix | None = None):
        """The node-dof entries of z-space Hessian entries (a_k, b_k):
        entry k contributes A[a_k, i] A[b_k, j] to (i, j) (``A``: the map
        z = A x, or a stand-in for it of the same shape). Returns
        (k, i, j, factor) arrays."""
        A = self.A if A is None else A
        ia, ib = A.indptr[a], A.indptr[b]
        na, nb = A.indptr[a + 1] - ia, A.indptr[b + 1] - ib
        count = na * nb
        k = np.repeat(np.arange(len(a)), count)
        off = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        ja, jb = ia[k] + off // nb[k], ib[k] + off % nb[k]
        return k, A.indices[ja], A.indices[jb], A.data[ja] * A.data[jb]
