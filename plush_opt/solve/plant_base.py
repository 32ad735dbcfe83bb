"""The plant interface: what every forward model of a scene promises
(see :mod:`plush_opt.solve.plant` for the idea and the factory)."""

from __future__ import annotations

import abc

import numpy as np

from ..fem.model import Model
from .equilibrium import Equilibrium, EquilibriumOptions, IpoptEquilibrium
from .friction_solve import segment_table


class Plant(abc.ABC):
    """The forward model of one scene with its committed history.

    Attributes
    ----------
    model : the energy :class:`~plush_opt.fem.model.Model` (shared, never
        changed by the plant).
    path_dependent : whether a pose depends on the path the winches took
        (then :meth:`drive` follows it in steps and the committed state is
        more than a pose).
    history_note : for a path-dependent plant, one sentence saying which
        history :meth:`equilibrium` assumes (for messages); else None.
    path_cause : for a path-dependent plant, what makes it so, in words
        ("friction at via points"); else None.
    state : the committed state (None: nothing committed; the scene's
        start state). Its type is the plant's own.

    Every pose is an equilibrium of ``model``; lengths in the scene's
    length unit, contractions (n_winches,), poses flat (n_dofs,).
    """

    path_dependent = False
    history_note: str | None = None
    path_cause: str | None = None

    def __init__(self, model: Model, state=None):
        self.model = model
        self._state = state
        # the IPOPT backend's built NLPs, kept across this plant's solves (forks share them)
        self.ipopt = IpoptEquilibrium(model)

    # -- history ----------------------------------------------------------

    @property
    def state(self):
        """The committed state (None: the scene's start state)."""
        return self._state

    @abc.abstractmethod
    def state_of(self, eq: Equilibrium):
        """The state ``eq`` stands for, as :meth:`commit` would keep it."""

    def commit(self, eq: Equilibrium) -> None:
        """Make ``eq`` (an equilibrium this plant returned) the committed
        state: the next :meth:`drive` starts from it."""
        self._state = self.state_of(eq)

    def reset(self, state=None) -> None:
        """Set the committed state (default: none, the scene's start state)."""
        self._state = state

    def fork(self, state=None) -> "Plant":
        """A plant of the same physics and model with its own history,
        starting at ``state`` (default: the scene's start state)."""
        other = type(self).__new__(type(self))
        other.__dict__.update(self.__dict__)
        other._state = state
        return other

    # -- solves -----------------------------------------------------------

    @abc.abstractmethod
    def equilibrium(self, contraction, x0=None, options: EquilibriumOptions | None = None,
                    steps: int | None = None) -> Equilibrium:
        """The pose at ``contraction`` (n_winches,) reached from the scene's
        start state, whatever is committed (a history-free plant: the
        equilibrium from ``x0``, default the rest pose; a path-dependent
        one: a straight path from the start state in ``steps`` steps)."""

    @abc.abstractmethod
    def drive(self, contraction, x0=None, options: EquilibriumOptions | None = None, *,
              origin: str | None = None) -> Equilibrium:
        """The pose at ``contraction`` reached from the committed state
        (not committed). A history-free plant solves from ``x0`` (default:
        the rest pose); a path-dependent one follows a straight path from
        its committed state in steps and records ``origin`` (where that
        state came from, in words) on the result."""

    @abc.abstractmethod
    def trial(self, contraction, guess=None, options: EquilibriumOptions | None = None, *,
              origin: str | None = None) -> Equilibrium:
        """A search's trial pose at ``contraction``, a small move from the
        committed state (not committed): a history-free plant stays on the
        committed equilibrium's stable branch, warm-started from ``guess``
        (a limit point makes it fail instead of snapping through); a
        path-dependent one drives there (``guess`` unused)."""

    # -- derivatives ------------------------------------------------------

    @abc.abstractmethod
    def sensitivity(self, eq: Equilibrium, columns=None):
        """dx/dc at ``eq``, (n_dofs, n_winches) dense (only ``columns``, the
        others zero), with the factorisation ``eq`` kept: the implicit
        derivative at a history-free equilibrium, the derivative of a path
        that goes on in its last step's modes at a path-dependent one."""

    @abc.abstractmethod
    def objective_gradient(self, eq: Equilibrium, dO_dx, columns=None):
        """dO/dc at ``eq`` (n_winches,) for an objective whose gradient in
        the pose is ``dO_dx`` (n_dofs,); only ``columns`` need be right."""

    # -- certified poses --------------------------------------------------

    @abc.abstractmethod
    def finish(self, eq: Equilibrium, path, options: EquilibriumOptions, *,
               origin: str | None = None) -> Equilibrium:
        """The certified end of a path (``path`` (n_steps, n_winches), the
        contractions followed) whose last equilibrium is ``eq``. Returns
        ``eq`` itself when there is nothing to add (a history-free plant
        without ``options.eigenvalue``)."""

    @abc.abstractmethod
    def certify(self, eq: Equilibrium, options: EquilibriumOptions, *,
                origin: str | None = None) -> Equilibrium:
        """``eq`` checked by one Newton solve from its pose with its smallest
        Hessian eigenvalue (at its own history where it has one)."""

    def require_history_free(self, what: str, instead: str) -> None:
        """Raise a :class:`~plush_opt.base.errors.SceneError` if the plant is
        path-dependent: ``what`` (a method that solves for the final pose
        alone) cannot serve it; ``instead`` says what to use."""

    # -- records ----------------------------------------------------------

    def segment_table(self, eq: Equilibrium) -> list[dict]:
        """Per tendon: ``segment_rest_lengths`` and ``segment_tensions`` at
        ``eq`` (see :func:`~plush_opt.solve.friction_solve.segment_table`)."""
        return segment_table(self.model, eq.x, eq.contraction, eq)

    @abc.abstractmethod
    def recorded(self, doc: dict, x, contraction, options: EquilibriumOptions, where: str
                 ) -> tuple[Equilibrium, str]:
        """The pose a result document recorded (pose ``x``, contractions
        ``contraction``, read and checked by the caller), as an equilibrium
        of this plant, and a note saying what was done; ``where`` names
        the file in messages."""


def moved_note(note: str, eq: Equilibrium, x) -> tuple[Equilibrium, str]:
    """``(eq, note)`` with how far the solve moved the recorded pose ``x``,
    and whether it converged."""
    moved = float(np.max(np.abs(eq.x - x), initial=0.0))
    note += f"; moved the recorded pose by at most {moved:.2g} (length units)"
    return eq, note if eq.converged else f"{note}; NOT converged: {eq.status}"
