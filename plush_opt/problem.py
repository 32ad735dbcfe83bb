"""A problem, built once: the scene read from its file, its mesh, its
energy model and its targets, with the solvers that own their caches.

Every app starts here (``load(path)`` or ``from_scene(scene)``) instead of
repeating the pipeline ``scene -> mesh -> model -> targets``.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from .solve.equilibrium import Equilibrium, EquilibriumOptions
from .base.errors import SceneError
from .io import load_scene
from .fem.contact import rest_pushes
from .fem.mesh import Mesh, build_mesh
from .fem.model import Model, build_model
from .fem.objective import Targets
from .io.scene import Scene

log = logging.getLogger("plush_opt")

#: what a bad target given to :meth:`Problem.with_targets` is reported as coming from
WITH_TARGETS = "with_targets"


class Problem:
    """Scene, mesh, model and targets of one problem file.

    Attributes
    ----------
    scene : the validated :class:`~plush_opt.io.scene.Scene`.
    mesh : its :class:`~plush_opt.fem.mesh.Mesh`.
    model : the energy :class:`~plush_opt.fem.model.Model` on that mesh.
    targets : the file's targets on that mesh (possibly none).
    mesh_report : how the mesh was chosen for an accuracy, or None.
    """

    def __init__(self, scene: Scene, mesh: Mesh, model: Model, targets: Targets,
                 mesh_report: dict | None = None):
        self._scene, self._mesh, self._model, self._targets = scene, mesh, model, targets
        self._mesh_report = mesh_report
        self._bilevel = None     # the bilevel solver keeps its built NLPs: made on first use
        self._plant = None       # the forward model with its history: made on first use

    scene = property(lambda self: self._scene)
    mesh = property(lambda self: self._mesh)
    model = property(lambda self: self._model)
    targets = property(lambda self: self._targets)
    mesh_report = property(lambda self: self._mesh_report)

    def __repr__(self) -> str:
        return (f"Problem({self.scene.name!r}, {self.mesh.n_nodes} nodes, "
                f"{self.model.n_winches} winches, {self.targets.n_targets} targets)")

    @property
    def winch_names(self) -> tuple[str, ...]:
        return self.model.winch_names

    @property
    def source(self) -> str:
        return self.scene.source

    # -- contractions and frozen sets by name ------------------------------

    def contraction_vector(self, contraction: Mapping[str, float] | None = None,
                           start=None, what: str = "contraction") -> np.ndarray:
        """(n_winches,) contractions: ``start`` (default the scene's) with
        the named values replaced. Unknown names and values outside the
        bounds are a :class:`SceneError` naming the winch (``what`` names
        where the value came from, e.g. ``--contraction``)."""
        names = self.winch_names
        c = (self.scene.contraction if start is None else np.asarray(start, dtype=np.float64)).copy()
        for name, value in (contraction or {}).items():
            value = float(value)
            if name not in names:
                raise SceneError(f"{what} {name}={value:g}: no winch named {name!r} "
                                 f"(winches: {', '.join(names)})")
            i = names.index(name)
            lo, hi = self.model.lower[i], self.model.upper[i]
            if not lo <= value <= hi:
                raise SceneError(f"{what} {name}={value:g}: outside the winch's bounds [{lo:g}, {hi:g}]")
            c[i] = value
        return c

    def frozen_vector(self, names: Iterable[str] | None = None, what: str = "frozen") -> np.ndarray:
        """(n_winches,) bool: the scene's frozen flags, plus ``names``."""
        frozen = self.scene.frozen.copy()
        for name in names or ():
            if name not in self.winch_names:
                raise SceneError(f"{what} {name}: no winch named {name!r} "
                                 f"(winches: {', '.join(self.winch_names)})")
            frozen[self.winch_names.index(name)] = True
        return frozen

    # -- solving -------------------------------------------------------------

    def equilibrium(self, contraction: Mapping[str, float] | None = None, x0=None,
                    options: EquilibriumOptions | None = None, steps: int | None = None) -> Equilibrium:
        """The equilibrium at these contractions (by winch name; the others
        at the scene's values), reached from the scene's start state by the
        :attr:`plant` (:meth:`~plush_opt.solve.plant.Plant.equilibrium`):
        from ``x0`` (default the rest pose) where the pose does not depend
        on the path; where it does (friction at via points), along a
        straight line from the start state in ``steps`` steps (default
        ``DEFAULT_PATH_STEPS``), ``x0`` unused, the result a
        :class:`~plush_opt.solve.friction_solve.FrictionEquilibrium`
        recording that path.
        """
        return self.plant.equilibrium(self.contraction_vector(contraction), x0, options, steps)

    @property
    def plant(self):
        """The :class:`~plush_opt.solve.plant.Plant` of the scene (built on
        first use by :func:`~plush_opt.solve.plant.make_plant`, the one place
        that asks whether the scene has friction at via points). Nothing is
        ever committed to it: a caller that keeps a history takes
        ``problem.plant.fork()``."""
        if self._plant is None:
            from .solve.plant import make_plant
            self._plant = make_plant(self.model)
        return self._plant

    def control(self, method: str = "reparam", contraction: Mapping[str, float] | None = None,
                frozen: Iterable[str] | None = None, x0=None, options=None, start=None):
        """Contractions that bring the body to the targets.

        Parameters
        ----------
        method : 'reparam' or 'clip' (the gradient loop with that bounds
            strategy) or 'bilevel' (IPOPT on the KKT formulation).
        contraction : where to start, by winch name (default the scene's).
        frozen : winch names to hold, besides the scene's frozen ones.
        x0 : a pose near the starting equilibrium (optional).
        options : the method's options (``ControlOptions`` or ``BilevelOptions``).
        start : the plant's state to start from (a path-dependent plant:
            the robot's friction state; default: the scene's start state
            driven to ``contraction``); each iterate is then reached from
            the one before (see :class:`~plush_opt.solve.plant.Plant`).

        Returns
        -------
        ControlResult
        """
        from .control import run_control
        if not self.targets.n_targets:
            raise SceneError(f"{self.source}: targets: control needs targets; the file has none")
        return run_control(self.model, self.targets, method, self.contraction_vector(contraction),
                           self.frozen_vector(frozen), x0, options,
                           bilevel=self.bilevel_solver if method == "bilevel" else None,
                           plant=self.plant.fork(start))

    @property
    def bilevel_solver(self):
        """The bilevel method's solver for this model (built NLPs kept across runs)."""
        if self._bilevel is None:
            from .control import BilevelSolver
            self._bilevel = BilevelSolver(self.model)
        return self._bilevel

    def with_targets(self, targets) -> "Problem":
        """The same problem with other targets (model, mesh and solvers shared).

        ``targets``: a list in the problem file's format,
        ``[{"at": [x, y], "to": [x, y], "weight": w}, ...]`` (``at`` a body
        point in rest coordinates, ``to`` where it should go, both in length
        units; ``weight`` > 0, default 1; ``[]`` for none), or a
        :class:`~plush_opt.fem.objective.Targets`. A bad entry, or a point
        off the body, is one :class:`SceneError` naming its index and key
        (``with_targets: targets[1].to: ...``).
        """
        if not isinstance(targets, Targets):
            targets = self._located(targets)
        other = Problem(self.scene, self.mesh, self.model, targets, self.mesh_report)
        other._bilevel, other._plant = self._bilevel, self._plant
        return other

    def _located(self, entries) -> Targets:
        """Problem-file target entries, checked and located in the mesh."""
        from .io.problem_file import read_targets
        found = read_targets(entries, WITH_TARGETS)
        if not found:
            return Targets.empty()
        try:
            return Targets.at_points(self.mesh, [t.at for t in found], [t.to for t in found],
                                     [t.weight for t in found])
        except SceneError as exc:        # a point off the body: say where it came from
            raise SceneError(f"{WITH_TARGETS}: {exc}") from None


def from_scene(scene: Scene, mesh: Mesh | None = None, *, max_area: float | None = None,
               accuracy: float | None = None) -> Problem:
    """Build a :class:`Problem` from a scene: mesh it (the file's mesh, a
    ``max_area``, or the element and mesh good to ``accuracy`` at the least
    solve time), model it, and place its targets."""
    report = None
    if mesh is None:
        if accuracy is not None:
            from .solve.accuracy import choose_mesh
            # (where the pose depends on the path, each probe's pose is the plant's fresh path there)
            mesh, report = choose_mesh(scene, accuracy)
            if mesh.element.name != scene.element:
                scene = dataclasses.replace(scene, element=mesh.element.name)
        else:
            mesh = build_mesh(scene, max_area)
    model = build_model(scene, mesh)
    pushes = rest_pushes(model.contact, model.X)
    if pushes is not None:                     # valid, but unlikely meant: said, not refused
        log.warning("%s: contact.self: on this mesh of %d nodes, %s (a contact.distance below the "
                    "boundary's segments keeps the rest pose free)", scene.source, mesh.n_nodes, pushes)
    return Problem(scene, mesh, model, Targets.from_mesh(mesh, scene), report)


def load(path, *, max_area: float | None = None, accuracy: float | None = None) -> Problem:
    """Read a problem file and build its :class:`Problem`.

    Parameters
    ----------
    path : the problem file (YAML, ``format: plush-opt/1``).
    max_area : mesh finer or coarser than the file asks (optional).
    accuracy : choose the element (P1, P2) and mesh whose target points
        are good to this length at the least cost of a solve (optional; see
        docs/accuracy.md). ``Problem.mesh_report`` says what was chosen and
        whether the tolerance was met.
    """
    return from_scene(load_scene(Path(path)), max_area=max_area, accuracy=accuracy)
