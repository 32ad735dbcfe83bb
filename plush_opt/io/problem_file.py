"""Problem file (format ``plush-opt/1``, docs/problem-format.md) ->
validated :class:`~plush_opt.io.scene.Scene`.

The document is read by :func:`~plush_opt.io.yaml_reader.read_yaml` and
checked section by section with a :class:`~plush_opt.io.checker.Checker`;
the geometry checks (simple polygons, holes inside the outline, points
inside the body or on nodes of an explicit mesh) use
:mod:`plush_opt.base.geometry`.
"""

from __future__ import annotations

import math
import numbers
import os
import re

import numpy as np
from scipy.spatial import cKDTree

from ..base.errors import format_number, format_point
from ..base.geometry import classify_points, diameter, find_crossing, locate_in_triangles, ring_area
from .scene import ELEMENTS, FORMAT, NODES_PER_TRIANGLE, POINT_TOL, Material, Scene, Target, Tendon, Winch
from .checker import MAX_COORD, MAX_WEIGHT, Checker, at_index, at_key, describe
from .yaml_reader import read_yaml

MAX_MIN_ANGLE = 34.0              # Triangle may not terminate above about 34 degrees
#: a polygon whose area is below this fraction of its bounding box's squared size is flat
ZERO_AREA = 1e-12
#: a triangle whose cross product is below this fraction of its longest squared edge is flat
FLAT_TRIANGLE = 1e-12
#: via points of one tendon, and of a whole file: a tendon's Hessian block and
#: its path's mesh nodes grow with them; sewn robots have tens
MAX_VIA_POINTS, MAX_VIA_POINTS_TOTAL = 1000, 5000
#: tendons of a file: each is a dense row and column of the Hessian's low-rank term
MAX_TENDONS = 200
#: a nonzero attachment radius is at least this fraction of the body's diameter
#: (and of its largest coordinate): smaller discs are below the resolution the
#: disc integration can split triangles to (use 0, a point attachment)
MIN_RADIUS, MIN_RADIUS_OF_COORD = 1e-6, 1e-9

_NAME = re.compile(r"[A-Za-z0-9_-]+")

_TOP_KEYS = ("format", "name", "description", "mesh", "material", "gravity", "pins",
             "winches", "tendons", "targets", "points")
_MESH_KEYS = ("outline", "holes", "max_area", "min_angle", "nodes", "triangles", "element")
_MATERIAL_KEYS = ("model", "youngs_modulus", "poisson_ratio", "mu", "lambda", "thickness",
                  "density")
_PIN_KEYS = ("stiffness", "at", "box")
_WINCH_KEYS = ("name", "bounds", "contraction", "frozen")
_TENDONS_KEYS = ("stiffness", "smoothing", "list", "attachment_radius", "friction")
_TENDON_KEYS = ("name", "winch", "path", "assembly_offset", "attachment_radius", "friction")
_TARGET_KEYS = ("at", "to", "weight")


def load_scene(path) -> Scene:
    """Read and validate a problem file (format ``plush-opt/1``).

    Parameters
    ----------
    path : str or os.PathLike
        The YAML problem file.

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        For any unreadable, oversized, malformed or invalid file. The message
        starts with the file name and names the key and list index.
    """
    source = os.path.basename(os.fspath(path)) or os.fspath(path)
    return scene_from_dict(read_yaml(path, what="problem file", source=source), source)


def _opt(d: dict, key: str):
    """Value of an optional key; an explicit null counts as absent."""
    return d.get(key)


def scene_from_dict(data: dict, source: str = "<memory>") -> Scene:
    """Validate an already parsed problem document.

    Parameters
    ----------
    data : dict
        The document as plain Python data (what ``yaml.safe_load`` gives).
    source : str
        Name used at the start of error messages (normally the file name).

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        The message starts with ``source`` and names the key and list index.
    """
    ck = Checker(source)
    ck.document(data, _TOP_KEYS,
                required=("format", "name", "mesh", "material", "pins", "winches", "tendons"))
    name, description = _header_section(ck, data)
    geo = _mesh_section(ck, data["mesh"])
    material = _material_section(ck, data["material"])

    gravity = _opt(data, "gravity")
    if gravity is not None:
        gravity = ck.point(gravity, "gravity")
        if material.density is None:
            ck.fail("material.density", "required when gravity is given")

    pin_stiffness, pin_points, pin_box = _pins_section(ck, data["pins"])
    winches = _winches_section(ck, data["winches"])
    t_stiffness, t_smoothing, tendons = _tendons_section(ck, data["tendons"], winches)
    _check_physics_ranges(ck, data, material, gravity, pin_stiffness, t_stiffness)
    targets = _targets_section(ck, _opt(data, "targets"))
    raw_points = _opt(data, "points")
    points = np.zeros((0, 2)) if raw_points is None else ck.points(raw_points, "points", min_len=0)
    _check_points_in_body(ck, geo, pin_points, tendons, targets, points)
    _check_tendon_sizes(ck, geo, tendons, data["tendons"], t_smoothing)

    return Scene(
        name=name, description=description, source=source, material=material,
        pin_stiffness=pin_stiffness, pin_points=pin_points, pin_box=pin_box,
        winches=tuple(winches), tendon_stiffness=t_stiffness, tendon_smoothing=t_smoothing,
        tendons=tuple(tendons), targets=tuple(targets), points=points, gravity=gravity,
        outline=geo["outline"], holes=tuple(geo["holes"]), max_area=geo["max_area"],
        min_angle=geo["min_angle"], nodes=geo["nodes"], triangles=geo["triangles"],
        element=geo["element"],
    )


def _header_section(ck: Checker, data: dict) -> tuple[str, str]:
    fmt = ck.string(data["format"], "format")
    if fmt != FORMAT:
        ck.fail("format", f"expected exactly '{FORMAT}', got {fmt!r}")
    name = ck.string(data["name"], "name")
    if not _NAME.fullmatch(name):
        ck.fail("name", f"{name!r} must match [A-Za-z0-9_-]+")
    description = _opt(data, "description")
    description = "" if description is None else ck.string(description, "description")
    return name, description


def _targets_section(ck: Checker, raw) -> list[Target]:
    targets = []
    if raw is None:
        return targets
    for i, t in enumerate(ck.seq(raw, "targets", what="list of targets")):
        path = at_index("targets", i)
        ck.mapping(t, path, _TARGET_KEYS, required=("at", "to"))
        weight = _opt(t, "weight")
        weight = 1.0 if weight is None else ck.number(weight, at_key(path, "weight"), gt=0)
        if weight > MAX_WEIGHT:
            ck.fail(at_key(path, "weight"), f"must be <= {MAX_WEIGHT:g}, got {format_number(weight)}")
        targets.append(Target(at=ck.point(t["at"], at_key(path, "at")),
                              to=ck.point(t["to"], at_key(path, "to")), weight=weight))
    return targets


def _check_tendon_sizes(ck: Checker, geo: dict, tendons, raw, smoothing: float) -> None:
    """The smoothing a length (within MAX_COORD), each nonzero attachment
    radius at least MIN_RADIUS of the body's size."""
    if smoothing > MAX_COORD:
        ck.fail("tendons.smoothing", f"{format_number(smoothing)} is too large (lengths are limited to "
                f"{MAX_COORD:g} in magnitude)")
    body = geo["outline"] if geo["outline"] is not None else geo["nodes"]
    floor = max(MIN_RADIUS * geo["diameter"], MIN_RADIUS_OF_COORD * float(np.max(np.abs(body))))
    for i, t in enumerate(tendons):
        if 0 < t.attachment_radius < floor:
            own = raw["list"][i].get("attachment_radius") is not None
            ck.fail(at_key(at_index("tendons.list", i), "attachment_radius") if own
                    else "tendons.attachment_radius",
                    f"{format_number(t.attachment_radius)} is below {floor:.3g}, {MIN_RADIUS:g} of "
                    "the body's size: give 0 for a point attachment")


def _check_points_in_body(ck: Checker, geo: dict, pin_points, tendons, targets, points):
    """Pins, via points and extra points inside the body (on nodes of an
    explicit mesh), targets inside the body, consecutive via points apart."""
    tol = POINT_TOL * geo["diameter"]
    forced = [("pins.at", pin_points)]
    forced += [(at_key(at_index("tendons.list", i), "path"), t.path) for i, t in enumerate(tendons)]
    forced += [("points", points)]
    for i, t in enumerate(tendons):
        step = np.hypot(*np.diff(t.path, axis=0).T)
        bad = np.flatnonzero(step <= tol)
        if bad.size:
            j = int(bad[0]) + 1
            ck.fail(at_index(at_key(at_index("tendons.list", i), "path"), j),
                    f"point {format_point(t.path[j])} repeats the previous via point (closer "
                    f"than {tol:.3g} = 1e-9 x body diameter); consecutive via points must be "
                    "distinct")
    at = np.array([t.at for t in targets]).reshape(-1, 2)
    if geo["nodes"] is not None:
        _check_points_are_nodes(ck, geo["nodes"], forced, tol)
        tri, _ = locate_in_triangles(geo["nodes"][geo["triangles"][:, :3]], at, tol)
        bad = np.flatnonzero(tri < 0)
        if bad.size:
            j = int(bad[0])
            ck.fail(at_key(at_index("targets", j), "at"),
                    f"point {format_point(at[j])} lies outside the body")
        return
    rings = [geo["outline"], *geo["holes"]]
    for key, pts in forced + [("targets", at)]:
        where = classify_points(pts, rings, tol)
        bad = np.flatnonzero(where < 0)
        if bad.size:
            j = int(bad[0])
            path = at_key(at_index(key, j), "at") if key == "targets" else at_index(key, j)
            ck.fail(path, f"point {format_point(pts[j])} lies outside the body")


def _mesh_section(ck: Checker, mesh) -> dict:
    ck.mapping(mesh, "mesh", _MESH_KEYS)
    has = {k for k in _MESH_KEYS if mesh.get(k) is not None}
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
        _check_ring(ck, outline, "mesh.outline")
        holes = []
        if "holes" in has:
            for i, h in enumerate(ck.seq(mesh["holes"], "mesh.holes", what="list of polygons")):
                hp = at_index("mesh.holes", i)
                hole = ck.points(h, hp, min_len=3)
                _check_ring(ck, hole, hp)
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
                ck.fail(at_index(p, c), f"node index {iv} out of range 0..{n_nodes - 1}")
            tris[e, c] = iv
    _check_explicit_mesh(ck, nodes, tris)
    if width == 6:
        _check_midside_nodes(ck, nodes, tris)
    out.update(nodes=nodes, triangles=tris, diameter=diameter(nodes))
    return out


def explicit_mesh(ck: Checker, element, nodes, triangles) -> tuple[np.ndarray, np.ndarray]:
    """``element``, ``nodes`` and ``triangles`` checked as a problem file's
    explicit mesh (``ck`` names the keys): (nodes (n, 2), triangles (m, 3 or 6))."""
    geo = _mesh_section(ck, {"element": element, "nodes": nodes, "triangles": triangles})
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


def _check_points_are_nodes(ck: Checker, nodes, forced, tol):
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


def _material_section(ck: Checker, mat) -> Material:
    ck.mapping(mat, "material", _MATERIAL_KEYS, required=("model", "thickness"))
    model = ck.string(mat["model"], "material.model")
    if model != "neo_hookean":
        ck.fail("material.model", f"unknown model {model!r}; version 1 has only 'neo_hookean'")
    has = {k for k in _MATERIAL_KEYS if mat.get(k) is not None}
    e_form = has & {"youngs_modulus", "poisson_ratio"}
    l_form = has & {"mu", "lambda"}
    if e_form and l_form:
        ck.fail(at_key("material", sorted(l_form)[0]),
                "give either youngs_modulus and poisson_ratio, or mu and lambda, not both")
    if e_form:
        for k in ("youngs_modulus", "poisson_ratio"):
            if k not in has:
                ck.fail(at_key("material", k), "required with material."
                        + ({"youngs_modulus", "poisson_ratio"} - {k}).pop())
        E = ck.number(mat["youngs_modulus"], "material.youngs_modulus", gt=0)
        nu = ck.number(mat["poisson_ratio"], "material.poisson_ratio", ge=0, lt=0.5)
        mu = E / (2.0 * (1.0 + nu))
        lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    elif l_form:
        for k in ("mu", "lambda"):
            if k not in has:
                ck.fail(at_key("material", k), "required with material."
                        + ({"mu", "lambda"} - {k}).pop())
        mu = ck.number(mat["mu"], "material.mu", gt=0)
        lam = ck.number(mat["lambda"], "material.lambda", gt=0)
    else:
        ck.fail("material", "give youngs_modulus and poisson_ratio, or mu and lambda")
    if not (math.isfinite(mu) and math.isfinite(lam)):
        ck.fail("material", f"the Lame parameters overflow (mu = {mu:g}, lambda = {lam:g})")
    thickness = ck.number(mat["thickness"], "material.thickness", gt=0)
    density = _opt(mat, "density")
    if density is not None:
        density = ck.number(density, "material.density", gt=0)
    return Material(mu=mu, lam=lam, thickness=thickness, density=density)


def _pins_section(ck: Checker, pins):
    ck.mapping(pins, "pins", _PIN_KEYS, required=("stiffness",))
    stiffness = ck.number(pins["stiffness"], "pins.stiffness", gt=0)
    box = _opt(pins, "box")
    if box is not None:
        if isinstance(box, np.ndarray):
            box = list(box)
        if not isinstance(box, (list, tuple)) or len(box) != 4:
            ck.fail("pins.box", f"expected [xmin, ymin, xmax, ymax], got {describe(box)}")
        box = np.array([ck.number(v, at_index("pins.box", i)) for i, v in enumerate(box)])
        big = np.flatnonzero(np.abs(box) > MAX_COORD)
        if big.size:
            ck.fail(at_index("pins.box", int(big[0])), f"{format_number(box[big[0]])} is too large "
                    f"(coordinates are limited to {MAX_COORD:g} in magnitude)")
        if box[0] > box[2]:
            ck.fail("pins.box", f"xmin {format_number(box[0])} > xmax {format_number(box[2])}")
        if box[1] > box[3]:
            ck.fail("pins.box", f"ymin {format_number(box[1])} > ymax {format_number(box[3])}")
    at = _opt(pins, "at")
    if at is None:
        if box is None:
            ck.fail("pins", "no pins: give pins.at or pins.box")
        at = np.zeros((0, 2))
    else:
        at = ck.points(at, "pins.at", min_len=0 if box is not None else 1)
    return stiffness, at, box


def _winches_section(ck: Checker, raw) -> list[Winch]:
    winches, seen = [], {}
    for i, w in enumerate(ck.seq(raw, "winches", min_len=1, what="list of winches")):
        path = at_index("winches", i)
        ck.mapping(w, path, _WINCH_KEYS, required=("name", "bounds"))
        name = ck.name(w["name"], at_key(path, "name"))
        if name in seen:
            ck.fail(at_key(path, "name"), f"duplicate name {name!r} (also winches[{seen[name]}])")
        seen[name] = i
        b = w["bounds"]
        if isinstance(b, np.ndarray):
            b = list(b)
        if not isinstance(b, (list, tuple)) or len(b) != 2:
            ck.fail(at_key(path, "bounds"), f"expected [lower, upper], got {describe(b)}")
        lo, hi = (_length(ck, b[k], at_index(at_key(path, "bounds"), k)) for k in (0, 1))
        if not lo < hi:
            ck.fail(at_key(path, "bounds"), f"lower {format_number(lo)} must be < upper {format_number(hi)}")
        c = _opt(w, "contraction")
        if c is None:
            c = min(max(0.0, lo), hi)
        else:
            c = ck.number(c, at_key(path, "contraction"))
            if not lo <= c <= hi:
                ck.fail(at_key(path, "contraction"),
                        f"{format_number(c)} is outside bounds [{format_number(lo)}, {format_number(hi)}]")
        frozen = _opt(w, "frozen")
        frozen = False if frozen is None else ck.boolean(frozen, at_key(path, "frozen"))
        winches.append(Winch(name=name, bounds=(lo, hi), contraction=c, frozen=frozen))
    return winches


def _tendons_section(ck: Checker, raw, winches):
    ck.mapping(raw, "tendons", _TENDONS_KEYS, required=("stiffness", "smoothing", "list"))
    stiffness = ck.number(raw["stiffness"], "tendons.stiffness", gt=0)
    smoothing = ck.number(raw["smoothing"], "tendons.smoothing", gt=0)
    radius = _opt(raw, "attachment_radius")
    radius = 0.0 if radius is None else ck.number(radius, "tendons.attachment_radius", ge=0)
    friction = _opt(raw, "friction")
    friction = 0.0 if friction is None else ck.number(friction, "tendons.friction", ge=0)
    winch_index = {w.name: i for i, w in enumerate(winches)}
    used = set()
    tendons, seen, n_via = [], {}, 0
    items = ck.seq(raw["list"], "tendons.list", min_len=1, what="list of tendons")
    if len(items) > MAX_TENDONS:
        ck.fail("tendons.list", f"{len(items)} tendons; at most {MAX_TENDONS}")
    for i, t in enumerate(items):
        path = at_index("tendons.list", i)
        ck.mapping(t, path, _TENDON_KEYS, required=("name", "winch", "path"))
        name = ck.name(t["name"], at_key(path, "name"))
        if name in seen:
            ck.fail(at_key(path, "name"),
                    f"duplicate name {name!r} (also tendons.list[{seen[name]}])")
        seen[name] = i
        winch = ck.name(t["winch"], at_key(path, "winch"))
        if winch not in winch_index:
            ck.fail(at_key(path, "winch"), f"no winch named {winch!r} (winches: "
                    f"{', '.join(repr(w.name) for w in winches)})")
        used.add(winch)
        via = ck.points(t["path"], at_key(path, "path"), min_len=2)
        n_via += len(via)
        if len(via) > MAX_VIA_POINTS or n_via > MAX_VIA_POINTS_TOTAL:
            ck.fail(at_key(path, "path"), f"{len(via)} via points; at most {MAX_VIA_POINTS} per tendon and "
                    f"{MAX_VIA_POINTS_TOTAL} in a file (this makes {n_via})")
        offset = _opt(t, "assembly_offset")
        offset = 0.0 if offset is None else ck.number(offset, at_key(path, "assembly_offset"))
        if abs(offset) > MAX_COORD:
            ck.fail(at_key(path, "assembly_offset"), f"{format_number(offset)} is too large "
                    f"(lengths are limited to {MAX_COORD:g} in magnitude)")
        rest = float(np.hypot(*np.diff(via, axis=0).T).sum())
        if not rest + offset > 0:
            ck.fail(at_key(path, "assembly_offset"), f"{format_number(offset)} leaves the tendon "
                    f"no length (its path is {format_number(rest)} long)")
        own = _opt(t, "attachment_radius")
        own = radius if own is None else ck.number(own, at_key(path, "attachment_radius"), ge=0)
        mu = _opt(t, "friction")
        mu = friction if mu is None else ck.number(mu, at_key(path, "friction"), ge=0)
        tendons.append(Tendon(name=name, winch=winch, path=via, assembly_offset=offset,
                              attachment_radius=own, friction=mu))
    for i, w in enumerate(winches):
        if w.name not in used:
            ck.fail(at_index("winches", i), f"winch {w.name!r} has no tendons")
    return stiffness, smoothing, tendons


def _check_ring(ck: Checker, ring: np.ndarray, path: str):
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
    area = abs(ring_area(ring))
    if not area > ZERO_AREA * float(np.sum(np.ptp(ring, axis=0) ** 2)):
        ck.fail(path, "polygon has zero area")


def _length(ck: Checker, value, path: str) -> float:
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


# Moduli and stiffnesses (any unit system: steel is 2e5 MPa, 2e11 Pa; diamond
# about 6 times that) and the body force density rho |g| (steel under Earth's
# gravity: 8e-5 N/mm^3, 8e4 N/m^3) are limited far above any material, so that
# forces and their squares (the residual's norm) stay far from float64 overflow.
MAX_MODULUS = 1e20
MAX_BODY_FORCE = 1e20


def _check_physics_ranges(ck: Checker, data: dict, material: Material, gravity, pin_stiffness: float,
                          t_stiffness: float) -> None:
    """Moduli, stiffnesses and the gravity load within the limits above: beyond
    them a solve overflows (a residual of inf certifies nothing) or no Hessian
    shift is found; one line naming the key and the limit."""
    mat = data["material"]
    named = [(at_key("material", k), mat.get(k)) for k in ("youngs_modulus", "mu", "lambda")]
    named += [("pins.stiffness", pin_stiffness), ("tendons.stiffness", t_stiffness)]
    for key, value in named:
        if isinstance(value, numbers.Real) and not isinstance(value, bool) and float(value) > MAX_MODULUS:
            ck.fail(key, f"{format_number(value)} is above the limit {MAX_MODULUS:g} "
                    "(far above any material; forces would overflow)")
    if gravity is not None and material.density is not None:
        load = material.density * math.hypot(float(gravity[0]), float(gravity[1]))
        if not load <= MAX_BODY_FORCE:
            ck.fail("material.density", f"density x |gravity| = {load:g} is above the limit "
                    f"{MAX_BODY_FORCE:g} (the gravity load would overflow; check material.density and gravity)")
