"""The body's geometry as a problem file gives it: its outline and holes
(simple rings, apart, holes inside the outline) and an explicit mesh
(nodes, triangles, P2 midside nodes), checked before any meshing. Used by
:mod:`.problem_file` and by result files read back (their recorded mesh).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..base.errors import format_number, format_point
from ..base.geometry import classify_points, diameter, find_crossing, ring_area
from .checker import MAX_COORD, Checker, at_index, at_key, describe
from .scene import ELEMENTS, NODES_PER_TRIANGLE, POINT_TOL

MAX_MIN_ANGLE = 34.0              # Triangle may not terminate above about 34 degrees
#: a polygon whose area is below this fraction of its bounding box's squared size is flat
ZERO_AREA = 1e-12
#: a triangle whose cross product is below this fraction of its longest squared edge is flat
FLAT_TRIANGLE = 1e-12

MESH_KEYS = ("outline", "holes", "max_area", "min_angle", "nodes", "triangles", "element")


def mesh_section(ck: Checker, mesh) -> dict:
    ck.mapping(mesh, "mesh", MESH_KEYS)
    has = {k for k in MESH_KEYS if mesh.get(k) is not None}
    out = dict(outline=None, holes=[], max_area=None, min_angle=None, nodes=None,
               triangles=None, element="P1")
    if "element" in has:
        element = ck.string(mesh["element"], "mesh.element")
        if element not in ELEMENTS:
            ck.fail("mesh.element", f"must be one of {', '.join(ELEMENTS)}, got {element!r}")
        out["element"] = element
    if "outline" in has:
        for k in ("nodes", "triangles"):
            if k in has:
                ck.fail(at_key("mesh", k), "give either mesh.outline or mesh.nodes + "
                        "mesh.triangles, not both")
        outline = ck.points(mesh["outline"], "mesh.outline", min_len=3)
        check_ring(ck, outline, "mesh.outline")
        holes = []
        if "holes" in has:
            for i, h in enumerate(ck.seq(mesh["holes"], "mesh.holes", what="list of polygons")):
                hp = at_index("mesh.holes", i)
                hole = ck.points(h, hp, min_len=3)
                check_ring(ck, hole, hp)
                holes.append(hole)
        out.update(outline=outline, holes=holes, diameter=diameter(outline))
        _check_ring_vertices_apart(ck, outline, holes, POINT_TOL * out["diameter"])
        _check_ring_layout(ck, outline, holes, POINT_TOL * out["diameter"])
        if "max_area" in has:
            out["max_area"] = ck.number(mesh["max_area"], "mesh.max_area", gt=0)
        if "min_angle" in has:
            a = ck.number(mesh["min_angle"], "mesh.min_angle", ge=0)
            if a > MAX_MIN_ANGLE:
                ck.fail("mesh.min_angle", f"must be <= {MAX_MIN_ANGLE:g} degrees (the mesher "
                        f"may not terminate above), got {format_number(a)}")
            out["min_angle"] = a
        return out
    if "nodes" not in has and "triangles" not in has:
        ck.fail("mesh", "give mesh.outline, or mesh.nodes and mesh.triangles")
    for k in ("nodes", "triangles"):
        if k not in has:
            other = "triangles" if k == "nodes" else "nodes"
            ck.fail(at_key("mesh", k), f"required with mesh.{other}")
    for k in ("holes", "max_area", "min_angle"):
        if k in has:
            ck.fail(at_key("mesh", k), "only allowed with mesh.outline")
    nodes = ck.points(mesh["nodes"], "mesh.nodes", min_len=3)
    raw = ck.seq(mesh["triangles"], "mesh.triangles", min_len=1, what="list of triangles")
    width = NODES_PER_TRIANGLE[out["element"]]
    tris = np.empty((len(raw), width), dtype=np.int64)
    n_nodes = len(nodes)
    for e, t in enumerate(raw):
        p = at_index("mesh.triangles", e)
        if isinstance(t, np.ndarray):
            t = list(t)
        if not isinstance(t, (list, tuple)) or len(t) != width:
            ck.fail(p, f"expected six node indices [a, b, c, ab, bc, ca] (mesh.element is P2), "
                    f"got {describe(t)}" if width == 6 else
                    f"expected three node indices [i, j, k], got {describe(t)}")
        for c, v in enumerate(t):
            iv = ck.integer(v, at_index(p, c))
            if not 0 <= iv < n_nodes:
                ck.fail(at_index(p, c), f"node index {iv} out of range 0..{n_nodes - 1} "
                        f"(mesh.nodes has {n_nodes} nodes)")
            tris[e, c] = iv
    _check_explicit_mesh(ck, nodes, tris)
    if width == 6:
        _check_midside_nodes(ck, nodes, tris)
    out.update(nodes=nodes, triangles=tris, diameter=diameter(nodes))
    return out


def explicit_mesh(ck: Checker, element, nodes, triangles) -> tuple[np.ndarray, np.ndarray]:
    """``element``, ``nodes`` and ``triangles`` checked as a problem file's
    explicit mesh (``ck`` names the keys): (nodes (n, 2), triangles (m, 3 or 6))."""
    geo = mesh_section(ck, {"element": element, "nodes": nodes, "triangles": triangles})
    return geo["nodes"], geo["triangles"]


def _check_explicit_mesh(ck: Checker, nodes: np.ndarray, tris: np.ndarray):
    p = nodes[tris]
    d1, d2, d3 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 2] - p[:, 1]
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    longest = np.max([np.einsum("ij,ij->i", d, d) for d in (d1, d2, d3)], axis=0)
    degenerate = np.abs(cross) <= FLAT_TRIANGLE * longest
    degenerate |= (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
    if degenerate.any():
        e = int(np.flatnonzero(degenerate)[0])
        ck.fail(at_index("mesh.triangles", e), f"degenerate triangle {tris[e].tolist()} "
                "(zero area)")
    key = np.sort(tris, axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    dup = np.flatnonzero(first[inverse] != np.arange(len(tris)))
    if dup.size:
        e = int(dup[0])
        ck.fail(at_index("mesh.triangles", e), f"duplicate of mesh.triangles[{int(first[inverse[e]])}]")
    used = np.zeros(len(nodes), dtype=bool)
    used[tris.reshape(-1)] = True
    if not used.all():
        i = int(np.flatnonzero(~used)[0])
        ck.fail(at_index("mesh.nodes", i), "node is not used by any triangle")
    tol = POINT_TOL * diameter(nodes)
    pairs = cKDTree(nodes).query_pairs(tol, output_type="ndarray")
    if len(pairs):
        i, j = sorted(map(int, pairs[np.lexsort((pairs[:, 0], pairs[:, 1]))][0]))
        ck.fail(at_index("mesh.nodes", j), f"coincides with mesh.nodes[{i}]")


def _check_midside_nodes(ck: Checker, nodes: np.ndarray, tris: np.ndarray):
    """P2 geometry is straight-sided: each midside node sits at its edge's midpoint."""
    tol = POINT_TOL * diameter(nodes)
    for k, (a, b) in enumerate(((0, 1), (1, 2), (2, 0))):
        gap = np.linalg.norm(nodes[tris[:, 3 + k]] - 0.5 * (nodes[tris[:, a]] + nodes[tris[:, b]]),
                             axis=1)
        bad = np.flatnonzero(gap > tol)
        if bad.size:
            e = int(bad[0])
            ck.fail(at_index(at_index("mesh.triangles", e), 3 + k),
                    f"midside node {int(tris[e, 3 + k])} is not at the midpoint of its edge "
                    f"(off by {gap[e]:.3g}); P2 triangles are straight-sided")


def check_points_are_nodes(ck: Checker, nodes, forced, tol):
    tree = cKDTree(nodes)
    for key, pts in forced:
        if len(pts) == 0:
            continue
        dist, near = tree.query(pts)
        bad = np.flatnonzero(dist > tol)
        if bad.size:
            j = int(bad[0])
            ck.fail(at_index(key, j), f"point {format_point(pts[j])} is not a node of the explicit "
                    f"mesh (nearest is mesh.nodes[{int(near[j])}] at distance {dist[j]:.3g})")


def check_ring(ck: Checker, ring: np.ndarray, path: str):
    """A simple polygon: no repeated consecutive points, no backtracking,
    no crossings or touchings, nonzero area."""
    nxt = np.roll(ring, -1, axis=0)
    same = np.all(ring == nxt, axis=1)
    if same.any():
        i = int(np.flatnonzero(same)[0])
        j = (i + 1) % len(ring)
        if j == 0:
            ck.fail(at_index(path, len(ring) - 1), "repeats the first point; do not close the "
                    "polygon, it is closed implicitly")
        ck.fail(at_index(path, j), f"point {format_point(ring[j])} repeats the previous point")
    d = nxt - ring
    d_next = np.roll(d, -1, axis=0)
    cross = d[:, 0] * d_next[:, 1] - d[:, 1] * d_next[:, 0]
    dot = np.einsum("ij,ij->i", d, d_next)
    back = (cross == 0) & (dot < 0)
    if back.any():
        i = (int(np.flatnonzero(back)[0]) + 1) % len(ring)
        ck.fail(at_index(path, i), f"the polygon turns back on itself at {format_point(ring[i])}")
    hit = find_crossing([ring])
    if hit is not None:
        (_, a), (_, b) = hit
        ck.fail(path, f"not a simple polygon: edge {a} (from point {a}) crosses or touches "
                f"edge {b} (from point {b})")
    # about its own first vertex: far from the origin, the shoelace sum of
    # absolute coordinates loses the area to round-off
    local = ring - ring[0]
    area = abs(ring_area(local))
    if not area > ZERO_AREA * float(np.sum(np.ptp(local, axis=0) ** 2)):
        ck.fail(path, "polygon has zero area")


def length(ck: Checker, value, path: str) -> float:
    """A finite length at most :data:`MAX_COORD` in magnitude, like a coordinate
    (a bound of 1e300 overflows the tendon energy, whose terms are squared)."""
    x = ck.number(value, path)
    if abs(x) > MAX_COORD:
        ck.fail(path, f"{format_number(x)} is too large (lengths are limited to {MAX_COORD:g} in magnitude)")
    return x


def _check_ring_vertices_apart(ck: Checker, outline: np.ndarray, holes: list, tol: float):
    """Outline and hole vertices farther apart than the point tolerance:
    closer ones would be one node, and meshed apart they make slivers."""
    rings = [("mesh.outline", outline)] + [(at_index("mesh.holes", i), h) for i, h in enumerate(holes)]
    keys = [at_index(key, j) for key, ring in rings for j in range(len(ring))]
    pts = np.concatenate([ring for _, ring in rings])
    pairs = sorted(tuple(sorted(p)) for p in cKDTree(pts).query_pairs(tol))
    if pairs:
        i, j = pairs[0]
        ck.fail(keys[j], f"point {format_point(pts[j])} is within {tol:.3g} (1e-9 x body diameter) of "
                f"{keys[i]} {format_point(pts[i])}: the same node; vertices must be distinct")


def _check_ring_layout(ck: Checker, outline: np.ndarray, holes: list, tol: float):
    """Holes strictly inside the outline and disjoint from each other."""
    if not holes:
        return
    rings = [outline, *holes]
    hit = find_crossing(rings)
    if hit is not None:
        (ra, _), (rb, _) = sorted(hit)
        other = "the outline" if ra == 0 else f"mesh.holes[{ra - 1}]"
        ck.fail(at_index("mesh.holes", rb - 1), f"crosses or touches {other}")
    # no edges cross, so one vertex tells where a whole hole lies
    first = np.array([h[0] for h in holes])
    where = classify_points(first, [outline], tol)
    for i in range(len(holes)):
        if where[i] == 0:
            ck.fail(at_index("mesh.holes", i), "touches the outline (holes must be strictly inside)")
        if where[i] < 0:
            ck.fail(at_index("mesh.holes", i), "lies outside the outline (holes must be strictly "
                    "inside)")
    # hole i in (or touching) hole j needs its first vertex in j's box
    lo = np.array([h.min(axis=0) for h in holes]) - tol
    hi = np.array([h.max(axis=0) for h in holes]) + tol
    order = np.argsort(lo[:, 0], kind="stable")
    for i in range(len(holes)):
        p = first[i]
        cand = order[:np.searchsorted(lo[order, 0], p[0], side="right")]
        cand = cand[(cand != i) & (hi[cand, 0] >= p[0]) & (lo[cand, 1] <= p[1])
                    & (hi[cand, 1] >= p[1])]
        for j in np.sort(cand):
            w = classify_points(p[None], [holes[j]], tol)[0]
            if w >= 0:
                what = "touches" if w == 0 else "lies inside"
                ck.fail(at_index("mesh.holes", i), f"{what} mesh.holes[{int(j)}]")
