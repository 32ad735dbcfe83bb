"""The path-dependent plant of a scene with friction at contacts
(docs/plant.md; docs/model.md, "Contact").

Its committed state is a :class:`ContactState`: the pose and contractions
the robot's history reached, and the friction's lagged data of the step
that reached it. :meth:`ContactFrictionPlant.drive` follows a straight
contraction path from it in steps; each step holds every contact node's
anchor (carried from the state before: its friction force goes on), solves the equilibrium with the
friction lagged at a pose, updates the lag at the pose found and solves
again until the normal forces agree (:func:`step`). A step without an
equilibrium (an incline steeper than the friction angle: the body slides)
ends the path with an honest status.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..base.errors import SceneError, SolverError
from ..fem.contact_friction import ContactFrictionTerm, Lag, carried_anchor, lag_at
from ..fem.model import HeldTerms, Model
from ..base.reprs import compact_repr
from .equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium
from .plant_base import Plant, moved_note
from .sensitivity import implicit_derivative

#: each winch moves at most this fraction of its range per step of a path
STEP_FRACTION = 0.05
#: steps of a path from the start state when none is asked for
DEFAULT_STEPS = 10
#: solves of one step while the lagged normal forces settle
MAX_LAG_ITERATIONS = 10
#: ... settled when they change by at most this fraction of the largest
LAG_RTOL = 1e-4
START = "start state: zero contraction, every contact node anchored at its rest position, its equilibrium"
FRESH_PATH = ("friction at contacts: the pose reached from the scene's start state along a straight path to "
              f"these contractions ({DEFAULT_STEPS} steps), not any earlier history")


@dataclass(frozen=True)
class ContactState:
    """A committed state: pose ``x`` (n_dofs,), ``contraction`` (n_winches,)
    and the ``lag`` its step held (its anchors those of the state before;
    :func:`~plush_opt.fem.contact_friction.carried_anchor` gives the next's)."""

    x: np.ndarray
    contraction: np.ndarray
    lag: Lag

    __repr__ = compact_repr


@dataclass(frozen=True)
class ContactEquilibrium(Equilibrium):
    """An :class:`Equilibrium` reached along a contraction path with friction
    at contacts: ``contact`` the state reached, ``path`` (steps, n_winches)
    the contractions followed from ``origin``, ``steps_done`` how many were
    reached."""

    contact: ContactState | None = field(default=None, repr=False, compare=False)
    path: np.ndarray | None = field(default=None, repr=False, compare=False)
    steps_done: int = 0
    origin: str = START

    __repr__ = compact_repr


class StepModel(HeldTerms):
    """The model of one step: the scene's terms plus the friction lagged at
    ``lag`` (what :func:`~plush_opt.solve.equilibrium.solve_equilibrium`
    minimises)."""

    def __init__(self, model: Model, lag: Lag):
        self.friction = ContactFrictionTerm(model.contact, lag)
        super().__init__(model, model.terms + (self.friction,), model.hessian_layout, model.factorizer)


def step(model: Model, state: ContactState, contraction, options: EquilibriumOptions | None,
         guess=None) -> tuple[Equilibrium, Lag, str | None]:
    """One step from ``state`` to ``contraction``: the equilibrium, the lag
    it holds, and why it failed (None when it converged with a settled lag)."""
    term = model.contact
    x = state.x if guess is None else guess
    anchor = carried_anchor(term, state.lag, state.x)
    lag = lag_at(term, anchor, x)
    failed = None
    for _ in range(MAX_LAG_ITERATIONS):
        eq = solve_equilibrium(StepModel(model, lag), contraction, x, options)
        if not model.admissible(eq.x):
            return eq, lag, eq.status
        new = lag_at(term, anchor, eq.x)
        settled = new.close_to(lag, LAG_RTOL)
        if eq.converged and settled:
            return eq, lag, None
        if not eq.converged:
            failed = eq.status
            if settled:
                return eq, lag, failed          # the forces it found change nothing: no equilibrium
            # contact the lag did not know of (the body landed, or touched
            # something new): solve again from the state, with its forces
            x = state.x
        else:
            failed, x = None, eq.x
        lag = new
    return eq, lag, failed or (f"the friction's normal forces did not settle in {MAX_LAG_ITERATIONS} "
                               f"solves (relative tolerance {LAG_RTOL:g})")


def path_steps(model: Model, start, contraction) -> int:
    """Steps of the straight path from ``start`` to ``contraction``: each
    winch moves at most :data:`STEP_FRACTION` of its range per step."""
    span = np.maximum(model.upper - model.lower, np.finfo(float).tiny)
    move = np.abs(np.asarray(contraction, dtype=np.float64) - np.asarray(start, dtype=np.float64)) / span
    return max(1, int(np.ceil(float(np.max(move, initial=0.0)) / STEP_FRACTION - 1e-12)))


def follow(model: Model, state: ContactState, path, options, origin: str) -> ContactEquilibrium:
    """The pose at the end of ``path`` ((steps, n_winches)) from ``state``,
    each step from the one before; stops at the first step that fails."""
    path = np.atleast_2d(np.asarray(path, dtype=np.float64))
    eq = None
    for k, c in enumerate(path):
        eq, lag, failed = step(model, state, c, options)
        if failed is not None:
            status = f"step {k + 1} of {len(path)} (contractions {np.round(c, 4).tolist()}): {failed}"
            return ContactEquilibrium(**{**_fields(eq), "converged": False, "status": status},
                                      contact=state, path=path, steps_done=k, origin=origin)
        state = ContactState(eq.x, np.array(c), lag)
    return ContactEquilibrium(**_fields(eq), contact=state, path=path, steps_done=len(path), origin=origin)


def _fields(eq: Equilibrium) -> dict:
    return {f.name: getattr(eq, f.name) for f in dataclasses.fields(Equilibrium)}


class ContactFrictionPlant(Plant):
    """A plant whose poses depend on the path: friction at contacts.

    Parameters
    ----------
    model : the energy model (its ``contact`` has friction > 0).
    state : the committed :class:`ContactState` (None: the start state).
    """

    path_dependent = True
    history_note = FRESH_PATH
    path_cause = "friction at contacts"

    def __init__(self, model: Model, state: ContactState | None = None):
        super().__init__(model, state)
        self._built: dict = {}          # the start state, shared with forks

    def state_of(self, eq: ContactEquilibrium) -> ContactState:
        return eq.contact

    def start_state(self, options=None) -> ContactEquilibrium:
        """The start state: the equilibrium at zero contraction, every node
        anchored at its rest position."""
        if "start" not in self._built:
            X, zero = self.model.X, np.zeros(self.model.n_winches)
            rest = ContactState(X, zero, lag_at(self.model.contact, self.model.contact.points(X), X))
            self._built["start"] = follow(self.model, rest, zero[None], options, "the rest pose")
        return self._built["start"]

    def _from(self, state: ContactState | None, contraction, steps, options, origin) -> ContactEquilibrium:
        if state is None:
            start = self.start_state(options)
            if not start.converged:
                return dataclasses.replace(start, status=f"the start state: {start.status}")
            state, origin = start.contact, START
        c = np.asarray(contraction, dtype=np.float64).reshape(-1)
        n = path_steps(self.model, state.contraction, c) if steps is None else int(steps)
        path = state.contraction + np.outer(np.arange(1, n + 1) / n, c - state.contraction)
        path[-1] = c
        return follow(self.model, state, path, options, origin)

    def equilibrium(self, contraction, x0=None, options=None, steps=None) -> ContactEquilibrium:
        """From the start state along a straight line in ``steps`` steps
        (default :data:`DEFAULT_STEPS`); ``x0`` is not used."""
        return self._from(None, contraction, DEFAULT_STEPS if steps is None else steps, options, START)

    def drive(self, contraction, x0=None, options=None, *, origin=None) -> ContactEquilibrium:
        """From the committed state (none: the start state) along a straight
        line, each winch moving at most :data:`STEP_FRACTION` of its range
        per step; ``x0`` is not used."""
        return self._from(self._state, contraction, None, options, origin or "the committed state")

    def trial(self, contraction, guess=None, options=None, *, origin=None) -> ContactEquilibrium:
        return self.drive(contraction, guess, options, origin=origin)

    def sensitivity(self, eq: ContactEquilibrium, columns=None):
        """dx/dc of a path that goes on from ``eq`` with its anchors and lag held."""
        return implicit_derivative(eq.factor, self.model.mixed(eq.x, eq.contraction), columns)

    def objective_gradient(self, eq, dO_dx, columns=None):
        return self.sensitivity(eq, columns).T @ dO_dx

    def finish(self, eq: ContactEquilibrium, path, options, *, origin=None) -> ContactEquilibrium:
        done = self.certify(eq, options, origin=origin)
        return dataclasses.replace(done, path=np.atleast_2d(np.asarray(path)), steps_done=len(path))

    def certify(self, eq: ContactEquilibrium, options, *, origin=None) -> ContactEquilibrium:
        """One Newton solve from ``eq``'s pose at its state's lag, with the
        smallest Hessian eigenvalue and the friction cones checked."""
        state = eq.contact
        again = solve_equilibrium(StepModel(self.model, state.lag), eq.contraction, eq.x,
                                  dataclasses.replace(options, eigenvalue=True))
        fields = _fields(again)
        outside = cone_violation(self.model, state.lag, again.x)
        if again.converged and outside is not None:
            fields.update(converged=False, status=outside)
        return ContactEquilibrium(**fields, contact=ContactState(again.x, state.contraction, state.lag),
                                  path=eq.path, steps_done=eq.steps_done, origin=origin or eq.origin)

    # -- a path's states (the sweep) ---------------------------------------

    def follow(self, path, on_step=None) -> list[ContactEquilibrium]:
        """The scene's start state and the states along ``path``
        ((n_steps, n_winches) contractions), each reached from the one
        before as :meth:`drive` would, stopping after the first step that fails (nothing
        committed); a :class:`SolverError` if the start state does not
        converge. ``on_step(k, state)``, if given, is called after step k
        (from 1)."""
        start = self.start_state()
        if not start.converged:
            raise SolverError(f"the start state did not converge: {start.status}")
        states, state = [start], start.contact
        for k, c in enumerate(np.atleast_2d(np.asarray(path, dtype=np.float64)), 1):
            eq = self._from(state, c, None, None, "the state before")   # in steps of STEP_FRACTION at most
            states.append(eq)
            if on_step is not None:
                on_step(k, eq)
            if not eq.converged:
                break
            state = eq.contact
        return states

    def end_tensions(self, state: ContactEquilibrium) -> list[tuple[float, float]]:
        """(winch end, stopper end) tension of every tendon at ``state``:
        each tendon is one spring here, pulling the same at both ends."""
        return [(float(t), float(t)) for t in self.model.tendon_state(state.x, state.contraction)["tension"]]

    def require_history_free(self, what: str, instead: str) -> None:
        raise SceneError(f"{self.model.scene.source}: contact.friction: {what} solves for the pose at the "
                         "final contractions alone, but with friction at contacts the pose depends on the "
                         f"path the winches took; {instead}")

    def recorded(self, doc, x, contraction, options, where):
        """A record holds no anchors: the pose reached along a fresh path
        from the start state (:data:`FRESH_PATH`), and the note says so."""
        eq = self.equilibrium(np.asarray(contraction, dtype=np.float64), options=options)
        return moved_note(f"{where} records no contact anchors: {FRESH_PATH}", eq, x)


def cone_violation(model: Model, lag: Lag, x: np.ndarray) -> str | None:
    """Whether a friction force at ``x`` (held at ``lag``) leaves its cone
    |f_t| <= mu lambda of the normal force at ``x`` itself, in words. The
    cone is widened by what the lag's settling leaves (10 :data:`LAG_RTOL`
    of the largest normal force, as :meth:`Lag.close_to` measures it): a
    node at the edge of a contact patch carries a small fraction of it."""
    friction = ContactFrictionTerm(model.contact, lag)
    now = lag_at(model.contact, model.contact.points(x), x)
    f = np.linalg.norm(friction.forces(x), axis=1)
    normal = np.zeros(len(lag.node))
    index = {(int(n), int(lab)): k for k, (n, lab) in enumerate(zip(now.node, now.label))}
    for k, (n, lab) in enumerate(zip(lag.node, lag.label)):
        j = index.get((int(n), int(lab)))
        normal[k] = now.normal[j] if j is not None else 0.0
    limit = model.contact.friction * (normal + 10 * LAG_RTOL * np.max(normal, initial=0.0))
    bad = np.flatnonzero(f > limit + 1e-300)
    if bad.size:
        k = int(bad[0])
        node = int(model.contact.boundary.nodes[lag.node[k]])
        return (f"friction outside its cone at node {node}: |f_t| = {f[k]:.4g} > mu * lambda = "
                f"{model.contact.friction * normal[k]:.4g}")
    return None
