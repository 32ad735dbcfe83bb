"""Meshes graded towards the points where the displacement is singular.

Near a reentrant corner of the body (interior angle above 180 degrees) and
at the end of a pinned stretch of boundary, the elastic displacement field
behaves like d^lambda in the distance d from the point (lambda about 0.54
at a 270 degree corner, about 0.7 where a clamped edge meets a free one at
90 degrees). On a uniform mesh that singularity sets the convergence of
every point of the body, at about h^(2 lambda), whatever the element's
degree, and neighbouring levels can agree long before they are right:
exactly what fools an error estimate. A corner rounded as a polyline has
every vertex reentrant by a few degrees (a mild singularity): each is
graded within half a chord, which costs little.

The second thing a uniform mesh resolves late is a finite tendon attachment
(a disc of radius r, plush_opt.fem.attachments): while the elements are
larger than r the disc's pull is spread over them like a point load's, and
the levels converge slowly and unevenly. docs/model.md ("Graded meshes")
records what both cost on the shipped problems.

A graded mesh (Babuska's remedy) makes its local element size h g(d) with

    g(d) = min(1, max(G_MIN, (d / R) ** gamma)),   gamma = 1 - lambda / p,

for elements of degree p (lambda = 1/2, on the safe side: gamma = 3/4 for
P2, 1/2 for P1), R a quarter of the body's size (at most half the
distance to the next singular point) and d the distance to the nearest
singular point. The accuracy sweep grades the first mesh of each nested
family and refines it uniformly, which keeps the grading relative to h.
The floor G_MIN keeps the elements at a singular point a fixed fraction of
h rather than letting them shrink without bound. Within one local element
of each attachment disc's rim the size is h / 4 (DISC_FACTOR), fixed the
same way.

The mesh is made by Triangle as usual and then refined ('r') with a
per-triangle area bound max_area * g^2 at the triangle's centroid, a few
times (the bound of a split triangle is its parent's, so each pass moves
the sizes nearer to g). At the centroid, the triangle at a singular point
stops shrinking once its own size sets the distance, at s ~ h^4 / (2R)^3:
far above the floor when h exceeds R, as on the coarse first mesh of a
nested family. A pinned end is therefore graded at the vertex: a triangle
touching it is bounded by g there, G_MIN (the triangles around it keep the
centroid: at their nearest vertex a wide zone would be graded finer than
g). A pinned end carries the reaction of the whole load (gravity and the
tendons pull against the root), and on a cantilevered body its singular
term sets the rate of every point. An attachment disc beside a pinned end
then fills with the small elements; its Hessian term has a stand-in there
(plush_opt.fem.hessian_layout), not a dense block. Reentrant corners keep
the centroid, which reaches the floor once h < R: graded at the vertex
they would cost several times the first mesh's nodes, and the estimates
hold without it. Only meshes the accuracy sweep chooses are graded; a
problem file's own mesh is what its max_area says.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
import triangle as _triangle

from ..base.geometry import body_area, ring_area, triangle_areas
from .elements import ELEMENTS
from ..io.scene import Scene

#: Smallest local size, as a fraction of the level's h.
G_MIN = 1.0 / 16
#: Grading radius, as a fraction of the body's size sqrt(area).
RADIUS = 0.25
#: The singular exponent lambda the grading assumes (the safe side of 0.54-0.7).
SINGULAR_EXPONENT = 0.5
#: Grading exponent per element (by its file name): gamma = 1 - lambda / p.
GAMMA = {e.name: 1 - SINGULAR_EXPONENT / e.degree for e in ELEMENTS}
#: Local size at a finite tendon attachment, as a fraction of h (within one
#: such element of the disc's rim).
DISC_FACTOR = 1.0 / 4
#: Refinement passes; a pass that leaves no triangle above its bound stops early.
PASSES = 6
#: A corner counts as reentrant above 180 degrees by this much (radians).
ANGLE_TOL = 1e-6
#: A triangle at most this fraction above its area bound meets it (the
#: round-off of Triangle's splits would otherwise ask for one more pass).
AREA_SLACK = 1e-9
#: A boundary segment whose extent along an axis is below this (length
#: units) runs parallel to that axis when clipped to the pin box.
PARALLEL_TOL = 1e-15


def _reentrant(ring: np.ndarray, body_left: bool) -> list[np.ndarray]:
    """Vertices of a closed ring where the body's interior angle exceeds 180
    degrees. ``body_left``: the body lies to the left of the ring as given."""
    out = []
    n = len(ring)
    for k in range(n):
        a, b, c = ring[k - 1], ring[k], ring[(k + 1) % n]
        u, v = b - a, c - b
        turn = np.arctan2(u[0] * v[1] - u[1] * v[0], u @ v)     # left turn > 0
        if (turn < -ANGLE_TOL) if body_left else (turn > ANGLE_TOL):
            out.append(b)
    return out


def _pinned_ends(scene: Scene) -> list[np.ndarray]:
    """Where a pinned stretch of the outline's boundary ends: the ends of
    each boundary segment's part inside the pin box that are not shared
    with the next pinned part."""
    x0, y0, x1, y1 = scene.pin_box
    rings = [scene.outline, *scene.holes]
    pieces = []
    for ring in rings:
        for a, b in zip(ring, np.roll(ring, -1, axis=0)):
            # clip the segment a + t (b - a), t in [0, 1], to the box
            lo, hi = 0.0, 1.0
            for axis, (lo_b, hi_b) in enumerate(((x0, x1), (y0, y1))):
                d = b[axis] - a[axis]
                if abs(d) < PARALLEL_TOL:
                    if not (lo_b - scene.tolerance <= a[axis] <= hi_b + scene.tolerance):
                        lo, hi = 1.0, 0.0
                    continue
                t0, t1 = sorted(((lo_b - a[axis]) / d, (hi_b - a[axis]) / d))
                lo, hi = max(lo, t0), min(hi, t1)
            if hi >= lo and (hi - lo) * np.linalg.norm(b - a) > scene.tolerance:   # not a mere touch
                pieces.append((a + lo * (b - a), a + hi * (b - a)))
    ends = [p for piece in pieces for p in piece]
    tol = scene.tolerance
    # an end shared by two pieces is inside a pinned stretch
    return [p for p in ends if sum(np.linalg.norm(q - p) <= tol for q in ends) == 1]


def singular_points(scene: Scene) -> np.ndarray:
    """Points the mesh is graded towards, (k, 2): reentrant corners of the
    outline and the holes, and the ends of pinned stretches of boundary.
    (A pin at a single point is a point support, singular too, but only
    locally: the field away from it converges at the element's rate.)"""
    if scene.outline is None:
        return np.zeros((0, 2))
    ccw = ring_area(scene.outline) > 0
    pts = _reentrant(np.asarray(scene.outline), body_left=ccw)
    for hole in scene.holes:
        pts += _reentrant(np.asarray(hole), body_left=ring_area(hole) < 0)
    if scene.pin_box is not None:
        pts += _pinned_ends(scene)
    if not pts:
        return np.zeros((0, 2))
    pts = np.array(pts, dtype=np.float64)
    # one copy of each point: the first of those within the tolerance of each other
    keep = np.ones(len(pts), dtype=bool)
    for i, j in cKDTree(pts).query_pairs(scene.tolerance):
        keep[max(i, j)] = False
    return pts[keep]


def grading_radii(singular: np.ndarray, size: float) -> np.ndarray:
    """R per singular point: RADIUS x the body's size, and at most half the
    distance to the nearest other singular point (on a narrow part, such as
    a leg, the corners' zones would otherwise cover the whole body)."""
    radius = np.full(len(singular), RADIUS * size)
    if len(singular) > 1:
        d = np.linalg.norm(singular[:, None, :] - singular[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        radius = np.minimum(radius, 0.5 * d.min(axis=1))
    return radius


def size_factor(points: np.ndarray, singular: np.ndarray, radii: np.ndarray, element: str) -> np.ndarray:
    """g at ``points`` (m, 2): the local element size as a fraction of h."""
    if len(singular) == 0:
        return np.ones(len(points))
    d = np.linalg.norm(points[:, None, :] - singular[None], axis=-1) / radii[None]
    return np.clip(np.min(d, axis=1) ** GAMMA[element], G_MIN, 1.0)


def grade(scene: Scene, X: np.ndarray, tris: np.ndarray, max_area: float, quality: str):
    """Refine the triangulation (X, tris) towards the scene's singular points
    and its tendons' attachment discs.

    ``quality`` is the Triangle switch of the mesh's angle bound ("q28", or
    ""); the input vertices stay first and in order. Returns X, tris."""
    singular = singular_points(scene)
    discs = [(p, t.attachment_radius) for t in scene.tendons if t.attachment_radius > 0 for p in t.path]
    if len(singular) == 0 and not discs:
        return X, tris
    radii = grading_radii(singular, np.sqrt(body_area(scene.outline, scene.holes)))
    ends = np.array(_pinned_ends(scene) if scene.pin_box is not None else np.zeros((0, 2))).reshape(-1, 2)
    h_disc = DISC_FACTOR * np.sqrt(max_area)
    for _ in range(PASSES):
        p = X[tris]
        centroid = p.mean(axis=1)
        g = size_factor(centroid, singular, radii, scene.element)
        for end in ends:
            # a triangle touching a pinned end takes the size there
            touching = np.any(np.linalg.norm(p - end, axis=2) <= scene.tolerance, axis=1)
            g[touching] = G_MIN
        for centre, r in discs:
            near = np.linalg.norm(centroid - centre, axis=1) < r + h_disc
            g[near] = np.minimum(g[near], DISC_FACTOR)
        bound = max_area * g ** 2
        if not np.any(triangle_areas(p) > bound * (1 + AREA_SLACK)):
            break
        edges = np.sort(np.vstack([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
        edges, count = np.unique(edges, axis=0, return_counts=True)
        out = _triangle.triangulate({"vertices": X, "triangles": tris, "segments": edges[count == 1],
                                     "triangle_max_area": bound}, "rpzQ" + quality + "a")
        X, tris = np.asarray(out["vertices"], dtype=np.float64), np.asarray(out["triangles"], dtype=np.int64)
    return X, tris
