"""The path-dependent plant: a scene with friction at via points
(docs/model.md, "Friction at via points").

Its committed state is a :class:`~plush_opt.solve.friction_path.FrictionState`
(pose, segment rest lengths, tensions, stick/slip modes): what the robot's
history left. :meth:`FrictionPlant.drive` follows a straight contraction
path from it in steps (plush_opt/solve/friction_solve.py), and every pose
it returns is a :class:`~plush_opt.solve.friction_solve.FrictionEquilibrium`
carrying the state it reached and the path it followed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..base.errors import SceneError, SolverError
from ..fem.friction import FrictionModel
from ..fem.model import Model
from .friction_path import STICK, FrictionState, check_state, follow, start_state, state_at
from .friction_solve import DEFAULT_PATH_STEPS, FrictionEquilibrium, drive, finish, path_sensitivity, solve_forward
from .plant_base import Plant, moved_note

# Which history a pose at contractions alone assumes (the pose reached by
# :meth:`FrictionPlant.equilibrium`), for messages.
FRESH_PATH = (f"friction at via points: the pose reached from the scene's start state along a straight "
              f"path to these contractions ({DEFAULT_PATH_STEPS} steps), not any earlier history")


class FrictionPlant(Plant):
    """A plant whose poses depend on the path (friction at via points).

    Parameters
    ----------
    model : the energy model; its :class:`~plush_opt.fem.friction.FrictionModel`
        is built on first use and shared by every fork.
    include_frictionless : split frictionless tendons with interior via
        points into segments too (see :func:`~plush_opt.solve.plant.make_plant`).
    state : the committed :class:`FrictionState` (None: the scene's start state).
    """

    path_dependent = True
    history_note = FRESH_PATH
    path_cause = "friction at via points"

    def __init__(self, model: Model, include_frictionless: bool = False, state: FrictionState | None = None):
        super().__init__(model, state)
        self._include_frictionless = include_frictionless
        self._built: dict = {}         # the friction model, shared with forks

    @property
    def friction_model(self) -> FrictionModel:
        """The scene's :class:`~plush_opt.fem.friction.FrictionModel`."""
        if "fm" not in self._built:
            self._built["fm"] = FrictionModel(self.model, include_frictionless=self._include_frictionless)
        return self._built["fm"]

    def state_of(self, eq: FrictionEquilibrium) -> FrictionState:
        return eq.friction

    # -- solves -----------------------------------------------------------

    def equilibrium(self, contraction, x0=None, options=None, steps=None) -> FrictionEquilibrium:
        """From the scene's start state along a straight line in ``steps``
        steps (default ``DEFAULT_PATH_STEPS``); ``x0`` is not used (a pose
        alone is not a friction state)."""
        return solve_forward(self.friction_model, contraction, DEFAULT_PATH_STEPS if steps is None else steps,
                             equilibrium=options)

    def drive(self, contraction, x0=None, options=None, *, origin=None) -> FrictionEquilibrium:
        """From the committed state (nothing committed: the scene's start
        state in ``DEFAULT_PATH_STEPS``) along a straight line, each winch
        moving at most ``MAX_STEP_FRACTION`` of its range per step; ``x0``
        is not used."""
        if self._state is None:
            return solve_forward(self.friction_model, contraction, DEFAULT_PATH_STEPS, equilibrium=options)
        return drive(self.friction_model, self._state, contraction, equilibrium=options, origin=origin)

    def trial(self, contraction, guess=None, options=None, *, origin=None) -> FrictionEquilibrium:
        return self.drive(contraction, guess, options, origin=origin)

    def follow(self, path, on_step=None) -> list[FrictionState]:
        """The scene's start state and the states along ``path``
        ((n_steps, n_winches) contractions), each from the one before,
        stopping after the first step that fails (nothing committed);
        a :class:`SolverError` if the start state does not converge.
        ``on_step(k, state)``, if given, is called after step k (from 1)."""
        fm = self.friction_model
        start = start_state(fm)
        if not start.converged:
            raise SolverError(f"the start state did not converge: {start.status}")
        return [start] + follow(fm, start, path, on_step=on_step)

    def end_tensions(self, state: FrictionState) -> list[tuple[float, float]]:
        """(winch end, stopper end) tension of every tendon of the scene at
        ``state`` (N): a tendon without segments pulls the same at both."""
        fm = self.friction_model
        one = self.model.tendon_state(state.x, state.contraction)["tension"]
        out = []
        for t in range(self.model.n_tendons):
            seg = np.flatnonzero(fm.seg_tendon == t)
            out.append((state.tension[seg[-1]], state.tension[seg[0]]) if seg.size else (one[t], one[t]))
        return out

    # -- derivatives ------------------------------------------------------

    def sensitivity(self, eq: FrictionEquilibrium, columns=None):
        """dx/dc in the stick/slip modes of ``eq``'s last step
        (:func:`~plush_opt.solve.friction_solve.path_sensitivity`)."""
        return path_sensitivity(self.friction_model, eq.friction, eq.factor, columns=columns)

    def objective_gradient(self, eq, dO_dx, columns=None):
        return self.sensitivity(eq, columns).T @ dO_dx

    # -- certified poses --------------------------------------------------

    def finish(self, eq: FrictionEquilibrium, path, options, *, origin=None) -> FrictionEquilibrium:
        """The pose polished and certified at the segment rest lengths of
        ``eq``'s state, with ``path`` (every step reached) attached."""
        path = np.asarray(path)
        done = finish(self.friction_model, eq.friction, path, len(path), options)
        return done if origin is None else dataclasses.replace(done, origin=origin)

    def certify(self, eq: FrictionEquilibrium, options, *, origin=None) -> FrictionEquilibrium:
        """At its state's segment rest lengths: the pose stays the one the
        robot's history reached; ``eq``'s own path is kept."""
        done = finish(self.friction_model, eq.friction, eq.path, eq.steps_done,
                      dataclasses.replace(options, eigenvalue=True))
        return done if origin is None else dataclasses.replace(done, origin=origin)

    def require_history_free(self, what: str, instead: str) -> None:
        raise SceneError(f"{self.model.scene.source}: tendons.friction: {what} solves for the pose at "
                         "the final contractions alone, but with friction at via points the pose depends on "
                         f"the path the winches took; {instead}")

    # -- records ----------------------------------------------------------

    def recorded(self, doc, x, contraction, options, where):
        """At the segment rest lengths the document recorded (every via
        point taken as stuck: a record has no last step), solved from the
        recorded pose; a document without them gets a fresh path from the
        start state (:data:`FRESH_PATH`), and the note says so."""
        fm = self.friction_model
        c = np.asarray(contraction, dtype=np.float64)
        rest = recorded_rest(doc, fm, where)
        if rest is None:
            eq = self.equilibrium(c, options=options)
            note = f"{where} records no segment rest lengths: {FRESH_PATH}"
            return eq, note if eq.converged else f"{note}; NOT converged: {eq.status}"
        state = _stuck(fm, x, c, rest, f"recorded in {where}")
        eq = finish(fm, state, np.atleast_2d(c), 1, options)
        eq = dataclasses.replace(eq, friction=_stuck(fm, eq.x, c, rest, state.status),
                                 origin=f"the state recorded in {where}")
        note = ("the state recorded (segment rest lengths), its equilibrium solved from the recorded pose"
                + "".join(f"; recorded state: {v}" for v in check_state(fm, state)))
        return moved_note(note, eq, x)


def _stuck(fm: FrictionModel, x, c, rest, status: str) -> FrictionState:
    """A recorded state: every via point taken as stuck (it has no last step)."""
    zero = np.zeros(fm.n_interior)
    return state_at(fm, x, rest, c, np.full(fm.n_interior, STICK, dtype=np.int8), zero, True, status)


def recorded_rest(doc: dict, fm: FrictionModel, where: str) -> np.ndarray | None:
    """The friction tendons' segment rest lengths recorded in a result
    document, in the friction model's order; None if it has none."""
    entries = doc["model"]["tendons"]["list"]
    scene = fm.model.scene
    rest = []
    for t in fm.tendons:
        key = f"{where}: model.tendons.list[{t}]"
        entry = entries[t]
        if entry.get("name") != scene.tendons[t].name:
            raise SceneError(f"{key}.name: {entry.get('name')!r}, but the problem's tendon {t} is "
                             f"{scene.tendons[t].name!r}")
        if "segment_rest_lengths" not in entry:
            return None
        if entry.get("friction", scene.tendons[t].friction) != scene.tendons[t].friction:
            raise SceneError(f"{key}.friction: {entry['friction']!r}, but the problem has "
                             f"{scene.tendons[t].friction!r}: a result of another friction")
        r = np.asarray(entry["segment_rest_lengths"], dtype=np.float64)
        want = int(np.sum(fm.seg_tendon == t))
        if r.shape != (want,) or not np.all(np.isfinite(r) & (r > 0)):
            raise SceneError(f"{key}.segment_rest_lengths: expected {want} positive lengths, got {r.tolist()}")
        rest.append(r)
    return np.concatenate(rest)

