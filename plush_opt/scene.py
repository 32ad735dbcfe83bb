"""Problem file -> validated, immutable :class:`Scene`.

Implements the problem format ``plush-opt/1`` (docs/problem-format.md).
The scene holds what the file says and nothing derived from a mesh; the
mesh and the model are built from it (``mesh.build_mesh``,
``model.build_model``), never the other way round.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
import os
import re
from dataclasses import dataclass, field

import numpy as np
import yaml
from scipy.spatial import ConvexHull, QhullError, cKDTree

from .errors import SceneError

FORMAT = "plush-opt/1"
MAX_FILE_BYTES = 1 << 20          # 1 MiB: problem files are small; refuse before parsing
POINT_TOL = 1e-9                  # coincidence tolerance, relative to the body diameter
MAX_MIN_ANGLE = 34.0              # Triangle may not terminate above about 34 degrees
MAX_COORD = 1e12                  # keeps squared lengths and areas far from overflow


def _points(a, ncols=2) -> np.ndarray:
    """Contiguous read-only float64 array of shape (k, ncols)."""
    arr = np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(-1, ncols))
    arr.setflags(write=False)
    return arr


def _vector(a) -> np.ndarray:
    arr = np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(-1))
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Material:
    """Compressible Neo-Hookean material (Lame parameters, consistent units)."""

    mu: float
    lam: float
    thickness: float
    density: float | None = None


@dataclass(frozen=True)
class Winch:
    """A winch: contracts all its tendons by the same length.

    ``bounds = (lower, upper)``; ``contraction`` is the forward input
    (already defaulted by the loader: 0, or the nearer bound if 0 is outside).
    """

    name: str
    bounds: tuple[float, float]
    contraction: float
    frozen: bool = False


@dataclass(frozen=True)
class Tendon:
    """A tendon routed through via points, stopper end first, winch end last."""

    name: str
    winch: str
    path: np.ndarray  # (n_via, 2) rest coordinates

    def __post_init__(self):
        object.__setattr__(self, "path", _points(self.path))

    def __eq__(self, other):
        return (isinstance(other, Tendon) and self.name == other.name
                and self.winch == other.winch and np.array_equal(self.path, other.path))

    __hash__ = None


@dataclass(frozen=True)
class Target:
    """Move the body point ``at`` (rest coordinates) to ``to``."""

    at: np.ndarray  # (2,)
    to: np.ndarray  # (2,)
    weight: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "at", _vector(self.at))
        object.__setattr__(self, "to", _vector(self.to))

    def __eq__(self, other):
        return (isinstance(other, Target) and np.array_equal(self.at, other.at)
                and np.array_equal(self.to, other.to) and self.weight == other.weight)

    __hash__ = None


@dataclass(frozen=True)
class Scene:
    """One validated scene. Exactly one of ``outline`` or ``nodes`` is set.

    Arrays are read-only float64 (int64 for ``triangles``), rows are points.
    """

    name: str
    material: Material
    pin_stiffness: float
    pin_points: np.ndarray            # (n_pin_points, 2)
    winches: tuple[Winch, ...]
    tendon_stiffness: float
    tendon_smoothing: float
    tendons: tuple[Tendon, ...]
    description: str = ""
    source: str = "<memory>"          # file name used in error messages
    outline: np.ndarray | None = None  # (n_outline, 2)
    holes: tuple[np.ndarray, ...] = ()
    max_area: float | None = None
    min_angle: float | None = None
    nodes: np.ndarray | None = None    # (n_nodes, 2) explicit mesh
    triangles: np.ndarray | None = None  # (n_elems, 3) explicit mesh, as given
    gravity: np.ndarray | None = None  # (2,)
    pin_box: np.ndarray | None = None  # (4,) xmin, ymin, xmax, ymax
    targets: tuple[Target, ...] = ()
    points: np.ndarray = field(default_factory=lambda: _points(np.zeros((0, 2))))

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        set_("pin_points", _points(self.pin_points))
        set_("points", _points(self.points))
        set_("holes", tuple(_points(h) for h in self.holes))
        set_("winches", tuple(self.winches))
        set_("tendons", tuple(self.tendons))
        set_("targets", tuple(self.targets))
        if self.outline is not None:
            set_("outline", _points(self.outline))
        if self.nodes is not None:
            set_("nodes", _points(self.nodes))
        if self.triangles is not None:
            tri = np.ascontiguousarray(np.asarray(self.triangles, dtype=np.int64).reshape(-1, 3))
            tri.setflags(write=False)
            set_("triangles", tri)
        if self.gravity is not None:
            set_("gravity", _vector(self.gravity))
        if self.pin_box is not None:
            set_("pin_box", _vector(self.pin_box))

    # -- convenience -----------------------------------------------------
    @property
    def winch_names(self) -> tuple[str, ...]:
        return tuple(w.name for w in self.winches)

    @property
    def contraction(self) -> np.ndarray:
        """Forward contractions from the file, (n_winches,)."""
        return np.array([w.contraction for w in self.winches], dtype=np.float64)

    @property
    def lower(self) -> np.ndarray:
        return np.array([w.bounds[0] for w in self.winches], dtype=np.float64)

    @property
    def upper(self) -> np.ndarray:
        return np.array([w.bounds[1] for w in self.winches], dtype=np.float64)

    @property
    def frozen(self) -> np.ndarray:
        return np.array([w.frozen for w in self.winches], dtype=bool)

    @property
    def diameter(self) -> float:
        """Body diameter (largest distance between two body points), length units."""
        return diameter(self.outline if self.outline is not None else self.nodes)

    @property
    def tolerance(self) -> float:
        """Distance below which two points are the same node: 1e-9 x diameter."""
        return POINT_TOL * self.diameter

    def replace(self, **changes) -> "Scene":
        return dataclasses.replace(self, **changes)

    def __eq__(self, other):
        if not isinstance(other, Scene):
            return NotImplemented
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if f.name == "holes":
                if len(a) != len(b) or not all(np.array_equal(p, q) for p, q in zip(a, b)):
                    return False
            elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or not np.array_equal(a, b):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None


# ---------------------------------------------------------------------------
# Reading the YAML
# ---------------------------------------------------------------------------

class _YamlRefused(yaml.YAMLError):
    """A YAML feature the problem format does not allow (aliases, merges)."""

    def __init__(self, message, mark=None):
        super().__init__(message)
        self.message = message
        self.mark = mark


# A float with an exponent, as YAML 1.2 and JSON write it.
_FLOAT_12 = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$")


class _Resolver(yaml.resolver.Resolver):
    """YAML 1.1 (PyYAML) reads 1e-9 and 2.0e11 as strings; users mean numbers."""


_Resolver.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789."))


class _Guard:
    """Refuses anchors and aliases (so no "billion laughs"), merge keys and
    duplicate keys while composing and constructing."""

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            raise _YamlRefused(f"alias *{event.anchor} (anchors and aliases are not allowed)",
                               event.start_mark)
        if getattr(event, "anchor", None) is not None:
            raise _YamlRefused(f"anchor &{event.anchor} (anchors and aliases are not allowed)",
                               event.start_mark)
        return super().compose_node(parent, index)

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                raise _YamlRefused("merge key '<<' is not allowed", key_node.start_mark)
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:
                raise _YamlRefused("a mapping key must be a plain value", key_node.start_mark)
            if duplicate:
                raise _YamlRefused(f"duplicate key {key!r}", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)

    def construct_object(self, node, deep=False):
        # an explicit tag with a value it cannot hold (!!float abc, !!bool
        # maybe, ...) makes PyYAML's constructors raise plain exceptions
        try:
            return super().construct_object(node, deep=deep)
        except (ValueError, TypeError, KeyError, AttributeError, OverflowError):
            raise _YamlRefused(f"bad {node.tag} value {node.value!r}"
                               if isinstance(node, yaml.ScalarNode) else f"bad {node.tag} value",
                               node.start_mark) from None


class _Loader(_Guard, yaml.reader.Reader, yaml.scanner.Scanner, yaml.parser.Parser,
              yaml.composer.Composer, yaml.constructor.SafeConstructor, _Resolver):
    """Pure-Python safe loader with the guards."""

    def __init__(self, stream):
        yaml.reader.Reader.__init__(self, stream)
        yaml.scanner.Scanner.__init__(self)
        yaml.parser.Parser.__init__(self)
        yaml.composer.Composer.__init__(self)
        yaml.constructor.SafeConstructor.__init__(self)
        _Resolver.__init__(self)


try:
    from yaml._yaml import CParser as _CParser
except ImportError:                      # PyYAML built without libyaml
    _CParser = None
else:
    class _CLoader(_Guard, yaml.composer.Composer, _CParser, yaml.constructor.SafeConstructor,
                   _Resolver):
        """libyaml scans and parses (fast); composing stays in Python so the
        guards see every event."""

        def __init__(self, stream):
            _CParser.__init__(self, stream)
            yaml.composer.Composer.__init__(self)
            yaml.constructor.SafeConstructor.__init__(self)
            _Resolver.__init__(self)


def _duplicate_key_path(node) -> str | None:
    """Key path of the first duplicate key in a composed YAML tree, if any."""
    stack = [(node, "")]
    while stack:
        node, path = stack.pop()
        if isinstance(node, yaml.MappingNode):
            seen, children = {}, []
            for key_node, value_node in node.value:
                if isinstance(key_node, yaml.ScalarNode):
                    key = (key_node.tag, key_node.value)
                    sub = _key(path, key_node.value)
                    if key in seen:
                        return (f"line {key_node.start_mark.line + 1}: {sub}: duplicate key "
                                f"(first on line {seen[key] + 1})")
                    seen[key] = key_node.start_mark.line
                    children.append((value_node, sub))
            stack.extend(reversed(children))       # visit in document order
        elif isinstance(node, yaml.SequenceNode):
            stack.extend(reversed([(v, _idx(path, i)) for i, v in enumerate(node.value)]))
    return None


def _parse_yaml(text: str, source: str):
    loader = (_Loader if _CParser is None else _CLoader)(text)
    try:
        node = loader.get_single_node()
        if node is None:
            raise SceneError(f"{source}: the file is empty")
        dup = _duplicate_key_path(node)
        if dup is not None:
            raise SceneError(f"{source}: {dup}")
        return loader.construct_document(node)
    except _YamlRefused as exc:
        line = f"line {exc.mark.line + 1}: " if exc.mark is not None else ""
        raise SceneError(f"{source}: {line}{exc.message}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = f"line {mark.line + 1}: " if mark is not None else ""
        what = " ".join(p for p in (exc.context, exc.problem) if p)
        raise SceneError(f"{source}: {line}invalid YAML: {what}") from None
    except yaml.YAMLError as exc:
        raise SceneError(f"{source}: YAML error: {exc}") from None
    except RecursionError:
        raise SceneError(f"{source}: the YAML is nested too deeply") from None
    except SceneError:
        raise
    except (ValueError, TypeError, KeyError, AttributeError, OverflowError) as exc:
        raise SceneError(f"{source}: YAML value not understood: {exc}") from None
    finally:
        loader.dispose()


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
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise SceneError(f"{source}: no such file ({os.fspath(path)})") from None
    except IsADirectoryError:
        raise SceneError(f"{source}: is a directory, not a problem file") from None
    except OSError as exc:
        raise SceneError(f"{source}: cannot read: {exc.strerror or exc}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise SceneError(f"{source}: file larger than {MAX_FILE_BYTES} bytes (1 MiB); "
                         "not a problem file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(f"{source}: not UTF-8 text (byte {exc.start})") from None
    return scene_from_dict(_parse_yaml(text, source), source)


# ---------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------

def _key(path: str, key) -> str:
    return f"{path}.{key}" if path else str(key)


def _idx(path: str, i: int) -> str:
    return f"{path}[{i}]"


def _describe(v) -> str:
    if v is None:
        return "null"
    if isinstance(v, (bool, np.bool_)):
        return f"boolean {str(bool(v)).lower()}"
    if isinstance(v, str):
        s = v if len(v) <= 40 else v[:37] + "..."
        return f"string {s!r}"
    if isinstance(v, numbers.Number):
        return f"number {v!r}"
    if isinstance(v, dict):
        return "a mapping"
    if isinstance(v, (list, tuple, np.ndarray)):
        return f"a list of {len(v)}"
    return f"a {type(v).__name__}"


def _fmt(x: float) -> str:
    return repr(float(x))


def _fmt_point(p) -> str:
    return f"({_fmt(p[0])}, {_fmt(p[1])})"


_NAME = re.compile(r"[A-Za-z0-9_-]+")

_TOP_KEYS = ("format", "name", "description", "mesh", "material", "gravity", "pins",
             "winches", "tendons", "targets", "points")
_MESH_KEYS = ("outline", "holes", "max_area", "min_angle", "nodes", "triangles")
_MATERIAL_KEYS = ("model", "youngs_modulus", "poisson_ratio", "mu", "lambda", "thickness",
                  "density")
_PIN_KEYS = ("stiffness", "at", "box")
_WINCH_KEYS = ("name", "bounds", "contraction", "frozen")
_TENDONS_KEYS = ("stiffness", "smoothing", "list")
_TENDON_KEYS = ("name", "winch", "path")
_TARGET_KEYS = ("at", "to", "weight")


class _Check:
    """Validation helpers bound to one source name; every failure raises."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, path: str, message: str):
        where = f"{path}: " if path else ""
        raise SceneError(f"{self.source}: {where}{message}")

    # -- structure --------------------------------------------------------
    def mapping(self, value, path, allowed, required=()):
        if not isinstance(value, dict):
            self.fail(path, f"expected a mapping, got {_describe(value)}")
        for k in value:
            if not isinstance(k, str) or k not in allowed:
                hint = difflib.get_close_matches(str(k), allowed, n=1)
                hint = f" (did you mean '{hint[0]}'?)" if hint else ""
                self.fail(_key(path, k), f"unknown key{hint}; allowed keys: {', '.join(allowed)}")
        for k in required:
            if k not in value:
                self.fail(_key(path, k), "missing required key")
            if value[k] is None:
                self.fail(_key(path, k), "required key has no value")
        return value

    def seq(self, value, path, *, min_len=0, what="list"):
        if isinstance(value, np.ndarray):
            value = list(value)
        if not isinstance(value, (list, tuple)):
            self.fail(path, f"expected a {what}, got {_describe(value)}")
        if len(value) < min_len:
            if len(value) == 0:
                self.fail(path, f"empty list; at least {min_len} required")
            self.fail(path, f"expected at least {min_len} entries, got {len(value)}")
        return value

    def string(self, value, path) -> str:
        if not isinstance(value, str):
            scalar = value is not None and not isinstance(value, (dict, list, tuple))
            hint = " (put it in quotes to make it a string)" if scalar else ""
            self.fail(path, f"expected a string, got {_describe(value)}{hint}")
        return value

    def number(self, value, path, *, gt=None, ge=None, lt=None) -> float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            self.fail(path, f"expected a number, got {_describe(value)}")
        try:
            x = float(value)
        except (OverflowError, ValueError, TypeError):
            self.fail(path, f"expected a finite number, got {_describe(value)}")
        if not math.isfinite(x):
            self.fail(path, f"expected a finite number, got {x!r}")
        if gt is not None and not x > gt:
            self.fail(path, f"must be > {gt:g}, got {_fmt(x)}")
        if ge is not None and not x >= ge:
            self.fail(path, f"must be >= {ge:g}, got {_fmt(x)}")
        if lt is not None and not x < lt:
            self.fail(path, f"must be < {lt:g}, got {_fmt(x)}")
        return x

    def integer(self, value, path) -> int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
            self.fail(path, f"expected an integer, got {_describe(value)}")
        return int(value)

    def boolean(self, value, path) -> bool:
        if not isinstance(value, (bool, np.bool_)):
            self.fail(path, f"expected true or false, got {_describe(value)}")
        return bool(value)

    def point(self, value, path) -> tuple[float, float]:
        if isinstance(value, np.ndarray):
            value = list(value)
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            self.fail(path, f"expected a point [x, y], got {_describe(value)}")
        xy = (self.number(value[0], _idx(path, 0)), self.number(value[1], _idx(path, 1)))
        for i, v in enumerate(xy):
            if abs(v) > MAX_COORD:
                self.fail(_idx(path, i), f"{_fmt(v)} is too large (coordinates are limited to "
                          f"{MAX_COORD:g} in magnitude)")
        return xy

    def points(self, value, path, *, min_len=1) -> np.ndarray:
        value = self.seq(value, path, min_len=min_len, what="list of points [[x, y], ...]")
        pts = [self.point(p, _idx(path, i)) for i, p in enumerate(value)]
        return np.array(pts, dtype=np.float64).reshape(-1, 2)

    def name(self, value, path) -> str:
        s = self.string(value, path)
        if not s.strip():
            self.fail(path, "empty name")
        return s


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
    ck = _Check(source)
    if not isinstance(data, dict):
        ck.fail("", f"the document must be a mapping of keys, got {_describe(data)}")
    ck.mapping(data, "", _TOP_KEYS,
               required=("format", "name", "mesh", "material", "pins", "winches", "tendons"))

    fmt = ck.string(data["format"], "format")
    if fmt != FORMAT:
        ck.fail("format", f"expected exactly '{FORMAT}', got {fmt!r}")
    name = ck.string(data["name"], "name")
    if not _NAME.fullmatch(name):
        ck.fail("name", f"{name!r} must match [A-Za-z0-9_-]+")
    description = _opt(data, "description")
    description = "" if description is None else ck.string(description, "description")

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

    targets = []
    raw_targets = _opt(data, "targets")
    if raw_targets is not None:
        for i, t in enumerate(ck.seq(raw_targets, "targets", what="list of targets")):
            path = _idx("targets", i)
            ck.mapping(t, path, _TARGET_KEYS, required=("at", "to"))
            weight = _opt(t, "weight")
            weight = 1.0 if weight is None else ck.number(weight, _key(path, "weight"), gt=0)
            targets.append(Target(at=ck.point(t["at"], _key(path, "at")),
                                  to=ck.point(t["to"], _key(path, "to")), weight=weight))

    raw_points = _opt(data, "points")
    points = np.zeros((0, 2)) if raw_points is None else ck.points(raw_points, "points", min_len=0)

    # -- geometry of the points against the body --------------------------
    tol = POINT_TOL * geo["diameter"]
    forced = [("pins.at", pin_points)]
    forced += [(_key(_idx("tendons.list", i), "path"), t.path) for i, t in enumerate(tendons)]
    forced += [("points", points)]
    for i, t in enumerate(tendons):
        step = np.hypot(*np.diff(t.path, axis=0).T)
        bad = np.flatnonzero(step <= tol)
        if bad.size:
            j = int(bad[0]) + 1
            ck.fail(_idx(_key(_idx("tendons.list", i), "path"), j),
                    f"point {_fmt_point(t.path[j])} repeats the previous via point (closer "
                    f"than {tol:.3g} = 1e-9 x body diameter); consecutive via points must be "
                    "distinct")
    if geo["nodes"] is not None:
        _check_points_are_nodes(ck, geo["nodes"], forced, tol)
        tri_pts = geo["nodes"][geo["triangles"]]
        for i, t in enumerate(targets):
            tri, _ = locate_in_triangles(tri_pts, t.at[None, :], tol)
            if tri[0] < 0:
                ck.fail(_key(_idx("targets", i), "at"),
                        f"point {_fmt_point(t.at)} lies outside the body")
    else:
        rings = [geo["outline"], *geo["holes"]]
        at = np.array([t.at for t in targets]).reshape(-1, 2)
        for key, pts in forced + [("targets", at)]:
            where = classify_points(pts, rings, tol)
            bad = np.flatnonzero(where < 0)
            if bad.size:
                j = int(bad[0])
                path = _key(_idx(key, j), "at") if key == "targets" else _idx(key, j)
                ck.fail(path, f"point {_fmt_point(pts[j])} lies outside the body")

    return Scene(
        name=name, description=description, source=source, material=material,
        pin_stiffness=pin_stiffness, pin_points=pin_points, pin_box=pin_box,
        winches=tuple(winches), tendon_stiffness=t_stiffness, tendon_smoothing=t_smoothing,
        tendons=tuple(tendons), targets=tuple(targets), points=points, gravity=gravity,
        outline=geo["outline"], holes=tuple(geo["holes"]), max_area=geo["max_area"],
        min_angle=geo["min_angle"], nodes=geo["nodes"], triangles=geo["triangles"],
    )


def _mesh_section(ck: _Check, mesh) -> dict:
    ck.mapping(mesh, "mesh", _MESH_KEYS)
    has = {k for k in _MESH_KEYS if mesh.get(k) is not None}
    out = dict(outline=None, holes=[], max_area=None, min_angle=None, nodes=None,
               triangles=None)
    if "outline" in has:
        for k in ("nodes", "triangles"):
            if k in has:
                ck.fail(_key("mesh", k), "give either mesh.outline or mesh.nodes + "
                        "mesh.triangles, not both")
        outline = ck.points(mesh["outline"], "mesh.outline", min_len=3)
        _check_ring(ck, outline, "mesh.outline")
        holes = []
        if "holes" in has:
            for i, h in enumerate(ck.seq(mesh["holes"], "mesh.holes", what="list of polygons")):
                hp = _idx("mesh.holes", i)
                hole = ck.points(h, hp, min_len=3)
                _check_ring(ck, hole, hp)
                holes.append(hole)
        out.update(outline=outline, holes=holes, diameter=diameter(outline))
        _check_ring_layout(ck, outline, holes, POINT_TOL * out["diameter"])
        if "max_area" in has:
            out["max_area"] = ck.number(mesh["max_area"], "mesh.max_area", gt=0)
        if "min_angle" in has:
            a = ck.number(mesh["min_angle"], "mesh.min_angle", ge=0)
            if a > MAX_MIN_ANGLE:
                ck.fail("mesh.min_angle", f"must be <= {MAX_MIN_ANGLE:g} degrees (the mesher "
                        f"may not terminate above), got {_fmt(a)}")
            out["min_angle"] = a
        return out
    if "nodes" not in has and "triangles" not in has:
        ck.fail("mesh", "give mesh.outline, or mesh.nodes and mesh.triangles")
    for k in ("nodes", "triangles"):
        if k not in has:
            other = "triangles" if k == "nodes" else "nodes"
            ck.fail(_key("mesh", k), f"required with mesh.{other}")
    for k in ("holes", "max_area", "min_angle"):
        if k in has:
            ck.fail(_key("mesh", k), "only allowed with mesh.outline")
    nodes = ck.points(mesh["nodes"], "mesh.nodes", min_len=3)
    raw = ck.seq(mesh["triangles"], "mesh.triangles", min_len=1, what="list of triangles")
    tris = np.empty((len(raw), 3), dtype=np.int64)
    n_nodes = len(nodes)
    for e, t in enumerate(raw):
        p = _idx("mesh.triangles", e)
        if isinstance(t, np.ndarray):
            t = list(t)
        if not isinstance(t, (list, tuple)) or len(t) != 3:
            ck.fail(p, f"expected three node indices [i, j, k], got {_describe(t)}")
        for c, v in enumerate(t):
            iv = ck.integer(v, _idx(p, c))
            if not 0 <= iv < n_nodes:
                ck.fail(_idx(p, c), f"node index {iv} out of range 0..{n_nodes - 1}")
            tris[e, c] = iv
    _check_explicit_mesh(ck, nodes, tris)
    out.update(nodes=nodes, triangles=tris, diameter=diameter(nodes))
    return out


def _check_explicit_mesh(ck: _Check, nodes: np.ndarray, tris: np.ndarray):
    p = nodes[tris]
    d1, d2, d3 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 2] - p[:, 1]
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    longest = np.max([np.einsum("ij,ij->i", d, d) for d in (d1, d2, d3)], axis=0)
    degenerate = np.abs(cross) <= 1e-12 * longest
    degenerate |= (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
    if degenerate.any():
        e = int(np.flatnonzero(degenerate)[0])
        ck.fail(_idx("mesh.triangles", e), f"degenerate triangle {tris[e].tolist()} "
                "(zero area)")
    key = np.sort(tris, axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    dup = np.flatnonzero(first[inverse] != np.arange(len(tris)))
    if dup.size:
        e = int(dup[0])
        ck.fail(_idx("mesh.triangles", e), f"duplicate of mesh.triangles[{int(first[inverse[e]])}]")
    used = np.zeros(len(nodes), dtype=bool)
    used[tris.reshape(-1)] = True
    if not used.all():
        i = int(np.flatnonzero(~used)[0])
        ck.fail(_idx("mesh.nodes", i), "node is not used by any triangle")
    tol = POINT_TOL * diameter(nodes)
    pairs = cKDTree(nodes).query_pairs(tol, output_type="ndarray")
    if len(pairs):
        i, j = sorted(map(int, pairs[np.lexsort((pairs[:, 0], pairs[:, 1]))][0]))
        ck.fail(_idx("mesh.nodes", j), f"coincides with mesh.nodes[{i}]")


def _check_points_are_nodes(ck: _Check, nodes, forced, tol):
    tree = cKDTree(nodes)
    for key, pts in forced:
        if len(pts) == 0:
            continue
        dist, near = tree.query(pts)
        bad = np.flatnonzero(dist > tol)
        if bad.size:
            j = int(bad[0])
            ck.fail(_idx(key, j), f"point {_fmt_point(pts[j])} is not a node of the explicit "
                    f"mesh (nearest is mesh.nodes[{int(near[j])}] at distance {dist[j]:.3g})")


def _material_section(ck: _Check, mat) -> Material:
    ck.mapping(mat, "material", _MATERIAL_KEYS, required=("model", "thickness"))
    model = ck.string(mat["model"], "material.model")
    if model != "neo_hookean":
        ck.fail("material.model", f"unknown model {model!r}; version 1 has only 'neo_hookean'")
    has = {k for k in _MATERIAL_KEYS if mat.get(k) is not None}
    e_form = has & {"youngs_modulus", "poisson_ratio"}
    l_form = has & {"mu", "lambda"}
    if e_form and l_form:
        ck.fail(_key("material", sorted(l_form)[0]),
                "give either youngs_modulus and poisson_ratio, or mu and lambda, not both")
    if e_form:
        for k in ("youngs_modulus", "poisson_ratio"):
            if k not in has:
                ck.fail(_key("material", k), "required with material."
                        + ({"youngs_modulus", "poisson_ratio"} - {k}).pop())
        E = ck.number(mat["youngs_modulus"], "material.youngs_modulus", gt=0)
        nu = ck.number(mat["poisson_ratio"], "material.poisson_ratio", ge=0, lt=0.5)
        mu = E / (2.0 * (1.0 + nu))
        lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    elif l_form:
        for k in ("mu", "lambda"):
            if k not in has:
                ck.fail(_key("material", k), "required with material."
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


def _pins_section(ck: _Check, pins):
    ck.mapping(pins, "pins", _PIN_KEYS, required=("stiffness",))
    stiffness = ck.number(pins["stiffness"], "pins.stiffness", gt=0)
    box = _opt(pins, "box")
    if box is not None:
        if isinstance(box, np.ndarray):
            box = list(box)
        if not isinstance(box, (list, tuple)) or len(box) != 4:
            ck.fail("pins.box", f"expected [xmin, ymin, xmax, ymax], got {_describe(box)}")
        box = np.array([ck.number(v, _idx("pins.box", i)) for i, v in enumerate(box)])
        big = np.flatnonzero(np.abs(box) > MAX_COORD)
        if big.size:
            ck.fail(_idx("pins.box", int(big[0])), f"{_fmt(box[big[0]])} is too large "
                    f"(coordinates are limited to {MAX_COORD:g} in magnitude)")
        if box[0] > box[2]:
            ck.fail("pins.box", f"xmin {_fmt(box[0])} > xmax {_fmt(box[2])}")
        if box[1] > box[3]:
            ck.fail("pins.box", f"ymin {_fmt(box[1])} > ymax {_fmt(box[3])}")
    at = _opt(pins, "at")
    if at is None:
        if box is None:
            ck.fail("pins", "no pins: give pins.at or pins.box")
        at = np.zeros((0, 2))
    else:
        at = ck.points(at, "pins.at", min_len=0 if box is not None else 1)
    return stiffness, at, box


def _winches_section(ck: _Check, raw) -> list[Winch]:
    winches, seen = [], {}
    for i, w in enumerate(ck.seq(raw, "winches", min_len=1, what="list of winches")):
        path = _idx("winches", i)
        ck.mapping(w, path, _WINCH_KEYS, required=("name", "bounds"))
        name = ck.name(w["name"], _key(path, "name"))
        if name in seen:
            ck.fail(_key(path, "name"), f"duplicate name {name!r} (also winches[{seen[name]}])")
        seen[name] = i
        b = w["bounds"]
        if isinstance(b, np.ndarray):
            b = list(b)
        if not isinstance(b, (list, tuple)) or len(b) != 2:
            ck.fail(_key(path, "bounds"), f"expected [lower, upper], got {_describe(b)}")
        lo = ck.number(b[0], _idx(_key(path, "bounds"), 0))
        hi = ck.number(b[1], _idx(_key(path, "bounds"), 1))
        if not lo < hi:
            ck.fail(_key(path, "bounds"), f"lower {_fmt(lo)} must be < upper {_fmt(hi)}")
        c = _opt(w, "contraction")
        if c is None:
            c = min(max(0.0, lo), hi)
        else:
            c = ck.number(c, _key(path, "contraction"))
            if not lo <= c <= hi:
                ck.fail(_key(path, "contraction"),
                        f"{_fmt(c)} is outside bounds [{_fmt(lo)}, {_fmt(hi)}]")
        frozen = _opt(w, "frozen")
        frozen = False if frozen is None else ck.boolean(frozen, _key(path, "frozen"))
        winches.append(Winch(name=name, bounds=(lo, hi), contraction=c, frozen=frozen))
    return winches


def _tendons_section(ck: _Check, raw, winches):
    ck.mapping(raw, "tendons", _TENDONS_KEYS, required=("stiffness", "smoothing", "list"))
    stiffness = ck.number(raw["stiffness"], "tendons.stiffness", gt=0)
    smoothing = ck.number(raw["smoothing"], "tendons.smoothing", gt=0)
    winch_index = {w.name: i for i, w in enumerate(winches)}
    used = set()
    tendons, seen = [], {}
    for i, t in enumerate(ck.seq(raw["list"], "tendons.list", min_len=1, what="list of tendons")):
        path = _idx("tendons.list", i)
        ck.mapping(t, path, _TENDON_KEYS, required=("name", "winch", "path"))
        name = ck.name(t["name"], _key(path, "name"))
        if name in seen:
            ck.fail(_key(path, "name"),
                    f"duplicate name {name!r} (also tendons.list[{seen[name]}])")
        seen[name] = i
        winch = ck.name(t["winch"], _key(path, "winch"))
        if winch not in winch_index:
            ck.fail(_key(path, "winch"), f"no winch named {winch!r} (winches: "
                    f"{', '.join(repr(w.name) for w in winches)})")
        used.add(winch)
        via = ck.points(t["path"], _key(path, "path"), min_len=2)
        tendons.append(Tendon(name=name, winch=winch, path=via))
    for i, w in enumerate(winches):
        if w.name not in used:
            ck.fail(_idx("winches", i), f"winch {w.name!r} has no tendons")
    return stiffness, smoothing, tendons


# ---------------------------------------------------------------------------
# Plane geometry (shared with mesh.py)
# ---------------------------------------------------------------------------

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


def _check_ring(ck: _Check, ring: np.ndarray, path: str):
    """A simple polygon: no repeated consecutive points, no backtracking,
    no crossings or touchings, nonzero area."""
    nxt = np.roll(ring, -1, axis=0)
    same = np.all(ring == nxt, axis=1)
    if same.any():
        i = int(np.flatnonzero(same)[0])
        j = (i + 1) % len(ring)
        if j == 0:
            ck.fail(_idx(path, len(ring) - 1), "repeats the first point; do not close the "
                    "polygon, it is closed implicitly")
        ck.fail(_idx(path, j), f"point {_fmt_point(ring[j])} repeats the previous point")
    d = nxt - ring
    d_next = np.roll(d, -1, axis=0)
    cross = d[:, 0] * d_next[:, 1] - d[:, 1] * d_next[:, 0]
    dot = np.einsum("ij,ij->i", d, d_next)
    back = (cross == 0) & (dot < 0)
    if back.any():
        i = (int(np.flatnonzero(back)[0]) + 1) % len(ring)
        ck.fail(_idx(path, i), f"the polygon turns back on itself at {_fmt_point(ring[i])}")
    hit = find_crossing([ring])
    if hit is not None:
        (_, a), (_, b) = hit
        ck.fail(path, f"not a simple polygon: edge {a} (from point {a}) crosses or touches "
                f"edge {b} (from point {b})")
    area = abs(ring_area(ring))
    if not area > 1e-12 * float(np.sum(np.ptp(ring, axis=0) ** 2)):
        ck.fail(path, "polygon has zero area")


def _check_ring_layout(ck: _Check, outline: np.ndarray, holes: list, tol: float):
    """Holes strictly inside the outline and disjoint from each other."""
    if not holes:
        return
    rings = [outline, *holes]
    hit = find_crossing(rings)
    if hit is not None:
        (ra, _), (rb, _) = sorted(hit)
        other = "the outline" if ra == 0 else f"mesh.holes[{ra - 1}]"
        ck.fail(_idx("mesh.holes", rb - 1), f"crosses or touches {other}")
    # no edges cross, so one vertex tells where a whole hole lies
    first = np.array([h[0] for h in holes])
    where = classify_points(first, [outline], tol)
    for i in range(len(holes)):
        if where[i] == 0:
            ck.fail(_idx("mesh.holes", i), "touches the outline (holes must be strictly inside)")
        if where[i] < 0:
            ck.fail(_idx("mesh.holes", i), "lies outside the outline (holes must be strictly "
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
                ck.fail(_idx("mesh.holes", i), f"{what} mesh.holes[{int(j)}]")


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
                hit = _segments_touch(a[i], b[i], a[j], b[j])
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


def _segments_touch(a, b, c, d):
    """Closed segments ab and cd share a point (bounding boxes known to overlap)."""
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


def barycentric(tri_pts: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric weights of every point in every triangle, (m, n_elems, 3)."""
    a, b, c = tri_pts[:, 0], tri_pts[:, 1], tri_pts[:, 2]
    v0, v1 = b - a, c - a
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    w = points[:, None, :] - a[None]
    l1 = (w[..., 0] * v1[None, :, 1] - w[..., 1] * v1[None, :, 0]) / det[None]
    l2 = (v0[None, :, 0] * w[..., 1] - v0[None, :, 1] * w[..., 0]) / det[None]
    return np.stack([1.0 - l1 - l2, l1, l2], axis=-1)


def locate_in_triangles(tri_pts: np.ndarray, points: np.ndarray, tol: float = 0.0,
                        chunk=1 << 18):
    """Triangle holding each point and its barycentric weights.

    Parameters
    ----------
    tri_pts : (n_elems, 3, 2) triangle corner coordinates.
    points : (m, 2) query points.
    tol : distance tolerance (length units) for points on or just outside an edge.

    Returns
    -------
    tri : (m,) int64, index of the triangle (-1 if none is within ``tol``);
        among several (a point on an edge), the one where the point lies
        deepest inside (largest smallest weight), lowest index on ties.
    beta : (m, 3) float64 weights in that triangle's corner order (NaN if none).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    m, n = len(points), len(tri_pts)
    tri = np.full(m, -1, dtype=np.int64)
    beta = np.full((m, 3), np.nan)
    if n == 0 or m == 0:
        return tri, beta
    # scale the distance tolerance to barycentric units: weight ~ distance / height
    e = np.stack([tri_pts[:, 1] - tri_pts[:, 0], tri_pts[:, 2] - tri_pts[:, 1],
                  tri_pts[:, 0] - tri_pts[:, 2]], axis=1)
    area2 = np.abs(e[:, 0, 0] * e[:, 2, 1] - e[:, 0, 1] * e[:, 2, 0])
    longest = np.sqrt(np.max(np.einsum("ekj,ekj->ek", e, e), axis=1))
    wtol = tol * longest / area2 + 1e-12     # distance tol / smallest height
    step = max(1, chunk // n)
    for s in range(0, m, step):
        bw = barycentric(tri_pts, points[s:s + step])
        depth = np.min(bw, axis=2)
        score = np.where(depth >= -wtol[None], depth, -np.inf)
        k = np.argmax(score, axis=1)
        rows = np.arange(len(k))
        ok = np.isfinite(score[rows, k])
        tri[s:s + step] = np.where(ok, k, -1)
        beta[s:s + step] = np.where(ok[:, None], bw[rows, k], np.nan)
    return tri, beta
