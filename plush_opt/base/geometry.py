"""Plane geometry shared by the problem-file checks and the mesher.

Diameters and areas of point sets and polygons, crossings of polygon
edges, where points lie against a polygonal body, and point location in a
triangle mesh. Everything works on ``(k, 2)`` float64 arrays, one row per
point, and is vectorised (no Python loop over points or triangles).
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

#: point location searches triangles whose reaches differ by less than this
#: factor with one radius: small enough that few extra triangles are tried,
#: large enough that a graded mesh needs only a few searches per point
LEVEL_RATIO = 2.0
#: relative slack on the search radius of point location, far above the
#: rounding of the barycentric weights (so no triangle is missed)
LOCATE_SLACK = 1e-6
#: absolute term of the barycentric tolerance: points on an edge count as
#: inside despite the rounding of their weights
WEIGHT_EPS = 1e-12


def diameter(points) -> float:
    """Largest distance between two of ``points`` ((k, 2) array), 0 if k < 2."""
    pts = np.unique(np.asarray(points, dtype=np.float64).reshape(-1, 2), axis=0)
    if len(pts) < 2:
        return 0.0
    try:
        hull = pts[ConvexHull(pts).vertices]       # counter-clockwise
    except QhullError:                             # all on one line
        d = pts[-1] - pts[0]
        s = pts @ d
        return float(np.hypot(*(pts[np.argmax(s)] - pts[np.argmin(s)])))
    # Antipodal pairs of the convex hull: for each edge, the vertex where the
    # edge direction turned by pi falls (edge angles increase around a convex
    # counter-clockwise polygon); the diameter is attained at such a pair.
    n = len(hull)
    edge = np.roll(hull, -1, axis=0) - hull
    ang = np.unwrap(np.arctan2(edge[:, 1], edge[:, 0]))
    ext = np.concatenate([ang, ang + 2 * np.pi, ang + 4 * np.pi])
    j = np.searchsorted(ext, ang + np.pi)
    i = np.arange(n)
    cand_i = np.concatenate([i, i + 1, i, i + 1, i, i + 1]) % n
    cand_j = np.concatenate([j, j, j - 1, j - 1, j + 1, j + 1]) % n
    d = hull[cand_i] - hull[cand_j]
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", d, d))))


def ring_area(ring: np.ndarray) -> float:
    """Signed area of a closed polygon (positive if counter-clockwise)."""
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def body_area(outline: np.ndarray, holes=()) -> float:
    """Area of the body an outline and its holes enclose."""
    return abs(ring_area(outline)) - sum(abs(ring_area(h)) for h in holes)


def triangle_areas(V: np.ndarray) -> np.ndarray:
    """Unsigned area of each triangle, (m, 3, 2) -> (m,)."""
    d1, d2 = V[:, 1] - V[:, 0], V[:, 2] - V[:, 0]
    return 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def _segments(rings):
    a = np.concatenate(rings)
    b = np.concatenate([np.roll(r, -1, axis=0) for r in rings])
    ring_id = np.concatenate([np.full(len(r), k) for k, r in enumerate(rings)])
    local = np.concatenate([np.arange(len(r)) for r in rings])
    size = np.concatenate([np.full(len(r), len(r)) for r in rings])
    return a, b, ring_id, local, size


def find_crossing(rings, chunk=1 << 20):
    """First pair of non-adjacent polygon edges that cross or touch.

    ``rings`` are closed polygons ((k, 2) arrays). Returns
    ``((ring, edge), (ring, edge))`` or None. Sweep over x with bounding-box
    pruning, so ordinary outlines cost about O(k log k).
    """
    a, b, rid, loc, size = _segments(rings)
    m = len(a)
    xmin, xmax = np.minimum(a[:, 0], b[:, 0]), np.maximum(a[:, 0], b[:, 0])
    ymin, ymax = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
    order = np.argsort(xmin, kind="stable")
    xs = xmin[order]
    hi = np.searchsorted(xs, xmax[order], side="right")
    counts = np.maximum(hi - np.arange(m) - 1, 0)
    ends = np.cumsum(counts)
    start = 0
    while start < m:
        base = ends[start - 1] if start else 0
        stop = int(np.searchsorted(ends, base + chunk, side="right"))
        stop = max(stop, start + 1)
        p = np.arange(start, stop)
        c = counts[p]
        total = int(c.sum())
        if total:
            ps = np.repeat(p, c)
            offs = np.arange(total) - np.repeat(np.cumsum(c) - c, c)
            i, j = order[ps], order[ps + 1 + offs]
            keep = (ymin[i] <= ymax[j]) & (ymin[j] <= ymax[i])
            same = rid[i] == rid[j]
            gap = np.abs(loc[i] - loc[j])
            keep &= ~(same & ((gap == 1) | (gap == size[i] - 1)))
            i, j = i[keep], j[keep]
            if i.size:
                hit = segments_touch(a[i], b[i], a[j], b[j])
                if hit.any():
                    k = np.flatnonzero(hit)
                    pairs = sorted((min((int(rid[i[q]]), int(loc[i[q]])),
                                        (int(rid[j[q]]), int(loc[j[q]]))),
                                    max((int(rid[i[q]]), int(loc[i[q]])),
                                        (int(rid[j[q]]), int(loc[j[q]]))))
                                   for q in k)
                    return pairs[0]
        start = stop
    return None


def _orient(a, b, c):
    return np.sign((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                   - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def segments_touch(a, b, c, d):
    """Closed segments ``a[s]b[s]`` and ``c[s]d[s]`` share a point, (s,) bool
    (their bounding boxes are known to overlap)."""
    o1, o2 = _orient(a, b, c), _orient(a, b, d)
    o3, o4 = _orient(c, d, a), _orient(c, d, b)
    return (o1 * o2 <= 0) & (o3 * o4 <= 0)


def _ring_contains(points: np.ndarray, ring: np.ndarray, chunk=1 << 20) -> np.ndarray:
    """Even-odd point-in-polygon test, (m,) bool (boundary undefined)."""
    out = np.zeros(len(points), dtype=bool)
    a, b = ring, np.roll(ring, -1, axis=0)
    step = max(1, chunk // max(len(ring), 1))
    for s in range(0, len(points), step):
        p = points[s:s + step, None, :]
        ay, by = a[None, :, 1], b[None, :, 1]
        straddle = (ay > p[..., 1]) != (by > p[..., 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = a[None, :, 0] + (p[..., 1] - ay) * (b[None, :, 0] - a[None, :, 0]) / (by - ay)
        out[s:s + step] = (np.count_nonzero(straddle & (p[..., 0] < xint), axis=1) % 2) == 1
    return out


def distance_to_segments(points: np.ndarray, a: np.ndarray, b: np.ndarray, chunk=1 << 20):
    """Distance of each point to the nearest segment a[s]b[s], its index and
    the parameter t in [0, 1] along it: three (m,) arrays."""
    m = len(points)
    dist = np.full(m, np.inf)
    seg = np.zeros(m, dtype=np.int64)
    par = np.zeros(m)
    if len(a) == 0:
        return dist, seg, par
    d = b - a
    dd = np.einsum("ij,ij->i", d, d)
    step = max(1, chunk // len(a))
    for s in range(0, m, step):
        p = points[s:s + step, None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.clip(np.einsum("mkj,kj->mk", p - a[None], d) / dd[None], 0.0, 1.0)
        t = np.where(dd[None] > 0, t, 0.0)
        q = a[None] + t[..., None] * d[None]
        r = np.hypot(p[..., 0] - q[..., 0], p[..., 1] - q[..., 1])
        k = np.argmin(r, axis=1)
        rows = np.arange(len(k))
        dist[s:s + step], seg[s:s + step], par[s:s + step] = r[rows, k], k, t[rows, k]
    return dist, seg, par


def classify_points(points: np.ndarray, rings, tol: float) -> np.ndarray:
    """Where points lie against the body bounded by ``rings`` (outline first,
    then holes): 1 inside, 0 on the boundary (within ``tol``), -1 outside."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    out = np.full(len(points), -1, dtype=np.int64)
    if len(points) == 0:
        return out
    inside = _ring_contains(points, rings[0])
    for h in rings[1:]:
        inside &= ~_ring_contains(points, h)
    out[inside] = 1
    a, b, *_ = _segments(list(rings))
    dist, _, _ = distance_to_segments(points, a, b)
    out[dist <= tol] = 0
    return out


def _weights(a, b, c, p):
    """Barycentric weights of points ``p`` in triangles ``abc`` (arrays that
    broadcast against each other, last axis x, y), stacked on a new last axis.

    Every path of point location computes the weights with this one
    expression, so they agree to the last bit."""
    v0, v1 = b - a, c - a
    det = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    w = p - a
    l1 = (w[..., 0] * v1[..., 1] - w[..., 1] * v1[..., 0]) / det
    l2 = (v0[..., 0] * w[..., 1] - v0[..., 1] * w[..., 0]) / det
    return np.stack([1.0 - l1 - l2, l1, l2], axis=-1)


def barycentric(tri_pts: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric weights of every point in every triangle, (m, n_elems, 3).

    ``tri_pts`` is (n_elems, 3, 2) corner coordinates, ``points`` (m, 2)."""
    tri_pts = np.asarray(tri_pts, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return _weights(tri_pts[None, :, 0], tri_pts[None, :, 1], tri_pts[None, :, 2],
                    points[:, None, :])


def _weight_tolerance(tri_pts: np.ndarray, tol: float) -> np.ndarray:
    """The distance tolerance in barycentric units per triangle, (n_elems,):
    a weight is about distance / height, and the smallest height is twice
    the area over the longest edge."""
    e = np.stack([tri_pts[:, 1] - tri_pts[:, 0], tri_pts[:, 2] - tri_pts[:, 1],
                  tri_pts[:, 0] - tri_pts[:, 2]], axis=1)
    area2 = np.abs(e[:, 0, 0] * e[:, 2, 1] - e[:, 0, 1] * e[:, 2, 0])
    longest = np.sqrt(np.max(np.einsum("ekj,ekj->ek", e, e), axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return tol * longest / area2 + WEIGHT_EPS


def _best_of(tri_pts, wtol, points, cand):
    """Best triangle among candidates for each point.

    ``cand`` is (m, k) triangle indices sorted ascending per row, with
    ``len(tri_pts)`` as padding. The best is the one where the point lies
    deepest (largest smallest weight) among those within tolerance; the
    first in ``cand`` order, so the lowest index, on ties."""
    n = len(tri_pts)
    valid = cand < n
    c = np.where(valid, cand, 0)
    corners = tri_pts[c]                                     # (m, k, 3, 2)
    bw = _weights(corners[..., 0, :], corners[..., 1, :], corners[..., 2, :],
                  points[:, None, :])
    depth = np.min(bw, axis=2)
    score = np.where(valid & (depth >= -wtol[c]), depth, -np.inf)
    k = np.argmax(score, axis=1)
    rows = np.arange(len(k))
    ok = np.isfinite(score[rows, k])
    tri = np.where(ok, c[rows, k], -1)
    beta = np.where(ok[:, None], bw[rows, k], np.nan)
    return tri, beta


class _Index:
    """KD-trees of triangle centroids, one per size class, for exact searches.

    The points within tolerance of a triangle (all weights >= -w) form the
    triangle scaled by 1 + 3w about its centroid, so they lie within
    ``reach = (1 + 3w) x`` (largest centroid-corner distance) of the
    centroid. Triangles are grouped by reach (within a factor
    :data:`LEVEL_RATIO`), and a point's candidates in a group are the
    centroids within the group's largest reach: no triangle that can hold
    the point is missed, and in a graded mesh small triangles are not
    searched with the radius of large ones. Triangles of zero area hold no
    point (the brute-force rule gives them no finite depth) and are left out.
    """

    def __init__(self, tri_pts: np.ndarray, wtol: np.ndarray):
        centroid = tri_pts.mean(axis=1)
        radius = np.sqrt(np.max(np.sum((tri_pts - centroid[:, None, :]) ** 2, axis=2), axis=1))
        with np.errstate(invalid="ignore"):
            reach = (1.0 + 3.0 * wtol) * radius
        ids = np.flatnonzero(np.isfinite(reach) & (reach > 0))
        self.levels = []
        if ids.size == 0:
            return
        level = np.floor(np.log(reach[ids] / reach[ids].min()) / np.log(LEVEL_RATIO))
        for lv in np.unique(level):
            members = ids[level == lv]
            self.levels.append((members, cKDTree(centroid[members]),
                                float(reach[members].max()) * (1.0 + LOCATE_SLACK)))

    def candidates(self, points: np.ndarray, sentinel: int, chunk: int):
        """Candidate triangles of every point, in blocks of about ``chunk``
        pairs: yields (rows, (len(rows), width) candidates ascending per row,
        ``sentinel`` padded)."""
        m = len(points)
        rows, tris = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
        for members, tree, r in self.levels:
            balls = tree.query_ball_point(points, r)
            count = np.fromiter(map(len, balls), dtype=np.int64, count=m)
            rows.append(np.repeat(np.arange(m), count))
            tris.append(members[np.fromiter(itertools.chain.from_iterable(balls), dtype=np.int64,
                                            count=int(count.sum()))])
        rows, tris = np.concatenate(rows), np.concatenate(tris)
        order = np.lexsort((tris, rows))
        rows, tris = rows[order], tris[order]
        count = np.bincount(rows, minlength=m)
        edges = np.concatenate([[0], np.cumsum(count)])          # row i: pairs edges[i]:edges[i+1]
        cols = np.arange(len(rows)) - edges[rows]
        step = max(1, chunk // max(1, int(count.max(initial=0))))
        for s in range(0, m, step):
            e = min(s + step, m)
            block = slice(edges[s], edges[e])
            cand = np.full((e - s, max(1, int(count[s:e].max()))), sentinel, dtype=np.int64)
            cand[rows[block] - s, cols[block]] = tris[block]
            yield np.arange(s, e), cand


def locate_in_triangles(tri_pts: np.ndarray, points: np.ndarray, tol: float = 0.0,
                        chunk=1 << 18):
    """Triangle holding each point and its barycentric weights.

    Candidates come from a KD-tree of the triangle centroids (see
    :class:`_Index`), and the answer is the same as testing every point
    against every triangle.

    Parameters
    ----------
    tri_pts : (n_elems, 3, 2) triangle corner coordinates.
    points : (m, 2) query points.
    tol : distance tolerance (length units) for points on or just outside an edge.
    chunk : at most this many (point, candidate) pairs are evaluated at once.

    Returns
    -------
    tri : (m,) int64, index of the triangle (-1 if none is within ``tol``);
        among several (a point on an edge), the one where the point lies
        deepest inside (largest smallest weight), lowest index on ties.
    beta : (m, 3) float64 weights in that triangle's corner order (NaN if none).
    """
    tri_pts = np.asarray(tri_pts, dtype=np.float64).reshape(-1, 3, 2)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    m, n = len(points), len(tri_pts)
    tri = np.full(m, -1, dtype=np.int64)
    beta = np.full((m, 3), np.nan)
    if n == 0 or m == 0:
        return tri, beta
    wtol = _weight_tolerance(tri_pts, tol)
    index = _Index(tri_pts, wtol)
    finite = np.flatnonzero(np.all(np.isfinite(points), axis=1))  # others lie in no triangle
    for part, cand in index.candidates(points[finite], n, chunk):
        r = finite[part]
        tri[r], beta[r] = _best_of(tri_pts, wtol, points[r], cand)
    return tri, beta
