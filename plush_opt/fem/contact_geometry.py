"""The plane geometry contact stands on: the IPC barrier on squared
distances, point-segment squared distances with their derivatives,
conservative continuous collision detection (CCD) for a point and a
segment, a broad phase that finds the pairs worth looking at in
near-linear time (a uniform grid), and exact segment crossing and polygon
tests.

Everything works on arrays of pairs at once (k pairs: points ``(k, 2)``,
scalars ``(k,)``); lengths are in the scene's length unit, squared
distances in its square.

Distances follow IPC (Li et al. 2020, "Incremental Potential Contact"): the
distance type of each pair (to end a, to end b, to the interior) is chosen
from where the point projects, and the derivatives are those of that type;
the squared distance is C1 across the types.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np

# A squared distance this close to d_hat^2 (relative) takes its logarithm
# from log1p of the small difference, so b, b' and b'' vanish smoothly
# instead of through cancellation; far below it log(s / d_hat^2) is exact.
LOG1P_FROM = 0.5

# CCD: at most this many advancing steps for every pair at once. A pair
# that needs more slides a long way along a close surface; it keeps its last
# safe time, which is conservative.
CCD_MAX_ITERATIONS = 1000
# CCD stops once the distance has come within this factor of its floor
# (min_fraction times the starting distance): steps shrink geometrically
# from there and gain little.
CCD_NEAR_FLOOR = 2.0

# Shewchuk's bound on the rounding error of a 2D orientation determinant
# computed in doubles (ccwerrboundA): within it the sign is decided exactly.
_EPS = 2.0 ** -53
ORIENT_ERRBOUND = (3.0 + 16.0 * _EPS) * _EPS

# Constant maps from the pose (p, a, b) flattened as [px, py, ax, ay, bx, by]
# to the local variables of each distance type.
_I2 = np.eye(2)
_Z2 = np.zeros((2, 2))
_TO_A = np.hstack([_I2, -_I2, _Z2])                  # q = p - a
_TO_B = np.hstack([_I2, _Z2, -_I2])                  # r = p - b
_TO_LINE = np.vstack([_TO_A, np.hstack([_Z2, -_I2, _I2])])   # (q, e = b - a)
# Hessian of cross(e, q) = e_x q_y - e_y q_x in the variables (q_x, q_y, e_x, e_y)
_CROSS_HESS = np.array([[0.0, 0.0, 0.0, -1.0],
                        [0.0, 0.0, 1.0, 0.0],
                        [0.0, 1.0, 0.0, 0.0],
                        [-1.0, 0.0, 0.0, 0.0]])
_LEN_HESS = np.diag([0.0, 0.0, 2.0, 2.0])            # Hessian of |e|^2

TO_A, TO_B, INTERIOR = 0, 1, 2


# --- the barrier -------------------------------------------------------------

def barrier(s, dhat2, order: int = 2):
    """The IPC barrier on a squared distance ``s`` and its derivatives in s.

    b(s) = -(s - dhat2)^2 ln(s / dhat2) for 0 < s < dhat2, 0 for s >= dhat2
    (C2 there: b, b', b'' all vanish), +inf for s <= 0 (derivatives nan).
    ``s`` any shape, ``dhat2`` a scalar or broadcastable; returns
    ``(b, db/ds, d2b/ds2)`` of the broadcast shape, the derivatives above
    ``order`` (0, 1 or 2) None.
    """
    s = np.asarray(s, float)
    if s.ndim == 1 and np.ndim(dhat2) == 0 and (s.size == 0 or (s.min() > 0 and s.max() < dhat2)):
        return _barrier_inside(s, float(dhat2), order)   # (every pair active: the common case)
    s, h = np.broadcast_arrays(s, np.asarray(dhat2, float))
    b, db, d2b = np.zeros(s.shape), np.zeros(s.shape), np.zeros(s.shape)
    inside = (s > 0) & (s < h)
    b[inside], db[inside], d2b[inside] = _barrier_inside(s[inside], h[inside])
    bad = (s <= 0) | np.isnan(s)
    b[bad] = np.where(np.isnan(s[bad]), np.nan, np.inf)
    db[bad] = d2b[bad] = np.nan
    return b, (db if order >= 1 else None), (d2b if order >= 2 else None)


def barrier_slope(s: np.ndarray, dhat2: float) -> np.ndarray:
    """db/ds of :func:`barrier` alone (the same values), for 1-d ``s`` and a
    scalar ``dhat2``: what a force along a path needs, without b''."""
    return barrier(s, dhat2, order=1)[1]


def _log_ratio(s, u, h):
    """ln(s / h) at 0 < s < h (1-d ``s``; ``u`` = s - h; ``h`` a scalar or
    alike): from log1p of u / h near h (exact where s -> h), else directly."""
    near = s >= LOG1P_FROM * h
    if near.all():
        return np.log1p(u / h)
    ln = np.empty_like(s)
    hb = np.broadcast_to(h, s.shape)
    ln[near] = np.log1p(u[near] / hb[near])
    ln[~near] = np.log(s[~near] / hb[~near])
    return ln


def _barrier_inside(s, h, order: int = 2):
    """:func:`barrier` at 0 < s < h (1-d ``s``; ``h`` a scalar or alike),
    the derivatives above ``order`` None."""
    u = s - h                                           # < 0, exact near dhat2
    ln = _log_ratio(s, u, h)
    with np.errstate(over="ignore"):                   # s below about 1e-154 dhat2: b'' is inf
        b = -u * u * ln
        db = -2.0 * u * ln - u * u / s if order >= 1 else None
        d2b = -2.0 * ln - 4.0 * u / s + (u / s) ** 2 if order >= 2 else None
    return b, db, d2b


# --- point-segment distance --------------------------------------------------

def _pairs(*arrays):
    return [np.asarray(v, float).reshape(-1, 2) for v in arrays]


def _cross(u, v):
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def pair_type(p, a, b) -> np.ndarray:
    """Which part of segment [a, b] is nearest to p, (k,) int: 0 the end a,
    1 the end b, 2 the interior. A segment of zero length counts as its end a."""
    p, a, b = _pairs(p, a, b)
    e, q = b - a, p - a
    length2 = np.einsum("ij,ij->i", e, e)
    along = np.einsum("ij,ij->i", q, e)               # t * |e|^2
    kind = np.full(len(p), INTERIOR)
    kind[along >= length2] = TO_B
    kind[along <= 0] = TO_A                           # also every zero-length segment
    return kind


def _point_point(d, order):
    s = np.einsum("ij,ij->i", d, d)
    g = 2.0 * d if order >= 1 else None
    h = np.broadcast_to(2.0 * _I2, (len(d), 2, 2)) if order >= 2 else None
    return s, g, h


def _point_line(q, e, order):
    """s = cross(e, q)^2 / |e|^2 and its derivatives in (q, e), (k, 4)."""
    c, length2 = _cross(e, q), np.einsum("ij,ij->i", e, e)
    s = c * c / length2
    if order == 0:
        return s, None, None
    gc = np.column_stack([-e[:, 1], e[:, 0], q[:, 1], -q[:, 0]])
    gl = np.column_stack([np.zeros((len(e), 2)), 2.0 * e])
    g = (2.0 * c / length2)[:, None] * gc - (c * c / length2 ** 2)[:, None] * gl
    if order == 1:
        return s, g, None
    # d2(c^2 / L) = 2 dc dc^T / L + 2 c d2c / L - 2 c (dc dL^T + dL dc^T) / L^2
    #               - c^2 d2L / L^2 + 2 c^2 dL dL^T / L^3
    col = lambda v: v[:, None, None]                    # noqa: E731
    gcl = np.einsum("ki,kj->kij", gc, gl)
    h = (col(2.0 / length2) * np.einsum("ki,kj->kij", gc, gc)
         + col(2.0 * c / length2) * _CROSS_HESS
         - col(2.0 * c / length2 ** 2) * (gcl + gcl.transpose(0, 2, 1))
         - col(c * c / length2 ** 2) * _LEN_HESS
         + col(2.0 * c * c / length2 ** 3) * np.einsum("ki,kj->kij", gl, gl))
    return s, g, h


def point_segment_sq(p, a, b, order: int = 2):
    """Squared unsigned distance from p to segment [a, b], with derivatives.

    ``p, a, b`` (k, 2). Returns ``(s, grad, hess)``: s (k,); grad (k, 6) and
    hess (k, 6, 6) with respect to [px, py, ax, ay, bx, by], each of the
    distance type :func:`pair_type` picks. ``order`` 0 gives s only (grad
    and hess None), 1 no hess.
    """
    p, a, b = _pairs(p, a, b)
    k = len(p)
    kind = pair_type(p, a, b)
    s = np.empty(k)
    grad = np.zeros((k, 6)) if order >= 1 else None
    hess = np.zeros((k, 6, 6)) if order >= 2 else None
    for which, to_local in ((TO_A, _TO_A), (TO_B, _TO_B), (INTERIOR, _TO_LINE)):
        idx = np.flatnonzero(kind == which)
        if idx.size == 0:
            continue
        if which == INTERIOR:
            si, gi, hi = _point_line(p[idx] - a[idx], b[idx] - a[idx], order)
        else:
            si, gi, hi = _point_point(p[idx] - (a if which == TO_A else b)[idx], order)
        s[idx] = si
        if order >= 1:
            grad[idx] = gi @ to_local                  # chain rule through a constant map
        if order >= 2:
            hess[idx] = to_local.T @ hi @ to_local
    return s, grad, hess


# --- continuous collision detection ------------------------------------------

def _approach_bound(dp, da, db):
    """Upper bound on how fast the point-segment distance can shrink over the
    motion (length per unit time): relative to the mean displacement, the
    point's speed plus the fastest point of the segment (IPC's l_p)."""
    mean = (dp + da + db) / 3.0
    speed = lambda v: np.linalg.norm(v - mean, axis=1)   # noqa: E731
    return speed(dp) + np.maximum(speed(da), speed(db))


# Power basis -> Bernstein basis of degree 4 on [0, 1]: M[i, j] = C(i, j) / C(4, j).
_TO_BERNSTEIN = np.array([[1.0, 0, 0, 0, 0],
                          [1.0, 1 / 4, 0, 0, 0],
                          [1.0, 2 / 4, 1 / 6, 0, 0],
                          [1.0, 3 / 4, 3 / 6, 1 / 4, 0],
                          [1.0, 1.0, 1.0, 1.0, 1.0]])
# The line certificate asks its Bernstein coefficients to clear rounding by
# this much, relative to the size of the terms they are made of.
LINE_CERTIFICATE_MARGIN = 1e-9


def _line_stays_clear(p, a, b, dp, da, db, t, floor):
    """Whether p provably stays farther than ``floor`` from the segment's
    whole line for every time in [t, 1], (k,) bool. The segment is part of
    its line, so this certifies the pair; it settles sliding contacts at
    once, which additive steps would cross in many small strides.

    With time s = t + tau (1 - t): cross(e, q) = c0 + c1 tau + c2 tau^2 and
    |e|^2 = l0 + l1 tau + l2 tau^2; the quartic cross^2 - floor^2 |e|^2 is
    positive on [0, 1] when all its Bernstein coefficients are.
    """
    rest = (1.0 - t)[:, None]
    q, e = (p - a) + t[:, None] * (dp - da), (b - a) + t[:, None] * (db - da)
    dq, de = rest * (dp - da), rest * (db - da)
    c0, c1, c2 = _cross(e, q), _cross(e, dq) + _cross(de, q), _cross(de, dq)
    dot = lambda u, v: np.einsum("ij,ij->i", u, v)      # noqa: E731
    f2 = floor * floor
    l0, l1, l2 = dot(e, e), 2.0 * dot(e, de), dot(de, de)
    power = np.column_stack([c0 * c0 - f2 * l0, 2 * c0 * c1 - f2 * l1, c1 * c1 + 2 * c0 * c2 - f2 * l2,
                             2 * c1 * c2, c2 * c2])
    size = (np.abs(c0) + np.abs(c1) + np.abs(c2)) ** 2 + f2 * (l0 + np.abs(l1) + l2)
    return np.all(power @ _TO_BERNSTEIN.T > LINE_CERTIFICATE_MARGIN * size[:, None], axis=1)


def ccd_point_segment(p, a, b, dp, da, db, *, min_fraction: float = 0.2,
                      tolerance: float = 1e-6, max_iterations: int = CCD_MAX_ITERATIONS):
    """Conservative time of impact of linear motions p + t dp, a + t da,
    b + t db, t in [0, 1], all pairs at once (additive CCD, Li et al. 2021,
    "Codimensional Incremental Potential Contact", Algorithm 1).

    Returns t (k,): on [0, t] the distance never falls below ``min_fraction``
    times its value at t = 0, so p never reaches the segment. Exactly 1.0
    for a pair that never comes that close; 0.0 for a pair already touching
    at t = 0. Each pair advances by steps its approach bound makes safe
    until p provably stays clear of the segment's line for the rest of the
    motion (then its t is 1), its distance comes within CCD_NEAR_FLOOR of
    the floor, a step advances t by less than ``tolerance``, or
    ``max_iterations`` steps are done; it stops at its last safe time.
    """
    if not 0.0 < min_fraction < 1.0:
        raise ValueError(f"ccd_point_segment: min_fraction must be in (0, 1), not {min_fraction}")
    p, a, b, dp, da, db = _pairs(p, a, b, dp, da, db)
    speed = _approach_bound(dp, da, db)
    dist = np.sqrt(point_segment_sq(p, a, b, order=0)[0])
    floor = min_fraction * dist
    t = np.where((dist > 0) & (speed == 0), 1.0, 0.0)   # a rigid translation never closes
    active = np.flatnonzero((dist > 0) & (speed > 0))
    for _ in range(max_iterations):
        clear = _line_stays_clear(p[active], a[active], b[active], dp[active], da[active], db[active],
                                  t[active], floor[active])
        t[active[clear]] = 1.0
        active = active[~clear]
        if active.size == 0:
            break
        # on [t, t + step] the distance stays >= dist - speed * step = floor
        step = np.maximum(dist[active] - floor[active], 0.0) / speed[active]
        reached = t[active] + step >= 1.0
        t[active[reached]] = 1.0
        active, step = active[~reached], step[~reached]
        t[active] += step
        at = t[active][:, None]
        dist[active] = np.sqrt(point_segment_sq(p[active] + at * dp[active], a[active] + at * da[active],
                                                b[active] + at * db[active], order=0)[0])
        stop = (dist[active] < CCD_NEAR_FLOOR * floor[active]) | (step < tolerance)
        active = active[~stop]
    return t


# --- exact crossings and polygons --------------------------------------------

def _exact_orientation(a, b, c) -> int:
    ax, ay, bx, by, cx, cy = (Fraction(float(v)) for v in (*a, *b, *c))
    det = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    return (det > 0) - (det < 0)


def orientation(a, b, c) -> np.ndarray:
    """Sign of the turn a -> b -> c (+1 counter-clockwise, -1 clockwise,
    0 collinear), (k,) int, exact for finite coordinates: the double
    determinant decides where it is beyond its rounding bound, rational
    arithmetic the rest (collinear or nearly collinear triples only)."""
    a, b, c = _pairs(a, b, c)
    left = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
    right = (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    det = left - right
    sign = np.sign(det).astype(np.int64)
    for i in np.flatnonzero(np.abs(det) <= ORIENT_ERRBOUND * (np.abs(left) + np.abs(right))):
        sign[i] = _exact_orientation(a[i], b[i], c[i])
    return sign


def segments_intersect(a1, b1, a2, b2) -> np.ndarray:
    """Closed segments [a1, b1] and [a2, b2] share a point (crossing or
    touching, collinear overlap included), (k,) bool, exact."""
    a1, b1, a2, b2 = _pairs(a1, b1, a2, b2)
    boxes = np.all((np.minimum(a1, b1) <= np.maximum(a2, b2))
                   & (np.minimum(a2, b2) <= np.maximum(a1, b1)), axis=1)
    hit = np.zeros(len(a1), dtype=bool)
    i = np.flatnonzero(boxes)
    o1, o2 = orientation(a1[i], b1[i], a2[i]), orientation(a1[i], b1[i], b2[i])
    o3, o4 = orientation(a2[i], b2[i], a1[i]), orientation(a2[i], b2[i], b1[i])
    # with the boxes overlapping, straddling both lines (or lying on them) is sharing a point
    hit[i] = (o1 * o2 <= 0) & (o3 * o4 <= 0)
    return hit


def _ring_edges(outline):
    P = np.asarray(outline, float)
    return P, np.roll(P, -1, axis=0)


def polygon_is_simple(outline):
    """Whether a closed polygon ``outline`` (k, 2) is simple: ``(True, None)``,
    or ``(False, i)`` with i the first offending edge (edge i runs from
    vertex i to i + 1): one of zero length, one folding back onto the next,
    or one meeting a non-adjacent edge; ``(False, None)`` for fewer than
    3 points or no area. A zero-length edge is named before any other fault."""
    P = np.asarray(outline, float)
    if P.ndim != 2 or P.shape[1] != 2 or len(P) < 3:
        return False, None
    a, b = _ring_edges(P)
    zero = np.flatnonzero(np.all(a == b, axis=1))
    if zero.size:                                    # said first: its neighbours touch through it
        return False, int(zero[0])
    bad = []
    nxt = np.roll(b, -1, axis=0)
    folds = (orientation(a, b, nxt) == 0) & (np.einsum("ij,ij->i", b - a, nxt - b) < 0)
    bad += list(np.flatnonzero(folds))
    ids = np.column_stack([np.arange(len(P)), (np.arange(len(P)) + 1) % len(P)])
    i, j = crossing_pairs(a, b, shared=ids)
    bad += list(np.minimum(i, j))
    if bad:
        return False, int(min(bad))
    area2 = np.sum(_cross(a, b))
    return (True, None) if area2 != 0 else (False, None)


def points_in_polygon(points, outline, chunk: int = 1 << 20) -> np.ndarray:
    """Even-odd rule: which points lie inside the closed polygon ``outline``
    (k, 2), (n,) bool (points on the boundary: either answer). Costs
    n * k work, in chunks of about ``chunk`` point-edge pairs."""
    return points_inside(points, *_ring_edges(outline), chunk=chunk)


def points_inside(points, a, b, chunk: int = 1 << 20) -> np.ndarray:
    """Even-odd rule over segments: which points lie inside the region the
    segments ``a`` -> ``b`` (k, 2 each) bound (closed rings in any order:
    an outline and its holes), (n,) bool (points on a segment: either
    answer). Costs n * k work, in chunks of about ``chunk`` point-segment
    pairs."""
    pts = np.asarray(points, float).reshape(-1, 2)
    a, b = np.asarray(a, float).reshape(-1, 2), np.asarray(b, float).reshape(-1, 2)
    out = np.zeros(len(pts), dtype=bool)
    rows = max(1, chunk // max(len(a), 1))
    for s in range(0, len(pts), rows):
        x, y = pts[s:s + rows, 0:1], pts[s:s + rows, 1:2]
        straddle = (a[:, 1] > y) != (b[:, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            cut = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        out[s:s + rows] = np.count_nonzero(straddle & (x < cut), axis=1) % 2 == 1
    return out


# --- broad phase: a uniform grid ---------------------------------------------

# The grid's cells start at the median box size; while the boxes together
# would cover more than this many cells per box (a few huge boxes), the
# cells double: the work stays near-linear in the number of boxes.
GRID_CELLS_PER_BOX = 16
# Cell indices per axis stay below this so that a cell's key fits an int64.
GRID_MAX_CELLS_PER_AXIS = 2 ** 30
# Segments longer than this many times the median are cut into pieces for
# the grid (a long obstacle edge's box would cover many cells it is far
# from); at or below it a segment stays whole, as most are.
PIECE_RATIO = 2.0
# Boxes grow by this many ulps of their coordinates, so a segment cut into
# pieces (rounded) stays inside its pieces' boxes.
BOX_PAD_ULPS = 8.0


def _cell_size(extents_b, extents_a, span) -> float:
    for ext in (extents_b, extents_a):
        positive = ext[ext > 0]
        if positive.size:
            return float(np.median(positive))
    return float(span.max()) or 1.0                    # boxes are points: any size will do


def _cells(ilo, ihi, width):
    """(cell key, box index) for every grid cell each box covers."""
    n = ihi - ilo + 1
    count = n[:, 0] * n[:, 1]
    box = np.repeat(np.arange(len(ilo)), count)
    off = np.arange(box.size) - np.repeat(np.cumsum(count) - count, count)
    return (ilo[box, 0] + off // n[box, 1]) * width + ilo[box, 1] + off % n[box, 1], box


def _grid(lo_a, hi_a, lo_b, hi_b, origin, span):
    """Both sets' cell ranges (lo, hi) as int64, on cells doubled from
    the median box size until the boxes cover a near-linear number of them."""
    h = _cell_size((hi_b - lo_b).max(axis=1), (hi_a - lo_a).max(axis=1), span)
    while True:
        if span.max() / h < GRID_MAX_CELLS_PER_AXIS:
            ranges = [(np.floor((lo - origin) / h), np.floor((hi - origin) / h))
                      for lo, hi in ((lo_a, hi_a), (lo_b, hi_b))]
            cover = sum(np.prod(hi - lo + 1, axis=1).sum() for lo, hi in ranges)
            if cover <= GRID_CELLS_PER_BOX * (len(lo_a) + len(lo_b)):
                return [(lo.astype(np.int64), hi.astype(np.int64)) for lo, hi in ranges]
        h *= 2.0


def box_pairs(lo_a, hi_a, lo_b, hi_b, unique: bool = True):
    """Every pair of overlapping closed boxes, box i of A and box j of B
    (each ``(n, 2)`` corners), through a uniform grid.

    Returns ``(ia, ib, tested)``: the pairs sorted by (ib, ia) (with
    ``unique`` False unsorted, a pair that shares several cells repeated),
    and ``tested`` the number of box pairs the grid put side by side (the
    work done: near-linear in the boxes when they are about as large as
    their spacing). Corners must be finite (ValueError otherwise).
    """
    lo_a, hi_a, lo_b, hi_b = _pairs(lo_a, hi_a, lo_b, hi_b)
    none = np.zeros(0, dtype=np.int64)
    if len(lo_a) == 0 or len(lo_b) == 0:
        return none, none, 0
    if not all(np.isfinite(v).all() for v in (lo_a, hi_a, lo_b, hi_b)):
        raise ValueError("box_pairs: a box with a non-finite corner")   # no grid holds it
    origin, top = lo_b.min(axis=0), hi_b.max(axis=0)
    # A's boxes outside B's union meet nothing; the rest are clipped to it
    inside = np.flatnonzero(np.all((lo_a <= top) & (hi_a >= origin), axis=1))
    la, ha = np.maximum(lo_a[inside], origin), np.minimum(hi_a[inside], top)
    (alo, ahi), (blo, bhi) = _grid(la, ha, lo_b, hi_b, origin, top - origin)
    width = int(bhi[:, 1].max()) + 1
    kb, jb = _cells(blo, bhi, width)
    order = np.argsort(kb, kind="stable")
    kb, jb = kb[order], jb[order]
    ka, ja = _cells(alo, ahi, width)
    order = np.argsort(ka, kind="stable")              # sorted needles search about 4x faster
    ka, ja = ka[order], ja[order]
    start, stop = np.searchsorted(kb, ka, "left"), np.searchsorted(kb, ka, "right")
    count = stop - start
    tested = int(count.sum())
    pos = np.repeat(start - (np.cumsum(count) - count), count) + np.arange(tested)
    ia, ib = inside[ja[np.repeat(np.arange(len(ka)), count)]], jb[pos]
    la, ha, lb, hb = lo_a[ia], hi_a[ia], lo_b[ib], hi_b[ib]
    meet = ((la[:, 0] <= hb[:, 0]) & (la[:, 1] <= hb[:, 1])         # columns by hand: np.all(axis=1)
            & (lb[:, 0] <= ha[:, 0]) & (lb[:, 1] <= ha[:, 1]))      # is several times slower
    if not unique:
        return ia[meet], ib[meet], tested
    key = np.unique(ib[meet] * len(lo_a) + ia[meet])
    return key % len(lo_a), key // len(lo_a), tested


def _pieces(starts, ends, size):
    """Cut segments (one row per segment; ``starts``/``ends`` stacked
    (c, m, 2) for several configurations of the same segments) into pieces
    no longer than PIECE_RATIO times ``size``: (piece starts, piece ends,
    segment index)."""
    length = np.linalg.norm(ends - starts, axis=2).max(axis=0)
    k = np.ones(len(length), dtype=np.int64)
    if size > 0:
        k = np.maximum(1, np.ceil(length / (PIECE_RATIO * size))).astype(np.int64)
    seg = np.repeat(np.arange(len(length)), k)
    j = np.arange(seg.size) - np.repeat(np.cumsum(k) - k, k)
    f0, f1 = (j / k[seg])[:, None], ((j + 1) / k[seg])[:, None]
    e = (ends - starts)[:, seg]
    p0, p1 = starts[:, seg] + f0 * e, starts[:, seg] + f1 * e
    last = j == k[seg] - 1
    p1[:, last] = ends[:, seg[last]]                    # the last piece ends where its segment does
    return p0, p1, seg


def _piece_boxes(starts, ends, radius, size):
    """Boxes around the pieces of segments in every configuration given,
    grown by the segment's radius: (lo, hi, segment index)."""
    p0, p1, seg = _pieces(starts, ends, size)
    corners = np.concatenate([p0, p1])
    pad = BOX_PAD_ULPS * np.finfo(float).eps * np.abs(corners).max(axis=(0, 2))
    grow = (np.broadcast_to(radius, (starts.shape[1],))[seg] + pad)[:, None]
    return corners.min(axis=0) - grow, corners.max(axis=0) + grow, seg


def _keep_not_excluded(point, seg, exclude):
    if exclude is None or point.size == 0:
        return point, seg
    ex = np.asarray(exclude, dtype=np.int64).reshape(len(np.asarray(exclude)), -1)
    keep = ~(ex[seg] == point[:, None]).any(axis=1)
    return point[keep], seg[keep]


def _segment_pairs(lo, hi, seg, point_lo, point_hi):
    """(point, segment) pairs whose boxes meet, segment pieces merged."""
    ia, ib, _ = box_pairs(point_lo, point_hi, lo, hi, unique=False)   # merged once below
    n = len(point_lo)
    key = np.unique(seg[ib] * n + ia)
    return key % n, key // n


def candidate_pairs(points, seg_a, seg_b, radius, exclude=None):
    """Every (point, segment) pair closer than ``radius`` (scalar or per
    segment (m,)): points (n, 2), segments from seg_a[j] to seg_b[j] (m, 2).
    ``exclude`` (m, q) int: point indices to skip for each segment (-1 pads).
    Returns int64 arrays (point_idx, seg_idx) sorted by (seg, point), the
    pairs with squared distance <= radius^2. Near-linear time: a grid over
    the segments, cut into pieces about their median length."""
    pts, a, b = _pairs(points, seg_a, seg_b)
    r = np.broadcast_to(np.asarray(radius, float), (len(a),))
    size = float(np.median(np.linalg.norm(b - a, axis=1) + 2 * r)) if len(a) else 0.0
    lo, hi, seg = _piece_boxes(a[None], b[None], r, size)
    point, seg = _segment_pairs(lo, hi, seg, pts, pts)
    point, seg = _keep_not_excluded(point, seg, exclude)
    near = point_segment_sq(pts[point], a[seg], b[seg], order=0)[0] <= r[seg] ** 2
    return point[near], seg[near]


def motion_candidates(points, dpoints, seg_a, seg_b, dseg_a, dseg_b, radius, exclude=None):
    """The pairs of :func:`candidate_pairs` for a linear motion (points move
    by ``dpoints``, segment ends by ``dseg_a``/``dseg_b``, all (., 2)):
    every pair that may come closer than ``radius`` at some time in [0, 1]
    (swept boxes that meet, and a start distance minus the pair's largest
    possible approach not beyond ``radius``). Sorted by (seg, point)."""
    pts, dpts, a, b, da, db = _pairs(points, dpoints, seg_a, seg_b, dseg_a, dseg_b)
    r = np.broadcast_to(np.asarray(radius, float), (len(a),))
    size = float(np.median(np.linalg.norm(b - a, axis=1) + 2 * r)) if len(a) else 0.0
    lo, hi, seg = _piece_boxes(np.stack([a, a + da]), np.stack([b, b + db]), r, size)
    swept = (np.minimum(pts, pts + dpts), np.maximum(pts, pts + dpts))
    point, seg = _segment_pairs(lo, hi, seg, *swept)
    point, seg = _keep_not_excluded(point, seg, exclude)
    start = np.sqrt(point_segment_sq(pts[point], a[seg], b[seg], order=0)[0])
    reach = _approach_bound(dpts[point], da[seg], db[seg])
    close = start - reach <= r[seg] * (1 + 1e-12) + 1e-300    # rounding: keep the borderline
    return point[close], seg[close]


def _share_an_end(i, j, a, b, shared):
    if shared is not None:
        ids = np.asarray(shared, dtype=np.int64)
        return (ids[i][:, :, None] == ids[j][:, None, :]).any(axis=(1, 2))
    ends_i, ends_j = np.stack([a[i], b[i]], 1), np.stack([a[j], b[j]], 1)
    return np.all(ends_i[:, :, None] == ends_j[:, None, :], axis=3).any(axis=(1, 2))


def crossing_pairs(seg_a, seg_b, other_a=None, other_b=None, exclude_shared=True, shared=None):
    """Pairs of segments that share a point (cross or touch), exact.

    Within one set (``other_a``/``other_b`` None): (i, j) with i < j; with
    ``exclude_shared``, pairs sharing an end are left out: by node id when
    ``shared`` (m, 2) gives each segment's end nodes, else by equal end
    coordinates. Between two sets: (i, j) with i in the first, j in the
    second. Returns int64 arrays sorted by (i, j); near-linear time.
    """
    a, b = _pairs(seg_a, seg_b)
    one_set = other_a is None
    oa, ob = (a, b) if one_set else _pairs(other_a, other_b)
    lengths = np.linalg.norm(np.concatenate([b - a, ob - oa]), axis=1)
    size = float(np.median(lengths)) if lengths.size else 0.0
    lo1, hi1, s1 = _piece_boxes(a[None], b[None], 0.0, size)
    lo2, hi2, s2 = _piece_boxes(oa[None], ob[None], 0.0, size)
    ia, ib, _ = box_pairs(lo1, hi1, lo2, hi2, unique=False)
    key = np.unique(s1[ia] * len(oa) + s2[ib])
    i, j = key // len(oa), key % len(oa)
    if one_set:
        keep = i < j
        i, j = i[keep], j[keep]
        if exclude_shared:
            keep = ~_share_an_end(i, j, a, b, shared)
            i, j = i[keep], j[keep]
    hit = segments_intersect(a[i], b[i], oa[j], ob[j])
    return i[hit], j[hit]
