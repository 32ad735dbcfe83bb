"""Attachment rings: the boundary of each finite tendon attachment as mesh edges.

A via point with attachment radius r > 0 pulls on the disc of radius r
around it (problem-format.md, "Finite tendon attachments"). With elements
as large as the disc, the disc load is under-resolved and mesh refinement
stays in its point-load-like (log-divergent) regime until h << r. So the
mesher gets, for each such via point, a ring of segments (a regular
polygon inscribed in the circle, its vertices on the circle) and a region
inside it with its own area bound: the load's edge lies on element edges
and the disc has several elements across at the file's resolution.

The region bound is ``rho * max_area`` with rho fixed by the file's
``max_area`` (not the level's), so the rings refine together with the rest
of the mesh and a max_area sweep stays one consistent refinement sequence.

A ring is made only where it cannot cut anything: the whole disc plus a
margin lies inside the body (away from the outline and the holes), no other
forced point (pin, via point of another centre, ``points`` entry) lies in
that disc plus margin, the disc plus margin misses the pin box, and it
overlaps no other ring's disc plus margin. A via point failing one of these
keeps a plain node (its load is still the exact disc integral); two discs
that overlap both lose their ring, so the result does not depend on order.
"""

from __future__ import annotations

import math

import numpy as np

from .geometry import distance_to_segments

# The disc's element area at the file's resolution, as a fraction of r^2:
# an equilateral triangle of this area has sides r, i.e. two elements across
# the disc's diameter (an 8-sided ring). Not finer: every node inside a disc
# is coupled to every other node of its tendon's discs through the tendon's
# tension (a dense block in the Hessian), so the disc's node count costs
# quadratically in the factorisation (four across made it 20x slower).
DISC_AREA_FRACTION = math.sqrt(3.0) / 4.0
MIN_SIDES = 8              # fewest sides of a ring: a coarser polygon is not a disc
# Clearance (fraction of r) kept between a ring and the outline, a hole, a
# forced point or another ring: no slivers squeezed between them.
RING_MARGIN = 0.25
# Side of an equilateral triangle of area A is sqrt(4 A / sqrt(3)).
_SIDE_PER_SQRT_AREA = math.sqrt(4.0 / math.sqrt(3.0))


def disc_area_bound(r: float, max_area: float | None, file_max_area: float | None) -> float:
    """Largest element area inside a ring of radius r at this level.

    ``DISC_AREA_FRACTION * r^2`` at the file's resolution, scaled with the
    level's ``max_area`` relative to the file's; never above ``max_area``."""
    local = DISC_AREA_FRACTION * r * r
    if max_area is None:
        return local
    if file_max_area is None:
        return min(max_area, local)
    return max_area * min(1.0, local / file_max_area)


def ring_sides(r: float, area: float) -> int:
    """Sides of the ring: none longer than the disc's element size, at least MIN_SIDES."""
    side = _SIDE_PER_SQRT_AREA * math.sqrt(area)
    return max(MIN_SIDES, math.ceil(2.0 * math.pi * r / side))


def _centre_radii(scene, forced, rep):
    """{unique forced index: r} for via points with r > 0 (one radius per centre)."""
    n_pin = len(scene.pin_points)
    radius_of = {}
    pos = n_pin
    for tendon in scene.tendons:
        for j in range(len(tendon.path)):
            u = int(rep[pos + j])
            radius_of.setdefault(u, set()).add(float(tendon.attachment_radius))
        pos += len(tendon.path)
    # concentric discs of different radii (two tendons through one point) get no ring
    return {u: rs.pop() for u, rs in radius_of.items() if len(rs) == 1 and max(rs) > 0}


def _clear_of_box(c, reach, box) -> bool:
    if box is None:
        return True
    x0, y0, x1, y1 = box
    dx = max(x0 - c[0], 0.0, c[0] - x1)
    dy = max(y0 - c[1], 0.0, c[1] - y1)
    return math.hypot(dx, dy) >= reach


def attachment_rings(scene, forced, rep, boundary_a, boundary_b, max_area):
    """Rings for the via points of tendons with r > 0.

    Parameters
    ----------
    scene : Scene with an outline.
    forced : (m, 2) forced points (mesh._forced_points order); rep : (m,)
        index of the point each merges into.
    boundary_a, boundary_b : (s, 2) ends of the outline's and holes' segments.
    max_area : float or None, this level's max_area.

    Returns
    -------
    list of (centre index u, polygon (n, 2), region area bound), in the
    order of the forced points.
    """
    radii = _centre_radii(scene, forced, rep)
    if not radii:
        return []
    uniq = np.flatnonzero(rep == np.arange(len(forced)))
    cand = {}
    for u, r in sorted(radii.items()):
        c = forced[u]
        reach = (1.0 + RING_MARGIN) * r
        dist, _, _ = distance_to_segments(c[None, :], boundary_a, boundary_b)
        others = uniq[uniq != u]
        near = np.hypot(*(forced[others] - c).T) if others.size else np.array([np.inf])
        if (dist[0] >= reach and near.min(initial=np.inf) >= reach
                and _clear_of_box(c, reach, scene.pin_box)):
            cand[u] = r
    # discs (with margin) that overlap one another: neither gets a ring
    keep = dict(cand)
    for u, r in cand.items():
        for v, s in cand.items():
            if u < v and np.hypot(*(forced[u] - forced[v])) < (1.0 + RING_MARGIN) * (r + s):
                keep.pop(u, None)
                keep.pop(v, None)
    rings = []
    for u, r in sorted(keep.items()):
        area = disc_area_bound(r, max_area, scene.max_area)
        n = ring_sides(r, area)
        ang = 2.0 * math.pi * np.arange(n) / n
        poly = forced[u] + r * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        rings.append((u, poly, area))
    return rings


def region_seed(centre: np.ndarray, r: float, n: int) -> np.ndarray:
    """A point inside the ring that is no input vertex: half way out, between two ring vertices."""
    a = math.pi / n
    return centre + 0.5 * r * np.array([math.cos(a), math.sin(a)])
