"""Plane geometry: polygon crossings and point location against brute force."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay

from plush_opt.base.geometry import (barycentric, diameter, find_crossing, locate_in_triangles,
                                ring_area, segments_touch)


def _brute_force_crossing(rings):
    segs = [(r, i, len(ring), ring[i], ring[(i + 1) % len(ring)])
            for r, ring in enumerate(rings) for i in range(len(ring))]
    for x, (ra, ia, na, a, b) in enumerate(segs):
        for rb, ib, _, c, d in segs[x + 1:]:
            if ra == rb and abs(ia - ib) in (1, na - 1):
                continue
            boxes = (min(a[0], b[0]) <= max(c[0], d[0]) and min(c[0], d[0]) <= max(a[0], b[0])
                     and min(a[1], b[1]) <= max(c[1], d[1]) and min(c[1], d[1]) <= max(a[1], b[1]))
            if boxes and segments_touch(a[None], b[None], c[None], d[None])[0]:
                return True
    return False


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(st.tuples(st.integers(0, 5), st.integers(0, 5)), min_size=3, max_size=7),
                min_size=1, max_size=3),
       st.integers(1, 64))
def test_crossing_sweep_agrees_with_brute_force(rings, chunk):
    rings = [np.array(r, dtype=float) for r in rings]
    assert (find_crossing(rings, chunk=chunk) is not None) == _brute_force_crossing(rings)


def test_diameter_and_ring_area():
    square = np.array([[0, 0], [2, 0], [2, 1], [0, 1]], dtype=float)
    assert diameter(square) == pytest.approx(np.hypot(2, 1))
    assert diameter(np.array([[0, 0], [1, 1], [3, 3]], dtype=float)) == pytest.approx(3 * np.sqrt(2))
    assert diameter(square[:1]) == 0.0
    assert ring_area(square) == 2.0 and ring_area(square[::-1]) == -2.0


def _brute_force_locate(tri_pts, points, tol):
    """Every point against every triangle (the rule locate_in_triangles keeps)."""
    e = np.stack([tri_pts[:, 1] - tri_pts[:, 0], tri_pts[:, 2] - tri_pts[:, 1],
                  tri_pts[:, 0] - tri_pts[:, 2]], axis=1)
    area2 = np.abs(e[:, 0, 0] * e[:, 2, 1] - e[:, 0, 1] * e[:, 2, 0])
    longest = np.sqrt(np.max(np.einsum("ekj,ekj->ek", e, e), axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        wtol = tol * longest / area2 + 1e-12
        bw = barycentric(tri_pts, points)
    depth = np.min(bw, axis=2)
    score = np.where(depth >= -wtol[None], depth, -np.inf)
    k = np.argmax(score, axis=1)
    rows = np.arange(len(k))
    ok = np.isfinite(score[rows, k])
    return np.where(ok, k, -1), np.where(ok[:, None], bw[rows, k], np.nan)


def _queries(rng, nodes, tris):
    """Random points inside and around the mesh, every vertex, points on
    edges, just outside the boundary and far away."""
    lo, hi = nodes.min(axis=0), nodes.max(axis=0)
    span = hi - lo
    inside = lo + rng.random((300, 2)) * span
    around = lo - 0.3 * span + rng.random((200, 2)) * 1.6 * span
    a, b = nodes[tris[:, 0]], nodes[tris[:, 1]]
    t = rng.choice([0.0, 0.25, 0.5, 1.0], size=(len(tris), 1))
    on_edges = a + t * (b - a)
    near_boundary = nodes + 1e-10 * rng.standard_normal(nodes.shape)
    far = np.array([[1e6, 1e6], [-1e6, 3.0], [np.nan, 0.0], [np.inf, 1.0]])
    return np.concatenate([inside, around, nodes, on_edges, near_boundary, far])


def _graded_nodes(rng, n):
    """Points crowded near one corner, so small and large triangles meet."""
    uniform = rng.random((n // 2, 2))
    crowded = rng.random((n - n // 2, 2)) ** 4
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    return np.unique(np.concatenate([corners, uniform, crowded]), axis=0)


@pytest.mark.parametrize("seed", [0, *(pytest.param(s, marks=pytest.mark.slow) for s in range(1, 4))])
@pytest.mark.parametrize("tol", [0.0, 1e-9, 1e-3, 0.2])
@pytest.mark.parametrize("grid", [False, True])
def test_located_like_brute_force_on_a_random_mesh(seed, tol, grid):
    rng = np.random.default_rng(seed)
    if grid:      # many points exactly on shared edges and vertices
        g = np.arange(7, dtype=float)
        nodes = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    else:
        nodes = _graded_nodes(rng, 400)
    tris = Delaunay(nodes).simplices
    tri_pts = nodes[tris]
    points = _queries(rng, nodes, tris)
    tol = tol * diameter(nodes)
    want_tri, want_beta = _brute_force_locate(tri_pts, points, tol)
    for chunk in (1 << 18, 2000):
        tri, beta = locate_in_triangles(tri_pts, points, tol, chunk=chunk)
        np.testing.assert_array_equal(tri, want_tri)
        np.testing.assert_array_equal(beta, want_beta)       # to the last bit
    assert (want_tri >= 0).sum() > len(nodes) and (want_tri < 0).sum() >= 4   # nan, inf, far


def test_located_like_brute_force_in_overlapping_and_flat_triangles():
    rng = np.random.default_rng(11)
    tri_pts = rng.random((300, 3, 2))
    tri_pts[::7] *= 0.01                                    # small ones among large ones
    tri_pts[5, 2] = tri_pts[5, 0]                           # zero area
    tri_pts[9] = [[0, 0], [1, 1], [2, 2]]                   # collinear
    points = np.concatenate([rng.random((500, 2)) * 1.2 - 0.1, tri_pts.reshape(-1, 2)])
    for tol in (0.0, 1e-6, 0.05):
        want = _brute_force_locate(tri_pts, points, tol)
        got = locate_in_triangles(tri_pts, points, tol)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])


def test_locate_with_nothing_to_locate():
    tri_pts = np.array([[[0, 0], [1, 0], [0, 1]]], dtype=float)
    tri, beta = locate_in_triangles(tri_pts, np.zeros((0, 2)))
    assert tri.shape == (0,) and beta.shape == (0, 3)
    tri, beta = locate_in_triangles(np.zeros((0, 3, 2)), [[0.2, 0.2]])
    assert tri.tolist() == [-1] and np.isnan(beta).all()
    tri, beta = locate_in_triangles(tri_pts, [[0.25, 0.25], [1, 1]])
    assert tri.tolist() == [0, -1] and beta[0].tolist() == [0.5, 0.25, 0.25]
