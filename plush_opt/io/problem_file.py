"""Problem file (format ``plush-opt/1``, docs/problem-format.md) ->
validated :class:`~plush_opt.io.scene.Scene`.

The document is read by :func:`~plush_opt.io.yaml_reader.read_yaml` and
checked section by section with a :class:`~plush_opt.io.checker.Checker`;
the body's outline, holes and explicit mesh are checked by
:mod:`.mesh_input`; points inside the body or on nodes of an explicit mesh
use :mod:`plush_opt.base.geometry`.
"""

from __future__ import annotations

import logging
import math
import numbers
import os
import re

import numpy as np

from ..base.errors import format_number, format_point, shown
from ..base.geometry import classify_points, locate_in_triangles
from .scene import FORMAT, POINT_TOL, Material, Scene, Target, Tendon, Winch
from .checker import MAX_COORD, MAX_WEIGHT, Checker, at_index, at_key, describe
from .contact_section import contact_section
from .mesh_input import check_points_are_nodes, length, mesh_section
from .plausibility import plausibility_warnings
from .units import DEFAULT_UNITS, FORCES, LENGTHS, Units
from .yaml_reader import read_yaml

log = logging.getLogger("plush_opt")

#: via points of one tendon, and of a whole file: a tendon's Hessian block and
#: its path's mesh nodes grow with them; sewn robots have tens
MAX_VIA_POINTS, MAX_VIA_POINTS_TOTAL = 1000, 5000
#: tendons of a file: each is a dense row and column of the Hessian's low-rank term
MAX_TENDONS = 200
#: a nonzero attachment radius is at least this fraction of the body's diameter
#: (and of its largest coordinate): smaller discs are below the resolution the
#: disc integration can split triangles to (use 0, a point attachment)
MIN_RADIUS, MIN_RADIUS_OF_COORD = 1e-6, 1e-9
#: the pin stiffness of a file without pins (contact holds the body): recorded,
#: never used, since no node is pinned
DEFAULT_PIN_STIFFNESS = 1.0

_NAME = re.compile(r"[A-Za-z0-9_-]+")

_TOP_KEYS = ("format", "name", "description", "mesh", "material", "gravity", "pins",
             "winches", "tendons", "targets", "points", "contact", "units")
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
    scene = scene_from_dict(read_yaml(path, what="problem file", source=source), source)
    for line in plausibility_warnings(scene):       # valid, but unlikely meant: said, not refused
        log.warning("%s: %s", source, line)
    return scene


def file_units(path) -> Units:
    """The :class:`~plush_opt.io.units.Units` a problem file says it is
    written in (its ``units`` key only; mm and N without it)."""
    source = os.path.basename(os.fspath(path)) or os.fspath(path)
    doc = read_yaml(path, what="problem file", source=source)
    return units_section(Checker(source), _opt(doc, "units") if isinstance(doc, dict) else None)


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
                required=("format", "name", "mesh", "material", "winches", "tendons"))
    name, description = _header_section(ck, data)
    units = units_section(ck, _opt(data, "units"))
    geo = mesh_section(ck, data["mesh"])
    material = _material_section(ck, data["material"])

    gravity = _opt(data, "gravity")
    if gravity is not None:
        gravity = ck.point(gravity, "gravity")
        if material.density is None:
            ck.fail("material.density", "required when gravity is given")

    contact = contact_section(ck, _opt(data, "contact"), geo["diameter"])
    pins = _opt(data, "pins")
    if pins is None and contact is None:
        ck.fail("pins", "missing required key (a body without pins needs a contact section to hold it)")
    pin_stiffness, pin_points, pin_box = (_pins_section(ck, pins) if pins is not None
                                          else (DEFAULT_PIN_STIFFNESS, np.zeros((0, 2)), None))
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
        element=geo["element"], contact=contact, units=units,
    )


def _header_section(ck: Checker, data: dict) -> tuple[str, str]:
    fmt = ck.string(data["format"], "format")
    if fmt != FORMAT:
        ck.fail("format", f"expected exactly '{FORMAT}', got {shown(fmt)}")
    name = ck.string(data["name"], "name")
    if not _NAME.fullmatch(name):
        ck.fail("name", f"{shown(name)} must match [A-Za-z0-9_-]+")
    description = _opt(data, "description")
    description = "" if description is None else ck.string(description, "description")
    return name, description


def units_section(ck: Checker, raw, *, result: bool = False) -> Units:
    """The optional ``units`` mapping (docs/problem-format.md, reading 30):
    ``length`` one of :data:`~plush_opt.io.units.LENGTHS`, ``force`` one of
    :data:`~plush_opt.io.units.FORCES` (defaults mm and N); a ``stress``, if
    given, must be the one they imply. Anything else is one line naming the key.
    ``result``: a result file's ``units`` object, whose other names (mass,
    density, ...) are not checked."""
    if raw is None:
        return DEFAULT_UNITS
    ck.mapping(raw, "units", tuple(raw) if result and isinstance(raw, dict) else ("length", "force", "stress"))
    chosen = {}
    for key, accepted in (("length", LENGTHS), ("force", FORCES)):
        value = _opt(raw, key)
        if value is None:
            chosen[key] = getattr(DEFAULT_UNITS, key)
            continue
        value = ck.string(value, f"units.{key}")
        if value not in accepted:
            ck.fail(f"units.{key}", f"{shown(value)} is not one of {', '.join(accepted)}")
        chosen[key] = value
    units = Units(**chosen)
    stress = _opt(raw, "stress")
    if stress is not None and ck.string(stress, "units.stress") != units.stress:
        ck.fail("units.stress", f"{shown(stress)} does not follow from {units.force} and {units.length}: "
                f"stress is force/length^2, {units.stress} (units are labels: give length and force)")
    return units


def read_targets(raw, source: str) -> list[Target]:
    """Targets given as the problem file's ``targets`` list (``[{"at": [x, y],
    "to": [x, y], "weight": w}, ...]``, lists or tuples), checked as the
    loader checks them; a bad entry is one :class:`SceneError`
    "SOURCE: targets[i].KEY: ..."."""
    return _targets_section(Checker(source), raw)


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
        check_points_are_nodes(ck, geo["nodes"], forced, tol)
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


def _material_section(ck: Checker, mat) -> Material:
    ck.mapping(mat, "material", _MATERIAL_KEYS, required=("model", "thickness"))
    model = ck.string(mat["model"], "material.model")
    if model != "neo_hookean":
        ck.fail("material.model", f"unknown model {shown(model)}; version 1 has only 'neo_hookean'")
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


#: a message lists at most this many names (the winches a tendon may name)
MAX_LISTED = 10


def _listed(names) -> str:
    """Names for a message, each capped, at most :data:`MAX_LISTED` of them."""
    more = f", ... ({len(names)} in all)" if len(names) > MAX_LISTED else ""
    return ", ".join(shown(n) for n in names[:MAX_LISTED]) + more


def _winches_section(ck: Checker, raw) -> list[Winch]:
    winches, seen = [], {}
    for i, w in enumerate(ck.seq(raw, "winches", min_len=1, what="list of winches")):
        path = at_index("winches", i)
        ck.mapping(w, path, _WINCH_KEYS, required=("name", "bounds"))
        name = ck.name(w["name"], at_key(path, "name"))
        if name in seen:
            ck.fail(at_key(path, "name"), f"duplicate name {shown(name)} (also winches[{seen[name]}])")
        seen[name] = i
        b = w["bounds"]
        if isinstance(b, np.ndarray):
            b = list(b)
        if not isinstance(b, (list, tuple)) or len(b) != 2:
            ck.fail(at_key(path, "bounds"), f"expected [lower, upper], got {describe(b)}")
        lo, hi = (length(ck, b[k], at_index(at_key(path, "bounds"), k)) for k in (0, 1))
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
                    f"duplicate name {shown(name)} (also tendons.list[{seen[name]}])")
        seen[name] = i
        winch = ck.name(t["winch"], at_key(path, "winch"))
        if winch not in winch_index:
            ck.fail(at_key(path, "winch"), f"no winch named {shown(winch)} (winches: "
                    f"{_listed([w.name for w in winches])})")
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
            ck.fail(at_index("winches", i), f"winch {shown(w.name)} has no tendons")
    return stiffness, smoothing, tendons


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
