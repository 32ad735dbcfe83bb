"""Contact geometry: the barrier and the point-segment distance against
finite differences and high-precision values, CCD never stepping through a
segment (property test over random motions), the broad phase against brute
force and its work counted, crossings and polygons on known cases."""

import decimal

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from plush_opt.fem import contact_geometry as cg

FD_STEP = 1e-6


# --- the barrier -------------------------------------------------------------

def _barrier_decimal(s, h):
    """b, b', b'' in 60-digit arithmetic."""
    decimal.getcontext().prec = 60
    S, H = decimal.Decimal(s), decimal.Decimal(h)
    u, ln = S - H, (S / H).ln()
    return float(-u * u * ln), float(-2 * u * ln - u * u / S), float(-2 * ln - 4 * u / S + (u / S) ** 2)


@pytest.mark.parametrize("s", [1e-300, 1e-100, 1e-30, 1e-8, 0.01, 0.3, 0.5, 0.7, 0.999, 1 - 1e-6,
                               1 - 1e-12, 1 - 2 ** -52])
@pytest.mark.parametrize("h", [1.0, 1e-6, 3e4])
def test_barrier_matches_high_precision_from_tiny_s_to_dhat(s, h):
    ours = [v[0] for v in cg.barrier(np.array([s * h]), h)]
    for value, exact in zip(ours, _barrier_decimal(s * h, h)):
        assert value == pytest.approx(exact, rel=1e-12, abs=0)


def test_barrier_derivatives_match_finite_differences():
    h = 2.0
    s = np.array([1e-4, 0.01, 0.3, 0.9, 1.5, 1.99])
    b, db, d2b = cg.barrier(s, h)
    e = FD_STEP * s
    bp, dbp, _ = cg.barrier(s + e, h)
    bm, dbm, _ = cg.barrier(s - e, h)
    np.testing.assert_allclose(db, (bp - bm) / (2 * e), rtol=1e-6)
    np.testing.assert_allclose(d2b, (dbp - dbm) / (2 * e), rtol=1e-6)
    assert np.all(b > 0) and np.all(db < 0) and np.all(d2b > 0)


def test_barrier_is_c2_at_dhat_and_zero_beyond():
    h = 0.25
    delta = np.array([1e-2, 1e-4, 1e-6, 1e-8])
    b, db, d2b = cg.barrier(h * (1 - delta), h)
    # b ~ delta^3, b' ~ delta^2, b'' ~ delta: all three vanish at dhat2
    np.testing.assert_allclose(b / (h * delta) ** 3 * h, 1.0, rtol=2e-2)
    np.testing.assert_allclose(db / (h * delta) ** 2 * h, -3.0, rtol=2e-2)
    np.testing.assert_allclose(d2b / (h * delta) * h, 6.0, rtol=2e-2)
    out = cg.barrier(np.array([h, 2 * h, 1e300]), h)
    assert all(np.all(v == 0) for v in out)


def test_barrier_slope_is_the_barriers_first_derivative_value_for_value():
    h = 0.25
    inside = np.concatenate([np.geomspace(1e-12, 0.49, 20), np.linspace(0.5, 0.999, 20)]) * h
    near = np.linspace(0.5, 0.999, 20) * h                  # log1p alone
    for s in (inside, near):
        assert np.array_equal(cg.barrier_slope(s, h), cg.barrier(s, h)[1])
    mixed = np.array([0.3 * h, h, 2 * h, 0.0, -1.0])       # active, at and beyond d_hat, touching, crossed
    np.testing.assert_array_equal(cg.barrier_slope(mixed, h), cg.barrier(mixed, h)[1])
    assert cg.barrier_slope(mixed, h)[1] == 0.0 and np.isnan(cg.barrier_slope(mixed, h)[3])


def test_barrier_refuses_touching_and_crossed_pairs():
    b, db, d2b = cg.barrier(np.array([0.0, -1e-3]), 1.0)
    assert np.all(np.isposinf(b)) and np.all(np.isnan(db)) and np.all(np.isnan(d2b))


# --- point-segment distance --------------------------------------------------

def _stacked(x):
    return x[:, 0:2], x[:, 2:4], x[:, 4:6]


def _fd_grad(x, order):
    """Central differences of s (order 0) or of the gradient (order 1), (k, 6[, 6])."""
    cols = []
    for i in range(6):
        e = np.zeros(6)
        e[i] = FD_STEP
        plus = cg.point_segment_sq(*_stacked(x + e), order=order)[order]
        minus = cg.point_segment_sq(*_stacked(x - e), order=order)[order]
        cols.append((plus - minus) / (2 * FD_STEP))
    return np.stack(cols, axis=1)


def _configurations(t, k=40, seed=0):
    """k random segments and points projecting at parameter t along them,
    at a random distance off the line."""
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(2, k, 2))
    e = b - a
    normal = np.column_stack([-e[:, 1], e[:, 0]])
    off = rng.uniform(0.1, 1.0, size=(k, 1)) * rng.choice([-1, 1], size=(k, 1))
    p = a + t * e + off * normal
    return np.hstack([p, a, b])


@pytest.mark.parametrize("t, kind", [(-0.7, cg.TO_A), (0.4, cg.INTERIOR), (1.8, cg.TO_B)])
def test_distance_derivatives_match_finite_differences_in_each_region(t, kind):
    x = _configurations(t)
    assert np.all(cg.pair_type(*_stacked(x)) == kind)
    s, g, h = cg.point_segment_sq(*_stacked(x))
    np.testing.assert_allclose(g, _fd_grad(x, 0), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(h, _fd_grad(x, 1), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(h, h.transpose(0, 2, 1), atol=1e-12)


def _brute_distance_sq(p, a, b, n=200001):
    u = np.linspace(0, 1, n)[None, :, None]
    pts = a[:, None] + u * (b - a)[:, None]
    return np.min(np.sum((pts - p[:, None]) ** 2, axis=2), axis=1)


@pytest.mark.parametrize("t", [-0.5, 0.0, 0.25, 1.0, 1.5])
def test_distance_is_the_nearest_point_of_the_segment(t):
    p, a, b = _stacked(_configurations(t, k=8, seed=3))
    s = cg.point_segment_sq(p, a, b, order=0)[0]
    assert np.all(s <= _brute_distance_sq(p, a, b) + 1e-12)
    assert np.all(s >= _brute_distance_sq(p, a, b) - 1e-9)


@pytest.mark.parametrize("end", [0.0, 1.0])
def test_distance_and_gradient_are_continuous_across_the_ends(end):
    step = 1e-9
    below, above = _configurations(end - step, seed=7), _configurations(end + step, seed=7)
    kinds = (cg.pair_type(*_stacked(below)), cg.pair_type(*_stacked(above)))
    assert {int(kinds[0][0]), int(kinds[1][0])} == ({cg.TO_A, cg.INTERIOR} if end == 0
                                                    else {cg.INTERIOR, cg.TO_B})
    s0, g0, _ = cg.point_segment_sq(*_stacked(below))
    s1, g1, _ = cg.point_segment_sq(*_stacked(above))
    # the two sides differ by the move itself only (|grad| * move), no jump
    np.testing.assert_allclose(s0, s1, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(g0, g1, rtol=1e-6, atol=1e-7)


def test_distance_orders_agree_and_degenerate_segment_is_a_point():
    x = _configurations(0.3, k=5)
    full = cg.point_segment_sq(*_stacked(x))
    assert cg.point_segment_sq(*_stacked(x), order=0)[1:] == (None, None)
    np.testing.assert_array_equal(cg.point_segment_sq(*_stacked(x), order=1)[1], full[1])
    s, g, _ = cg.point_segment_sq([[3.0, 4.0]], [[0.0, 0.0]], [[0.0, 0.0]])
    assert s[0] == 25.0 and np.all(np.isfinite(g))


# --- CCD ---------------------------------------------------------------------

# coordinates on a fine lattice: no subnormal dust
coordinate = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False).map(lambda v: round(v, 12))
point = st.tuples(coordinate, coordinate).map(np.array)


@st.composite
def motions(draw):
    """A point, a segment and a linear motion of all three: random, straight
    through the segment, grazing along it, or a rotating segment; steps from
    tiny to huge."""
    p, a, b = draw(point), draw(point), draw(point)
    assume(np.linalg.norm(b - a) > 1e-3)
    scale = 10.0 ** draw(st.integers(-6, 3))
    kind = draw(st.sampled_from(["random", "through", "graze", "rotate"]))
    dp, da, db = (draw(point) * scale for _ in range(3))
    if kind == "through":                       # p aims at an interior point, and beyond
        target = a + draw(st.floats(0.01, 0.99)) * (b - a)
        dp = (target - p) * draw(st.floats(0.5, 20.0))
    elif kind == "graze":                       # p slides along the segment, close to it
        e = (b - a) / np.linalg.norm(b - a)
        p = a + draw(st.floats(-0.5, 0.5)) * (b - a) + 10.0 ** draw(st.integers(-6, -1)) * e[::-1] * [-1, 1]
        dp = scale * e + draw(point) * 1e-3 * scale
    elif kind == "rotate":                      # the ends turn about the middle
        mid, w = (a + b) / 2, draw(st.floats(-7.0, 7.0))
        da, db = w * (a - mid)[::-1] * [-1, 1], w * (b - mid)[::-1] * [-1, 1]
        dp = draw(point) * scale
    return p, a, b, dp, da, db


def _line_crossings(p, a, b, dp, da, db):
    """Times where p lies on the segment's line (roots of a quadratic)."""
    q0, e0, dq, de = p - a, b - a, dp - da, db - da
    cross = lambda u, v: u[0] * v[1] - u[1] * v[0]      # noqa: E731
    coeffs = np.array([cross(de, dq), cross(e0, dq) + cross(de, q0), cross(e0, q0)])
    big = np.abs(coeffs).max()
    if big == 0:
        return np.array([])
    coeffs = np.trim_zeros(np.where(np.abs(coeffs) < 1e-15 * big, 0.0, coeffs / big), "f")
    roots = np.roots(coeffs)
    return np.real(roots[np.abs(np.imag(roots)) <= 1e-12 * (1 + np.abs(roots))])


def _distances(p, a, b, dp, da, db, times):
    at = np.asarray(times)[:, None]
    return np.sqrt(cg.point_segment_sq(p + at * dp, a + at * da, b + at * db, order=0)[0])


@settings(max_examples=400, deadline=None)
@given(motions())
def test_ccd_never_steps_through_the_segment(motion):
    p, a, b, dp, da, db = motion
    d0 = _distances(*motion, [0.0])[0]
    assume(d0 > 1e-9)
    t = cg.ccd_point_segment(p[None], a[None], b[None], dp[None], da[None], db[None])[0]
    assert 0.0 < t <= 1.0
    floor = 0.2 * d0 * (1 - 1e-9)
    times = np.linspace(0.0, t, 4001)
    roots = [r for r in _line_crossings(*motion) if 0.0 <= r <= t]
    # never below the floor: neither at dense samples nor where p meets the line
    assert np.all(_distances(*motion, np.r_[times, roots]) >= floor)
    # while p projects inside the segment, it stays on one side of it (it
    # may change sides going round an end)
    at = times[:, None]
    pa, pb, pp = a + at * da, b + at * db, p + at * dp
    inside = cg.pair_type(pp, pa, pb) == cg.INTERIOR
    side = np.sign(cg._cross(pb - pa, pp - pa))
    both = inside[1:] & inside[:-1]
    assert np.all(side[1:][both] == side[:-1][both])
    # a pair that stays well away runs the whole step
    speed = cg._approach_bound(dp[None], da[None], db[None])[0]
    dense = np.linspace(0.0, 1.0, 4001)
    lowest = _distances(*motion, dense).min() - speed / 4000 / 2
    if lowest > cg.CCD_NEAR_FLOOR * 0.2 * d0 * (1 + 1e-9) and speed < 0.2 * d0 * cg.CCD_MAX_ITERATIONS / 2:
        assert t == 1.0


def test_ccd_known_times_and_all_pairs_at_once():
    # straight at the middle: the first step goes 80 % of the way to the distance floor
    t = cg.ccd_point_segment([[0.5, 1.0]], [[0.0, 0.0]], [[1.0, 0.0]],
                             [[0.0, -2.0]], [[0.0, 0.0]], [[0.0, 0.0]])
    assert t[0] == pytest.approx(0.4)
    # far away, or moving rigidly together: the whole step
    far = cg.ccd_point_segment([[0.5, 10.0], [0.5, 0.1]], [[0.0, 0.0]] * 2, [[1.0, 0.0]] * 2,
                               [[0.0, -1.0], [3.0, 3.0]], [[0.0, 0.0], [3.0, 3.0]],
                               [[0.0, 0.0], [3.0, 3.0]])
    assert np.all(far == 1.0)
    assert cg.ccd_point_segment([[0.0, 0.0]], [[0.0, 0.0]], [[1.0, 0.0]],
                                [[0.0, 1.0]], [[0.0, 0.0]], [[0.0, 0.0]])[0] == 0.0
    # a batch gives each pair the time it gets alone
    rng = np.random.default_rng(5)
    batch = [rng.normal(size=(300, 2)) * s for s in (1, 1, 1, 0.3, 0.3, 0.3)]
    together = cg.ccd_point_segment(*batch)
    alone = [cg.ccd_point_segment(*(v[i:i + 1] for v in batch))[0] for i in range(300)]
    np.testing.assert_array_equal(together, alone)
    assert 0 < np.count_nonzero(together < 1) < 300


def test_ccd_settles_sliding_at_once_and_stops_at_its_budget_safely():
    # sliding along the segment very close to it: the line certificate ends it at 1
    slide = ([[0.0, 1e-4]], [[-1.0, 0.0]], [[1.0, 0.0]], [[1.0, 0.0]], [[0.0, 0.0]], [[0.0, 0.0]])
    assert cg.ccd_point_segment(*slide, max_iterations=1)[0] == 1.0
    # leaving the line just past an end: one additive step of 80 % of the
    # distance, then the certificate; with a budget of one step it stops there
    leave = ([[-1e-3, 0.0]], [[0.0, 0.0]], [[1.0, 0.0]], [[0.0, 1.0]], [[0.0, 0.0]], [[0.0, 0.0]])
    assert cg.ccd_point_segment(*leave, max_iterations=1)[0] == pytest.approx(8e-4)
    assert cg.ccd_point_segment(*leave)[0] == 1.0
    # coming straight at the segment the certificate never holds
    head_on = ([[0.5, 1.0]], [[0.0, 0.0]], [[1.0, 0.0]], [[0.0, -2.0]], [[0.0, 0.0]], [[0.0, 0.0]])
    assert not cg._line_stays_clear(*(np.array(v, float) for v in head_on), np.zeros(1), np.full(1, 0.2))[0]


# --- broad phase -------------------------------------------------------------

def _all_pairs_sq(points, a, b):
    n, m = len(points), len(a)
    s = cg.point_segment_sq(np.repeat(points, m, 0), np.tile(a, (n, 1)), np.tile(b, (n, 1)), order=0)[0]
    return s.reshape(n, m)


clouds = st.tuples(st.integers(0, 60), st.integers(0, 25), st.floats(0.0, 2.0),
                   st.floats(0.01, 3.0), st.integers(0, 2 ** 31))


@settings(max_examples=150, deadline=None)
@given(clouds)
def test_candidate_pairs_are_the_pairs_within_radius(cloud):
    n, m, radius, seg_len, seed = cloud
    rng = np.random.default_rng(seed)
    points = rng.uniform(0, 10, size=(n, 2))
    a = rng.uniform(0, 10, size=(m, 2))
    b = a + rng.normal(scale=seg_len, size=(m, 2))
    r = rng.uniform(0, radius, size=m) if seed % 2 else radius
    point, seg = cg.candidate_pairs(points, a, b, r)
    inside = _all_pairs_sq(points, a, b) <= np.broadcast_to(r, (m,))[None, :] ** 2
    assert set(zip(point.tolist(), seg.tolist())) == set(zip(*np.nonzero(inside)))
    assert np.all(np.diff(seg * max(n, 1) + point) > 0)          # sorted by (seg, point)
    assert point.dtype == seg.dtype == np.int64


def test_candidate_pairs_skip_excluded_points():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.01], [5.0, 5.0]])
    point, seg = cg.candidate_pairs(points, points[[0]], points[[1]], 0.1, exclude=[[0, 1, -1]])
    assert point.tolist() == [2] and seg.tolist() == [0]


@settings(max_examples=100, deadline=None)
@given(clouds, st.floats(0.0, 3.0))
def test_motion_candidates_hold_every_pair_that_comes_close(cloud, move):
    n, m, radius, seg_len, seed = cloud
    rng = np.random.default_rng(seed)
    points, dpoints = rng.uniform(0, 10, size=(n, 2)), rng.normal(scale=move, size=(n, 2))
    a = rng.uniform(0, 10, size=(m, 2))
    b = a + rng.normal(scale=seg_len, size=(m, 2))
    da, db = rng.normal(scale=move, size=(2, m, 2))
    point, seg = cg.motion_candidates(points, dpoints, a, b, da, db, radius)
    found = set(zip(point.tolist(), seg.tolist()))
    for t in np.linspace(0, 1, 21):
        close = _all_pairs_sq(points + t * dpoints, a + t * da, b + t * db) <= radius ** 2
        assert set(zip(*np.nonzero(close))) <= found


def _grid_scene(side, long_edge=False):
    """Points on a side x side lattice, segments between horizontal
    neighbours (and one long edge across it all), radius half the spacing."""
    x, y = np.meshgrid(np.arange(side, dtype=float), np.arange(side, dtype=float))
    points = np.column_stack([x.ravel(), y.ravel()])
    a = points[np.arange(len(points)) % side < side - 1]
    b = a + [1.0, 0.0]
    if long_edge:
        a, b = np.vstack([a, [[0.0, 0.3]]]), np.vstack([b, [[side - 1.0, side - 0.7]]])
    return points, a, b


@pytest.mark.parametrize("long_edge", [False, True])
def test_broad_phase_work_grows_linearly(monkeypatch, long_edge):
    tested = []
    box_pairs = cg.box_pairs

    def counted(*args, **kwargs):
        out = box_pairs(*args, **kwargs)
        tested.append(out[2])
        return out

    monkeypatch.setattr(cg, "box_pairs", counted)
    for side in (20, 40, 80):
        points, a, b = _grid_scene(side, long_edge)
        cg.candidate_pairs(points, a, b, 0.5)
        cg.motion_candidates(points, 0.1 * np.ones_like(points), a, b, 0 * a, 0 * b, 0.5)
    per_point = np.array(tested, dtype=float).reshape(3, 2) / np.array([20, 40, 80])[:, None] ** 2
    assert np.all(per_point < 40)                     # a few neighbours per point, at every size
    assert np.all(per_point[2] < 1.2 * per_point[0])  # work per point does not grow with n


# --- crossings and polygons --------------------------------------------------

@pytest.mark.parametrize("s1, s2, hit", [
    (((0, 0), (2, 2)), ((0, 2), (2, 0)), True),       # X
    (((0, 0), (2, 0)), ((1, 0), (1, 3)), True),       # T: an end on the other's interior
    (((0, 0), (1, 0)), ((1, 0), (2, 5)), True),       # shared end
    (((0, 0), (2, 0)), ((1, 0), (3, 0)), True),       # collinear overlap
    (((0, 0), (1, 0)), ((2, 0), (3, 0)), False),      # collinear apart
    (((0, 0), (1, 0)), ((0, 1), (1, 1)), False),      # parallel
    (((0, 0), (1, 1)), ((1, 0), (2, 1)), False),      # parallel, boxes overlapping
    (((0, 0), (2, 0)), ((1, 1e-300), (1, 1)), False),  # just above
])
def test_segments_intersect_known_cases(s1, s2, hit):
    args = [np.array([v], dtype=float) for v in (*s1, *s2)]
    assert cg.segments_intersect(*args)[0] == hit
    assert cg.segments_intersect(*args[2:], *args[:2])[0] == hit


@settings(max_examples=200, deadline=None)
@given(point, point, st.floats(-2.0, 3.0))
def test_orientation_is_exact_for_nearly_collinear_points(a, b, u):
    from fractions import Fraction
    c = a + u * (b - a)                                # on the line, up to rounding
    F = [Fraction(float(v)) for v in (*a, *b, *c)]
    det = (F[2] - F[0]) * (F[5] - F[1]) - (F[3] - F[1]) * (F[4] - F[0])
    assert cg.orientation(a[None], b[None], c[None])[0] == (det > 0) - (det < 0)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 40), st.integers(0, 2 ** 31), st.booleans())
def test_crossing_pairs_agree_with_all_pairs(m, seed, two_sets):
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 8, size=(m, 2)).astype(float)     # a lattice: many touching and collinear cases
    b = a + rng.integers(-3, 4, size=(m, 2))
    oa, ob = (a[::-1].copy(), b[::-1] + 0.5) if two_sets else (None, None)
    i, j = cg.crossing_pairs(a, b, oa, ob, exclude_shared=False)
    other_a, other_b = (a, b) if oa is None else (oa, ob)
    ii, jj = np.meshgrid(np.arange(m), np.arange(len(other_a)), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    hit = cg.segments_intersect(a[ii], b[ii], other_a[jj], other_b[jj])
    if not two_sets:
        hit &= ii < jj
    assert set(zip(i.tolist(), j.tolist())) == set(zip(ii[hit].tolist(), jj[hit].tolist()))


def test_crossing_pairs_leave_out_neighbours_sharing_an_end():
    chain = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.5, -1.0]])
    a, b = chain[:-1], chain[1:]
    ids = np.column_stack([np.arange(3), np.arange(1, 4)])
    for kwargs in ({}, {"shared": ids}):
        i, j = cg.crossing_pairs(a, b, **kwargs)
        assert list(zip(i.tolist(), j.tolist())) == [(0, 2)]


@pytest.mark.parametrize("outline, expected", [
    ([[0, 0], [1, 0], [1, 1], [0, 1]], (True, None)),
    ([[0, 1], [1, 1], [1, 0], [0, 0]], (True, None)),              # clockwise
    ([[0, 0], [4, 0], [4, 4], [2, 1], [0, 4]], (True, None)),      # concave
    ([[0, 0], [1, 1], [1, 0], [0, 1]], (False, 0)),                # bow tie
    ([[0, 0], [1, 0], [1, 0], [0, 1]], (False, 1)),                # zero-length edge
    ([[0, 0], [2, 0], [1, 0], [1, 1]], (False, 0)),                # folds back onto itself
    ([[0, 0], [4, 0], [4, 4], [2, 0], [0, 4]], (False, 0)),        # a vertex on another edge
    ([[0, 0], [1, 0]], (False, None)),                             # too few points
    ([[0, 0], [1, 1], [2, 2]], (False, 1)),                        # no area: edge 1 folds back
])
def test_polygon_is_simple_known_cases(outline, expected):
    assert cg.polygon_is_simple(np.array(outline, dtype=float)) == expected


def test_points_in_polygon_even_odd():
    u_shape = np.array([[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]], dtype=float)
    pts = np.array([[0.5, 2.0], [1.5, 2.0], [2.5, 2.0], [1.5, 0.5], [4.0, 1.0], [-1.0, 2.0]])
    assert cg.points_in_polygon(pts, u_shape).tolist() == [True, False, True, True, False, False]
    assert cg.points_in_polygon(pts, u_shape[::-1], chunk=3).tolist() == [True, False, True, True,
                                                                        False, False]
    assert cg.points_in_polygon(np.zeros((0, 2)), u_shape).shape == (0,)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 50), st.integers(0, 50), st.integers(0, 3), st.integers(0, 2 ** 31))
def test_box_pairs_agree_with_all_pairs_even_with_huge_boxes(na, nb, huge, seed):
    rng = np.random.default_rng(seed)

    def boxes(n):
        lo = rng.uniform(0, 100, size=(n, 2))
        size = rng.exponential(1.0, size=(n, 2)) * (rng.random((n, 1)) < 0.8)   # some points
        size[:min(huge, n)] *= 1e4                                             # a few huge boxes
        return lo, lo + size

    (la, ha), (lb, hb) = boxes(na), boxes(nb)
    ia, ib, _ = cg.box_pairs(la, ha, lb, hb)
    meet = np.all((la[:, None] <= hb[None]) & (lb[None] <= ha[:, None]), axis=2)
    assert set(zip(ia.tolist(), ib.tolist())) == set(zip(*np.nonzero(meet)))


def test_candidate_pairs_with_a_zero_length_segment():
    points = np.array([[0.0, 0.05], [0.0, 0.5]])
    point, seg = cg.candidate_pairs(points, [[0.0, 0.0]], [[0.0, 0.0]], 0.1)
    assert point.tolist() == [0] and seg.tolist() == [0]


@settings(max_examples=60, deadline=None)
@given(st.integers(3, 30), st.integers(0, 2 ** 31))
def test_points_in_polygon_agrees_with_matplotlib_on_star_polygons(k, seed):
    path = pytest.importorskip("matplotlib.path")
    rng = np.random.default_rng(seed)
    angle = np.sort(rng.uniform(0, 2 * np.pi, k))
    outline = rng.uniform(0.3, 1.0, size=(k, 1)) * np.column_stack([np.cos(angle), np.sin(angle)])
    pts = rng.uniform(-1.1, 1.1, size=(400, 2))
    a, b = outline, np.roll(outline, -1, axis=0)
    s = np.min([cg.point_segment_sq(pts, np.broadcast_to(a[i], pts.shape), np.broadcast_to(b[i], pts.shape),
                                    order=0)[0] for i in range(k)], axis=0)
    clear = s > 1e-12                                  # on the boundary either answer is right
    expected = path.Path(outline).contains_points(pts)
    assert np.array_equal(cg.points_in_polygon(pts, outline)[clear], expected[clear])


def test_broad_phase_refuses_non_finite_coordinates():
    with pytest.raises(ValueError, match="non-finite"):
        cg.candidate_pairs([[np.nan, 0.0]], [[0.0, 0.0]], [[1.0, 0.0]], 0.1)
