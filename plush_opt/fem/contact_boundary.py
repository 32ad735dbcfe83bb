"""The body's contact surface: its boundary as straight segments.

The boundary edges of the mesh (outline and holes), oriented with the body
on their left; a P2 boundary edge is split at its midside node into two
segments (docs/problem-format.md, "Contact"). Boundary nodes are the
segments' end points; each carries the length weight w of its pairs (half
the summed rest lengths of the segments at it), and knows its neighbours
along the boundary (self-contact skips them). :func:`self_crossing` finds
where a pose's boundary passes through itself (a scene without
self-contact allows it; a level or a result that does is flagged).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import contact_geometry as geo
from .mesh import Mesh


@dataclass(frozen=True)
class Boundary:
    """The contact surface of one mesh.

    nodes : (b,) int64 mesh indices of the boundary nodes (sorted).
    segments : (m, 2) int64 mesh node indices of each segment's ends, the
        body on the left going from the first to the second.
    local : (m, 2) the same ends as indices into ``nodes``.
    weight : (b,) length weight of each boundary node (length units).
    rest_length : (m,) each segment's rest length.
    near : (m, q) int64, per segment the indices into ``nodes`` that a
        self-contact pair with it skips (its ends and their neighbours
        along the boundary), padded with -1.
    """

    nodes: np.ndarray
    segments: np.ndarray
    local: np.ndarray
    weight: np.ndarray
    rest_length: np.ndarray
    near: np.ndarray


def boundary_segments(mesh: Mesh) -> np.ndarray:
    """(m, 2) node indices of the boundary segments of ``mesh``, each
    oriented as in its (counter-clockwise) element: the body on its left."""
    tri = mesh.triangles
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    outer = edges[counts[inverse.ravel()] == 1]
    if str(mesh.element) != "P2":
        return outer
    # a P2 element lists [a, b, c, ab, bc, ca]: each corner edge's midside node
    elem = mesh.elements
    corner = np.concatenate([elem[:, [0, 1]], elem[:, [1, 2]], elem[:, [2, 0]]])
    mid = np.concatenate([elem[:, 3], elem[:, 4], elem[:, 5]])
    lookup = {(int(a), int(b)): int(m) for (a, b), m in zip(corner, mid)}
    middle = np.array([lookup[(int(a), int(b))] for a, b in outer], dtype=np.int64)
    return np.concatenate([np.stack([outer[:, 0], middle], axis=1),
                           np.stack([middle, outer[:, 1]], axis=1)])


def build_boundary(mesh: Mesh) -> Boundary:
    """The :class:`Boundary` of ``mesh`` at its rest positions."""
    segments = boundary_segments(mesh)
    nodes, local = np.unique(segments, return_inverse=True)
    local = local.reshape(-1, 2)
    X = mesh.X
    rest_length = np.linalg.norm(X[segments[:, 1]] - X[segments[:, 0]], axis=1)
    weight = 0.5 * np.bincount(local.ravel(), weights=np.repeat(rest_length, 2), minlength=len(nodes))
    # neighbours along the boundary: the other end of every segment at a node
    b = len(nodes)
    nbrs = [[] for _ in range(b)]
    for i, j in local:
        nbrs[i].append(j)
        nbrs[j].append(i)
    near = [sorted({int(i), int(j), *nbrs[i], *nbrs[j]}) for i, j in local]
    width = max((len(n) for n in near), default=0)
    near_arr = np.full((len(local), width), -1, dtype=np.int64)
    for k, n in enumerate(near):
        near_arr[k, :len(n)] = n
    return Boundary(nodes=nodes.astype(np.int64), segments=segments.astype(np.int64),
                    local=local.astype(np.int64), weight=weight, rest_length=rest_length,
                    near=near_arr)


def self_crossing(boundary: Boundary, x: np.ndarray) -> str | None:
    """Where the boundary of flat pose ``x`` crosses itself: the first two
    crossing segments (neither sharing an end node) and the point, in
    words; None where it does not."""
    P = np.asarray(x, dtype=np.float64).reshape(-1, 2)[boundary.nodes]
    A, B = P[boundary.local[:, 0]], P[boundary.local[:, 1]]
    i, j = geo.crossing_pairs(A, B, shared=boundary.local)
    if not len(i):
        return None
    s, t = boundary.segments[i[0]], boundary.segments[j[0]]
    near = 0.25 * (A[i[0]] + B[i[0]] + A[j[0]] + B[j[0]])
    return (f"boundary segments {int(s[0])}-{int(s[1])} and {int(t[0])}-{int(t[1])} cross "
            f"near ({near[0]:.4g}, {near[1]:.4g})")


def crossings(model, poses) -> tuple:
    """Per flat pose of ``model`` in ``poses`` (None: no pose), where it
    crosses itself (:func:`self_crossing`) or None, in a scene whose body
    may pass through itself (no ``contact.self``); () in one whose may not.
    The contact term's boundary is used where the model has one."""
    contact = model.contact
    if contact is not None and contact.self_contact:
        return ()
    boundary = contact.boundary if contact is not None else build_boundary(model.mesh)
    return tuple(None if x is None else self_crossing(boundary, x) for x in poses)
