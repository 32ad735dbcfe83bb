"""The body's contact surface: its boundary as straight segments.

The boundary edges of the mesh (outline and holes), oriented with the body
on their left; a P2 boundary edge is split at its midside node into two
segments (docs/problem-format.md, "Contact"). Boundary nodes are the
segments' end points; each carries the length weight w of its pairs (half
the summed rest lengths of the segments at it), and knows its neighbours
along the boundary (self-contact skips them). :func:`self_crossing` finds
where a pose's boundary passes through itself (a scene without
self-contact allows it; a level or a result that does is flagged), and
tells a crease (the boundary folded back on itself over a short stretch)
from an overlap (two parts of the body far apart along it passing through
each other).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

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


_BOUNDARIES: dict[int, Boundary] = {}     # boundary_of's, by id of a live mesh


def boundary_of(mesh: Mesh) -> Boundary:
    """:func:`build_boundary` of ``mesh``, built once while the mesh lives
    (a crossing test with it costs a few per cent of building it: 1.3 ms
    against 35 ms on a 10,000-node P1 mesh)."""
    key = id(mesh)
    found = _BOUNDARIES.get(key)
    if found is None:
        found = _BOUNDARIES[key] = build_boundary(mesh)
        weakref.finalize(mesh, _BOUNDARIES.pop, key, None)
    return found


#: A crossing whose two segments are at most this fraction of their loop's
#: rest length apart along the boundary is a crease. A crease has no length
#: scale (each finer mesh folds further), an overlap converges like any
#: pose. Measured (docs/notes/accuracy-measurements.md, "A crease and an
#: overlap, along the boundary"): creases 0.5-3 % of their loop apart, the
#: thin strip's curled end over its base 35 %.
CREASE_SPAN = 0.1


def self_crossing(boundary: Boundary, x: np.ndarray, creases_only: bool = False) -> str | None:
    """Where the boundary of flat pose ``x`` crosses itself: the first two
    crossing segments (neither sharing an end node), the point and how far
    apart the two are along the rest boundary (a crease, or an overlap: see
    :data:`CREASE_SPAN`), in words; None where it does not (with
    ``creases_only``: where it has no crease)."""
    P = np.asarray(x, dtype=np.float64).reshape(-1, 2)[boundary.nodes]
    A, B = P[boundary.local[:, 0]], P[boundary.local[:, 1]]
    i, j = geo.crossing_pairs(A, B, shared=boundary.local)
    if not len(i):
        return None
    apart, loop = crossing_spans(boundary, i, j)
    crease = apart <= CREASE_SPAN * loop
    k = int(np.argmax(crease)) if crease.any() else (None if creases_only else 0)
    if k is None:
        return None
    if not crease[k]:               # (the search above stopped at a crease's span: the whole way for this one)
        apart[k] = crossing_spans(boundary, i[k:k + 1], j[k:k + 1], limit=None)[0][0]
    s, t = boundary.segments[i[k]], boundary.segments[j[k]]
    near = 0.25 * (A[i[k]] + B[i[k]] + A[j[k]] + B[j[k]])
    how = (f"a crease, {apart[k]:.3g} apart along a boundary of {loop[k]:.4g}" if crease[k] else
           "an overlap, on separate boundaries" if not np.isfinite(apart[k]) else
           f"an overlap, {apart[k]:.3g} apart along a boundary of {loop[k]:.4g}")
    return (f"boundary segments {int(s[0])}-{int(s[1])} and {int(t[0])}-{int(t[1])} cross "
            f"near ({near[0]:.4g}, {near[1]:.4g}): {how}")


def crossing_spans(boundary: Boundary, i: np.ndarray, j: np.ndarray,
                   limit: float | None = CREASE_SPAN) -> tuple[np.ndarray, np.ndarray]:
    """For segment pairs (``i``, ``j``) of ``boundary``: the rest length
    along the boundary between them (the shortest way from an end of one to
    an end of the other; inf on separate loops, e.g. a hole's and the
    outline's, and beyond ``limit`` times the longest of their loops) and
    the rest length of the loop of ``i``."""
    local, length = boundary.local, boundary.rest_length
    n = len(boundary.nodes)
    graph = sp.coo_matrix((np.r_[length, length], (np.r_[local[:, 0], local[:, 1]], np.r_[local[:, 1], local[:, 0]])),
                          shape=(n, n)).tocsr()
    _, label = connected_components(graph, directed=False)
    loop = np.bincount(label[local[:, 0]], weights=length)[label[local[i, 0]]]
    sources, row = np.unique(local[i].ravel(), return_inverse=True)
    dist = dijkstra(graph, indices=sources, limit=np.inf if limit is None else limit * float(loop.max()) * 1.01)
    row = row.reshape(-1, 2)
    apart = np.min([dist[row[:, a], local[j, b]] for a in (0, 1) for b in (0, 1)], axis=0)
    return apart, loop


def crossings(model, poses, creases_only: bool = False) -> tuple:
    """Per flat pose of ``model`` in ``poses`` (None: no pose), where it
    crosses itself (:func:`self_crossing`; with ``creases_only``, where it
    creases) or None, in a scene whose body may pass through itself (no
    ``contact.self``); () in one whose may not. The contact term's
    boundary is used where the model has one."""
    contact = model.contact
    if contact is not None and contact.self_contact:
        return ()
    boundary = contact.boundary if contact is not None else boundary_of(model.mesh)
    return tuple(None if x is None else self_crossing(boundary, x, creases_only) for x in poses)
