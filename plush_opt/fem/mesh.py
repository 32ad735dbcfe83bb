"""Scene -> Mesh: triangulation (the ``triangle`` package), node lookup of
pins, via points and extra points, and point location for targets."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import triangle as _triangle
from scipy.spatial import cKDTree

from ..base.errors import SceneError, format_point
from ..base.reprs import compact_repr
from ..base.geometry import body_area, diameter, distance_to_segments, locate_in_triangles
from .elements import Element, add_midside_nodes, named
from .grading import grade
from ..io.plausibility import large_mesh_note
from ..io.scene import POINT_TOL, Scene

log = logging.getLogger("plush_opt")

DEFAULT_MIN_ANGLE = 20.0     # Triangle's own default for quality meshing, degrees
MAX_ELEMS = 4_000_000        # refuse a mesh larger than this (the model would not fit in memory)
# A quality mesh has more triangles than area / max_area (about 1.5 times at
# 20 degrees). Near the cap, a trial mesh this many times coarser predicts
# the count (it scales with 1/max_area) in a hundredth of the time, so a
# mesh certain to be refused is not made; the real mesh is checked always.
TRIAL_COARSENING = 64.0
TRIAL_FROM = 0.25            # trial only when area / max_area exceeds this fraction of the cap
TRIAL_MARGIN = 1.1           # refuse on the prediction only this far above the cap (it is within a few %)


def _frozen(a, dtype) -> np.ndarray:
    arr = np.ascontiguousarray(np.asarray(a, dtype=dtype))
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh with everything the model needs indexed by node.

    Attributes
    ----------
    X : (n_nodes, 2) float64, rest positions.
    triangles : (n_elems, 3) int64, counter-clockwise in ``X``.
    pin_nodes : (n_pins,) int64, sorted unique nodes pinned at rest position
        (``pins.at`` and every node in ``pins.box``).
    tendon_nodes : tuple of (n_via,) int64 arrays, one per scene tendon, in
        scene order, stopper end first.
    target_triangles : (n_targets,) int64, rest triangle holding each target.
    target_beta : (n_targets, 3) float64, barycentric weights in that
        triangle (order of ``triangles[target_triangles[k]]``), summing to 1.
    point_nodes : (n_points,) int64, node of each scene ``points`` entry.
    element : the element type (:data:`~plush_opt.fem.elements.P1` or
        :data:`~plush_opt.fem.elements.P2`; given as its file name "P1" or
        "P2", it is looked up). ``str(mesh.element)`` is the name.
    elements : (n_elems, 3 or 6) int64, each element's nodes: ``triangles``
        for P1; ``[a, b, c, ab, bc, ca]`` for P2 (corners as in
        ``triangles``, then the midside nodes). Pins, via points, points and
        targets always refer to the corner triangles.
    """

    X: np.ndarray
    triangles: np.ndarray
    pin_nodes: np.ndarray
    tendon_nodes: tuple
    target_triangles: np.ndarray
    target_beta: np.ndarray
    point_nodes: np.ndarray
    element: Element | str = "P1"
    elements: np.ndarray | None = None

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        set_("X", _frozen(np.reshape(self.X, (-1, 2)), np.float64))
        set_("triangles", _frozen(np.reshape(self.triangles, (-1, 3)), np.int64))
        set_("pin_nodes", _frozen(np.reshape(self.pin_nodes, -1), np.int64))
        set_("tendon_nodes", tuple(_frozen(np.reshape(t, -1), np.int64)
                                   for t in self.tendon_nodes))
        set_("target_triangles", _frozen(np.reshape(self.target_triangles, -1), np.int64))
        set_("target_beta", _frozen(np.reshape(self.target_beta, (-1, 3)), np.float64))
        set_("point_nodes", _frozen(np.reshape(self.point_nodes, -1), np.int64))
        if isinstance(self.element, str):
            set_("element", named(self.element))
        set_("elements", self.triangles if self.elements is None
             else _frozen(np.reshape(self.elements, (-1, self.element.nodes)), np.int64))

    @property
    def n_nodes(self) -> int:
        return self.X.shape[0]

    @property
    def n_elems(self) -> int:
        return self.triangles.shape[0]

    @property
    def diameter(self) -> float:
        """Largest distance between two nodes (length units)."""
        return diameter(self.X)

    @property
    def areas(self) -> np.ndarray:
        """Rest area of each triangle, (n_elems,) float64, all positive."""
        p = self.X[self.triangles]
        d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])

    def locate(self, points, tol: float | None = None):
        """Rest triangle holding each point and its barycentric weights.

        Parameters
        ----------
        points : (m, 2) array_like, rest coordinates.
        tol : float, optional
            Distance (length units) within which a point just outside the
            mesh still counts as on it; default 1e-9 x diameter.

        Returns
        -------
        tri : (m,) int64, triangle index, -1 for points outside the mesh.
        beta : (m, 3) float64, weights in the order of ``triangles[tri]``
            (NaN rows for points outside); ``beta @ X[triangles[tri]]`` is the point.
        """
        if tol is None:
            tol = POINT_TOL * self.diameter
        return locate_in_triangles(self.X[self.triangles], points, tol)

    __repr__ = compact_repr      # a mesh prints by its arrays' shapes

    def __eq__(self, other):
        if not isinstance(other, Mesh):
            return NotImplemented
        return (all(np.array_equal(getattr(self, k), getattr(other, k))
                    for k in ("X", "triangles", "elements", "pin_nodes", "target_triangles",
                              "target_beta", "point_nodes"))
                and self.element is other.element
                and len(self.tendon_nodes) == len(other.tendon_nodes)
                and all(np.array_equal(a, b) for a, b in zip(self.tendon_nodes,
                                                             other.tendon_nodes)))

    __hash__ = None


def _forced_points(scene: Scene):
    """All points that must become nodes, in a fixed order, with their key paths."""
    chunks = [(f"pins.at[{i}]", p) for i, p in enumerate(scene.pin_points)]
    for t, tendon in enumerate(scene.tendons):
        chunks += [(f"tendons.list[{t}].path[{j}]", p) for j, p in enumerate(tendon.path)]
    chunks += [(f"points[{i}]", p) for i, p in enumerate(scene.points)]
    keys = [k for k, _ in chunks]
    pts = np.array([p for _, p in chunks], dtype=np.float64).reshape(-1, 2)
    return keys, pts


def _num(x: float) -> str:
    """A number as Triangle's switch parser reads it (no exponent)."""
    return np.format_float_positional(float(x), trim="-")


def _hole_seed(hole: np.ndarray) -> np.ndarray:
    """A point strictly inside a simple polygon: centroid of its largest triangle."""
    n = len(hole)
    seg = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
    t = _triangle.triangulate({"vertices": np.array(hole), "segments": seg}, "pzQ")
    p = t["vertices"][t["triangles"]]
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    return p[int(np.argmax(area))].mean(axis=0)


def _merge_close(pts: np.ndarray, tol: float) -> np.ndarray:
    """rep[j]: index of the earlier point ``j`` merges into (itself if none)."""
    rep = np.arange(len(pts))
    if len(pts) < 2:
        return rep
    pairs = cKDTree(pts).query_pairs(tol, output_type="ndarray")     # distance <= tol
    if len(pairs):
        gap = np.hypot(*(pts[pairs[:, 0]] - pts[pairs[:, 1]]).T)
        pairs = pairs[gap < tol]                                       # closer than tol
    for i, j in sorted((min(p), max(p)) for p in pairs.tolist()):
        if rep[j] == j and rep[i] == i:
            rep[j] = i
    return rep


def _mesh_outline(scene: Scene, max_area, tol, graded: bool = False):
    """Triangulate the outline (graded towards its singular points if asked:
    plush_opt.fem.grading); returns X, triangles and the node of every forced point."""
    rings = [scene.outline, *scene.holes]
    ring_pts = np.concatenate(rings)
    n_ring = len(ring_pts)
    offsets = np.cumsum([0] + [len(r) for r in rings])
    seg_a = np.concatenate([np.arange(len(r)) + o for r, o in zip(rings, offsets)])
    seg_b = np.concatenate([(np.arange(len(r)) + 1) % len(r) + o for r, o in zip(rings, offsets)])

    keys, forced = _forced_points(scene)
    rep = _merge_close(forced, tol)
    node_of = np.full(len(forced), -1, dtype=np.int64)

    extra = []                                # new input vertices (beyond the rings)
    on_segment = {}                           # ring segment -> [(t, vertex)]
    uniq = np.flatnonzero(rep == np.arange(len(forced)))
    if uniq.size:
        dist_v, near_v = cKDTree(ring_pts).query(forced[uniq])
        dist_s, seg, par = distance_to_segments(forced[uniq], ring_pts[seg_a], ring_pts[seg_b])
        for u, dv, nv, ds, s, t in zip(uniq, dist_v, near_v, dist_s, seg, par):
            if dv < tol:
                node_of[u] = nv
                continue
            node_of[u] = n_ring + len(extra)
            extra.append(forced[u])
            if ds <= tol:
                on_segment.setdefault(int(s), []).append((float(t), int(node_of[u])))
    node_of = node_of[rep]

    segments = []
    for s, (a, b) in enumerate(zip(seg_a, seg_b)):
        chain = [int(a)] + [v for _, v in sorted(on_segment.get(s, []))] + [int(b)]
        segments += list(zip(chain[:-1], chain[1:]))
    vertices = np.vstack([ring_pts, np.array(extra).reshape(-1, 2)])

    min_angle = DEFAULT_MIN_ANGLE if scene.min_angle is None else scene.min_angle
    quality = "q" + _num(min_angle) if min_angle > 0 else ""
    opts = "pzQ" + quality
    if max_area is not None:
        opts += "a" + _num(max_area)
    pslg = {"vertices": vertices, "segments": np.array(segments, dtype=np.int32)}
    if scene.holes:
        pslg["holes"] = np.array([_hole_seed(h) for h in scene.holes])
    out = _triangle.triangulate(pslg, opts)
    X = np.asarray(out["vertices"], dtype=np.float64)
    tris = np.asarray(out["triangles"], dtype=np.int64)
    if graded:
        X, tris = grade(scene, X, tris, max_area, quality)
    # Triangle keeps input vertices first and in order; check rather than trust.
    if not (len(X) >= len(vertices) and np.array_equal(X[:len(vertices)], vertices)):
        dist, near = cKDTree(X).query(vertices)
        if np.max(dist[node_of], initial=0.0) > tol:
            raise SceneError(f"{scene.source}: mesh: the mesher lost a forced point")
        node_of = near[node_of]
    return X, tris, node_of, keys


def _refuse_large(scene: Scene, max_area: float, tol: float) -> None:
    """Refuse up front a mesh certain to exceed :data:`MAX_ELEMS`: by area
    alone (each triangle is at most ``max_area``), or by a coarser trial mesh."""
    src = scene.source
    body = body_area(scene.outline, scene.holes)
    if body / max_area > MAX_ELEMS:
        raise SceneError(f"{src}: mesh.max_area: {max_area:g} would give more than "
                         f"{body / max_area:.3g} triangles (limit {MAX_ELEMS}); use a larger max_area")
    if body / max_area > TRIAL_FROM * MAX_ELEMS:
        _, trial, _, _ = _mesh_outline(scene, max_area * TRIAL_COARSENING, tol)
        predicted = len(trial) * TRIAL_COARSENING
        if predicted > TRIAL_MARGIN * MAX_ELEMS:
            raise SceneError(f"{src}: mesh.max_area: {max_area:g} would give about {predicted:.3g} "
                             f"triangles (limit {MAX_ELEMS}); use a larger max_area")


def refine_uniformly(X: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle into four at its edge midpoints (red refinement).

    The nodes of ``X`` keep their numbers (new ones follow), so forced
    points stay the nodes they were; each child is oriented as its parent.
    A sequence of such meshes is nested: the error of a point's prediction
    shrinks by the element's rate per level, without the scatter of meshes
    made independently (docs/accuracy.md)."""
    X, six = add_midside_nodes(X, tris)
    a, b, c, ab, bc, ca = six.T
    children = np.stack([np.stack(t, axis=1) for t in
                         ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))], axis=1)
    return X, children.reshape(-1, 3)


def build_mesh(scene: Scene, max_area: float | None = None, graded: bool = False,
               refinements: int = 0, announce: bool = True) -> Mesh:
    """Mesh a scene.

    Parameters
    ----------
    scene : Scene
    max_area : float, optional
        Largest triangle area (length units squared); overrides
        ``scene.max_area`` (mesh-resolution sweeps). Ignored for explicit meshes.
    graded : bool
        Refine towards reentrant corners and the ends of pinned boundary
        (plush_opt.fem.grading), with ``max_area`` the bound far from them
        (the accuracy sweep's levels). Needs ``max_area``; ignored for
        explicit meshes.
    refinements : int
        Split every triangle into four this many times after meshing
        (:func:`refine_uniformly`): the accuracy sweep's nested levels.
        Outline scenes only.
    announce : bool
        Log a line for a mesh estimated above the large-mesh size
        (io/plausibility.py); False for a trial mesh a search discards.

    Returns
    -------
    Mesh
        Deterministic: the same scene and ``max_area`` give the same mesh.

    Raises
    ------
    SceneError
        A pin box that catches no node, a forced point of an explicit mesh
        that is not a node, a target outside the mesh, or a mesh that would
        be unreasonably large.
    """
    src = scene.source
    tol = scene.tolerance
    if isinstance(refinements, bool) or not (isinstance(refinements, (int, np.integer))
                                             and 0 <= refinements <= 8):
        raise SceneError(f"{src}: mesh: refinements must be an integer 0..8, got {refinements!r}")
    if refinements and scene.outline is None:
        raise SceneError(f"{src}: mesh: an explicit mesh cannot be refined")
    if scene.outline is not None:
        if max_area is None:
            max_area = scene.max_area
        elif not (isinstance(max_area, (int, float)) and math.isfinite(max_area) and max_area > 0):
            raise SceneError(f"{src}: max_area: must be a finite number > 0, got {max_area!r}")
        if max_area is not None:
            _refuse_large(scene, max_area / 4.0 ** refinements, tol)
            note = large_mesh_note(scene, max_area, refinements) if announce else None
            if note is not None:                  # minutes of work ahead: say what is being built
                log.warning("%s: %s", src, note)
        if graded and max_area is None:
            raise SceneError(f"{src}: mesh: a graded mesh needs max_area")
        X, tris, node_of, keys = _mesh_outline(scene, max_area, tol, graded)
        n_tris = len(tris) * 4 ** refinements      # known before refining: refuse before allocating
        if n_tris > MAX_ELEMS:
            refined = f" refined {refinements} times" if refinements else ""
            area = "the mesher's default" if max_area is None else f"{max_area:g}"
            raise SceneError(f"{src}: mesh.max_area: {area}{refined} gives {n_tris} triangles "
                             f"(limit {MAX_ELEMS}); use a larger max_area")
        for _ in range(refinements):
            X, tris = refine_uniformly(X, tris)
    else:
        X, tris = scene.nodes, scene.triangles
        keys, forced = _forced_points(scene)
        node_of = np.zeros(len(forced), dtype=np.int64)
        if len(forced):
            dist, node_of = cKDTree(X).query(forced)
            bad = np.flatnonzero(dist > tol)
            if bad.size:
                j = int(bad[0])
                raise SceneError(f"{src}: {keys[j]}: point {format_point(forced[j])} "
                                 "is not a node of the explicit mesh")

    # counter-clockwise in X (a P2 triangle's midside nodes follow its edges)
    p = X[tris[:, :3]]
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    cw = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0] < 0
    tris = tris.copy()
    tris[cw] = tris[cw][:, [0, 2, 1, 5, 4, 3] if tris.shape[1] == 6 else [0, 2, 1]]

    # drop nodes no triangle uses (keep the order of the rest)
    used = np.zeros(len(X), dtype=bool)
    used[tris.reshape(-1)] = True
    if not used.all():
        new = np.cumsum(used) - 1
        if len(node_of) and not used[node_of].all():
            j = int(np.flatnonzero(~used[node_of])[0])
            raise SceneError(f"{src}: {keys[j]}: point is not part of the mesh")
        X, tris, node_of = X[used], new[tris], new[node_of]
    element = named(scene.element)
    X, tris, elements = element.complete(X, tris)
    if elements is not None:
        midside = ~np.isin(node_of, tris)
        if midside.any():
            j = int(np.flatnonzero(midside)[0])
            raise SceneError(f"{src}: {keys[j]}: point is a midside node of the {element} mesh; "
                             "pins, via points and points must be corner nodes")

    n_pin = len(scene.pin_points)
    pins = node_of[:n_pin]
    pos = n_pin
    tendon_nodes = []
    for t, tendon in enumerate(scene.tendons):
        nodes = node_of[pos:pos + len(tendon.path)]
        pos += len(tendon.path)
        same = np.flatnonzero(nodes[1:] == nodes[:-1])
        if same.size:
            j = int(same[0]) + 1
            raise SceneError(f"{src}: tendons.list[{t}].path[{j}]: via point is the same node "
                             f"as path[{j - 1}]")
        tendon_nodes.append(nodes)
    point_nodes = node_of[pos:]

    if scene.pin_box is not None:
        x0, y0, x1, y1 = scene.pin_box
        inbox = np.flatnonzero((X[:, 0] >= x0 - tol) & (X[:, 0] <= x1 + tol)
                               & (X[:, 1] >= y0 - tol) & (X[:, 1] <= y1 + tol))
        if inbox.size == 0:
            raise SceneError(f"{src}: pins.box: catches no mesh node")
        pins = np.concatenate([pins, inbox])
    pin_nodes = np.unique(pins)

    at = np.array([t.at for t in scene.targets]).reshape(-1, 2)
    target_tri, target_beta = locate_in_triangles(X[tris], at, tol)
    bad = np.flatnonzero(target_tri < 0)
    if bad.size:
        k = int(bad[0])
        raise SceneError(f"{src}: targets[{k}].at: point {format_point(at[k])} "
                         "lies outside the mesh")

    return Mesh(X=X, triangles=tris, pin_nodes=pin_nodes, tendon_nodes=tuple(tendon_nodes),
                target_triangles=target_tri, target_beta=target_beta, point_nodes=point_nodes,
                element=element, elements=elements)


def mesh_for_nodes(scene: Scene, target_nodes: int, *, rel_tol: float = 0.05,
                   max_iter: int = 16) -> Mesh:
    """Mesh an outline scene with about ``target_nodes`` nodes (see
    :func:`area_for_nodes`)."""
    return area_for_nodes(scene, target_nodes, rel_tol=rel_tol, max_iter=max_iter)[1]


def area_for_nodes(scene: Scene, target_nodes: int, *, graded: bool = False, rel_tol: float = 0.05,
                   max_iter: int = 16) -> tuple[float, Mesh]:
    """The ``max_area`` that meshes an outline scene with about
    ``target_nodes`` nodes, and that mesh.

    Adjusts ``max_area`` (steps assuming nodes ~ 1 / area, kept inside a
    bracket) until the node count is within ``rel_tol`` of the target, and
    returns the closest mesh found. Deterministic.

    Raises
    ------
    SceneError
        For an explicit mesh (its resolution is fixed) or a bad target.
    """
    if scene.outline is None:
        raise SceneError(f"{scene.source}: mesh: an explicit mesh cannot be resized")
    if not (isinstance(target_nodes, (int, np.integer)) and target_nodes >= 3):
        raise SceneError(f"{scene.source}: target_nodes must be an integer >= 3, "
                         f"got {target_nodes!r}")
    body = body_area(scene.outline, scene.holes)
    lo, hi = 0.0, math.inf              # bracket on max_area: lo too fine, hi too coarse
    area = body / (2.0 * target_nodes)  # a triangulation has about twice as many elements
    best = None
    for _ in range(max_iter):
        mesh = build_mesh(scene, max_area=area, graded=graded, announce=False)   # (a trial: quiet)
        n = mesh.n_nodes
        if best is None or abs(n - target_nodes) < abs(best[1].n_nodes - target_nodes):
            best = (area, mesh)
        if abs(n - target_nodes) <= rel_tol * target_nodes:
            break
        if n > target_nodes:
            lo = max(lo, area)
        else:
            hi = min(hi, area)
        guess = area * n / target_nodes   # n ~ 1 / area
        if not lo < guess < hi:
            guess = math.sqrt(lo * hi) if math.isfinite(hi) and lo > 0 else (
                area * 2.0 if n > target_nodes else area / 2.0)
        if guess == area:
            break
        area = guess
    note = large_mesh_note(scene, best[0])
    if note is not None:                          # the mesh kept, announced as build_mesh does
        log.warning("%s: %s", scene.source, note)
    return best
