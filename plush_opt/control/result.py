"""One result shape for every control method.

The gradient loop (``reparam``, ``clip``) and the bilevel method
(``bilevel``) both return a :class:`ControlResult`: the certified final
pose, why the run stopped (a code from :data:`REASONS` and a sentence),
the iterates, and typed solver statistics. Apps read this and nothing
method-specific.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..base.reprs import compact_repr
from ..solve.equilibrium import Equilibrium

if TYPE_CHECKING:
    from ..fem.model import Model
    from ..fem.objective import Targets

METHODS = ("reparam", "clip", "bilevel")

# Why a control run stopped. `converged` is True only for the first two.
REASONS = (
    "targets_reached",      # O fell below the objective floor
    "stationary",           # first-order optimal within the bounds (KKT), certified
    "no_decrease",          # no trial step decreased O (line search, stall) short of stationarity
    "max_iterations",       # the iteration budget ran out
    "max_time",             # the time budget ran out
    "not_certified",        # the solver's end point is not a certified stable equilibrium
    "solver_failed",        # the solver gave up (IPOPT's own failure statuses)
    "interrupted",          # a signal (Ctrl-C, SIGTERM, SIGHUP) ended the run at its last accepted iterate
)
CONVERGED_REASONS = ("targets_reached", "stationary")
#: the reason of a run a signal ended (as a run log's end line says it)
INTERRUPTED = "interrupted"


@dataclass(frozen=True)
class ControlIterate:
    """One iterate of a control run.

    Attributes
    ----------
    iteration : 0 for the starting equilibrium.
    t_wall : seconds since the run started.
    contraction : (n_winches,) contractions (length units).
    objective : O at this iterate's pose (length^2).
    equilibrium : the certified equilibrium at ``contraction`` when the
        iterate is dispatchable (every iterate of the gradient loop), else
        None (an IPOPT iterate, whose pose is not yet an equilibrium).
    gradient : (n_winches,) dO/dc, or None where the method has none.
    constraint_violation : equilibrium residual of the iterate (0 for a
        certified equilibrium).
    active_bounds : names of winches held at a bound.
    equilibrium_solves, newton_iterations : cumulative counts.
    """

    iteration: int
    t_wall: float
    contraction: np.ndarray
    objective: float
    equilibrium: Equilibrium | None = None
    gradient: np.ndarray | None = None
    constraint_violation: float = 0.0
    active_bounds: tuple[str, ...] = ()
    equilibrium_solves: int = 0
    newton_iterations: int = 0

    __repr__ = compact_repr

    @property
    def dispatchable(self) -> bool:
        """A certified stable equilibrium: safe to send to the robot now."""
        return self.equilibrium is not None and self.equilibrium.converged

    @property
    def x(self) -> np.ndarray | None:
        return None if self.equilibrium is None else self.equilibrium.x


@dataclass(frozen=True)
class ControlStats:
    """Solver statistics common to every method.

    Attributes
    ----------
    solver : 'gradient-loop' or 'ipopt'.
    iterations : accepted iterates (loop) or IPOPT iterations.
    equilibrium_solves, newton_iterations : Newton work, all solves counted.
    t_wall : seconds for the whole run, set-up included.
    t_setup : seconds spent building solvers (0 when cached).
    details : method-specific typed statistics (e.g. the bilevel method's
        IPOPT timings and KKT check), or None.
    """

    solver: str
    iterations: int
    equilibrium_solves: int
    newton_iterations: int
    t_wall: float
    t_setup: float = 0.0
    details: object | None = None

    __repr__ = compact_repr


@dataclass(frozen=True)
class ControlResult:
    """The outcome of a control run, whatever the method.

    Attributes
    ----------
    method : one of :data:`METHODS`.
    converged : the run reached a certified optimum (see ``reason``).
    reason : why it stopped, one of :data:`REASONS`.
    status : the same in a sentence, with the specifics.
    equilibrium : the certified final pose (smallest Hessian eigenvalue
        computed), ready for the result file and the robot.
    objective : O at ``equilibrium`` (length^2).
    active_bounds : winches ending at a bound.
    frozen : winches held fixed during the run.
    history : every iterate, in order (:class:`ControlIterate`).
    stats : :class:`ControlStats`.
    model, targets : what was solved (not compared, not printed).
    """

    method: str
    converged: bool
    reason: str
    status: str
    equilibrium: Equilibrium
    objective: float
    active_bounds: tuple[str, ...]
    frozen: tuple[str, ...]
    history: tuple[ControlIterate, ...]
    stats: ControlStats
    model: "Model" = field(repr=False, compare=False)
    targets: "Targets" = field(repr=False, compare=False)

    def __repr__(self) -> str:
        """One line: the verdict, O and the contractions (no arrays; the
        pose is ``x``, the iterates ``history``)."""
        shown = ", ".join(f"{n!r}: {v:.4g}" for n, v in self.contractions.items())
        return (f"ControlResult(method={self.method!r}, reason={self.reason!r}, converged={self.converged}, "
                f"objective={self.objective:.4g}, contractions={{{shown}}}, "
                f"active_bounds={self.active_bounds!r}, frozen={self.frozen!r}, "
                f"iterations={self.stats.iterations}, equilibrium_solves={self.stats.equilibrium_solves})")

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method: expected one of {METHODS}, got {self.method!r}")
        if self.reason not in REASONS:
            raise ValueError(f"reason: expected one of {REASONS}, got {self.reason!r}")

    @property
    def x(self) -> np.ndarray:
        """(n_dofs,) the final pose, flat."""
        return self.equilibrium.x

    @property
    def contraction(self) -> np.ndarray:
        """(n_winches,) the final contractions."""
        return self.equilibrium.contraction

    @property
    def contractions(self) -> dict[str, float]:
        """The final contractions by winch name."""
        return {n: float(v) for n, v in zip(self.model.winch_names, self.contraction)}

    def to_dict(self) -> dict:
        """The result file's document (``plush-opt-result/1``)."""
        from ..solve.result_file import control_result_dict
        return control_result_dict(self)

    def save(self, path) -> None:
        """Write the result file to ``path`` atomically."""
        from ..solve.result_file import control_result_dict
        from ..base.files import write_json_atomic
        write_json_atomic(path, control_result_dict(self))
