"""The validated, immutable :class:`Scene` of a problem and its parts.

A scene holds what a problem file (format ``plush-opt/1``,
docs/problem-format.md) says and nothing derived from a mesh; the mesh
and the model are built from it (``mesh.build_mesh``,
``model.build_model``), never the other way round. Files are read and
checked by :func:`plush_opt.io.load_scene`.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field

import numpy as np

from ..base.geometry import diameter
from .units import DEFAULT_UNITS, Units

FORMAT = "plush-opt/1"
ELEMENTS = ("P1", "P2")          # mesh.element: 3-node or 6-node (quadratic) triangles
# nodes per row of an explicit mesh's triangles, by the file's mesh.element
# (the element types themselves are plush_opt.fem.elements, a layer above)
NODES_PER_TRIANGLE = {"P1": 3, "P2": 6}
POINT_TOL = 1e-9                  # coincidence tolerance, relative to the body diameter


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
    """A tendon routed through via points, stopper end first, winch end last.

    ``assembly_offset`` d (length units) adds to the assembly length:
    a = l(X) + d (negative: tied taut at rest; positive: slack).
    ``attachment_radius`` r (length units): with r > 0 each via point is the
    average of the body over the disc of radius r around it (a stopper or a
    felt hole spreads the pull); 0 is the single node.
    ``friction`` mu >= 0 is the capstan friction coefficient at its interior
    via points (0: the tendon slides freely, one spring).
    """

    name: str
    winch: str
    path: np.ndarray  # (n_via, 2) rest coordinates
    assembly_offset: float = 0.0
    attachment_radius: float = 0.0
    friction: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "path", _points(self.path))

    def __eq__(self, other):
        return (isinstance(other, Tendon) and self.name == other.name
                and self.winch == other.winch and np.array_equal(self.path, other.path)
                and self.assembly_offset == other.assembly_offset
                and self.attachment_radius == other.attachment_radius
                and self.friction == other.friction)

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
class Ground:
    """The floor: the line through (0, ``height``) at ``slope`` degrees
    (counter-clockwise); the body stays on its upper side."""

    height: float = 0.0
    slope: float = 0.0

    @property
    def normal(self) -> np.ndarray:
        """(2,) unit normal pointing to the upper (admissible) side."""
        a = np.radians(self.slope)
        return np.array([-np.sin(a), np.cos(a)])

    @property
    def tangent(self) -> np.ndarray:
        """(2,) unit direction along the floor (its x-ward direction)."""
        a = np.radians(self.slope)
        return np.array([np.cos(a), np.sin(a)])


@dataclass(frozen=True, eq=False)
class Obstacle:
    """A rigid polygon fixed in space: ``outline`` (k, 2), a simple polygon."""

    name: str
    outline: np.ndarray

    def __eq__(self, other):
        return (isinstance(other, Obstacle) and self.name == other.name
                and np.array_equal(self.outline, other.outline))

    __hash__ = None


@dataclass(frozen=True)
class Contact:
    """The scene's contact section (docs/problem-format.md, "Contact").

    ``distance`` d_hat > 0: the gap below which the barrier pushes;
    ``stiffness`` kappa (None: chosen by the model); ``friction`` the
    Coulomb coefficient against ground and obstacles."""

    ground: Ground | None = None
    obstacles: tuple[Obstacle, ...] = ()
    self_contact: bool = False
    distance: float = 1.0
    stiffness: float | None = None
    friction: float = 0.0


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
    triangles: np.ndarray | None = None  # (n_elems, 3 or 6) explicit mesh, as given
    gravity: np.ndarray | None = None  # (2,)
    pin_box: np.ndarray | None = None  # (4,) xmin, ymin, xmax, ymax
    targets: tuple[Target, ...] = ()
    points: np.ndarray = field(default_factory=lambda: _points(np.zeros((0, 2))))
    element: str = "P1"               # "P1" (3-node) or "P2" (6-node triangles)
    contact: Contact | None = None     # floor, obstacles, self-contact
    units: Units = DEFAULT_UNITS       # the file's unit names (labels for outputs, never conversions)

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
            tri = np.ascontiguousarray(np.asarray(self.triangles, dtype=np.int64).reshape(
                -1, NODES_PER_TRIANGLE[self.element]))
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

    @functools.cached_property
    def diameter(self) -> float:
        """Body diameter (largest distance between two body points), length
        units; computed once per scene (``tolerance`` asks for it often)."""
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
