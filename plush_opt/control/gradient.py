"""Method 1: the sensitivity-driven outer loop on the winch contractions.

Each iteration, at the current certified equilibrium x(c):

1. gradient dO/dc from the implicit sensitivity (the Newton factor of H is
   reused: no new factorisation), and for a Gauss-Newton direction also
   dx/dc (one solve per free winch with the same factor);
2. a direction on the reparametrised variables xi (c = f(xi) within the
   bounds), or on c itself with plain clipping (the baseline);
3. a backtracking line search on O, each trial contraction solved by a
   warm-started equilibrium (first-order predictor x + dx/dc dc);
4. the trial is accepted only if its equilibrium is certified (converged,
   positive definite Hessian) and O decreased.

:class:`Controller` is anytime: :meth:`Controller.iterates` yields every
accepted iterate, each a stable equilibrium within bounds that can go to
the robot at once. Between iterates a caller may change the targets or
freeze/unfreeze winches; the loop continues from where it is.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field

import numpy as np

from ..solve.equilibrium import Equilibrium, EquilibriumOptions
from ..base.errors import SolverError
from ..fem.model import Model
from ..fem.objective import Targets
from ..solve.plant import Plant, make_plant
from .bounds import bounds_strategy
from .result import ControlIterate, ControlResult, ControlStats
from .restart import restart_move
from .slack import slack_winches

log = logging.getLogger(__name__)

DIRECTIONS = ("gauss-newton", "gradient")
# where a path-dependent plant's iterates were driven from (recorded on them)
CONTROL_ORIGIN = "the control run's starting state, then its accepted iterates in order"
BOUNDS = ("reparam", "clip")


@dataclass(frozen=True)
class ControlOptions:
    """Options of the gradient loop.

    Attributes
    ----------
    bounds : 'reparam' (c = f(xi), the default) or 'clip' (step on c, then
        clip to the bounds: the simple baseline).
    direction : 'gauss-newton' (Levenberg-Marquardt on the target
        residuals, uses dx/dc) or 'gradient' (steepest descent, one adjoint
        solve per iterate, Barzilai-Borwein step length).
    max_iterations : accepted iterates at most.
    max_time : seconds at most (None: no limit).
    ftol : stop when the relative decrease of O stays below ftol for
        ``patience`` consecutive iterates.
    gtol : stop when the projected gradient |P dO/dc| times the mean bound
        range is below gtol * max(O, floor), floor as below.
    objective_floor : O below this times the mean target weight (length^2)
        counts as targets reached: relative to the weights, so that tiny
        weights do not make a far target look reached.
    patience : see ftol.
    blend : width of the reparametrisation's blend zone, as a fraction
        of each winch's range.
    slope_floor : smallest f' used in the search direction (so a winch on
        a bound can come back).
    max_step : largest change of one winch's xi per iterate, as a fraction
        of its range (keeps the loop in the basin it starts in and every
        streamed iterate a modest move for the robot).
    max_backtracks : line-search trials per iterate.
    initial_damping : Levenberg-Marquardt damping at the start and after
        every restart, relative to the largest curvature of J^T J (small:
        the first step is nearly Gauss-Newton).
    min_damping : the damping never falls below this (keeps J^T J + damping
        well conditioned when a column vanishes).
    damping_decrease, damping_increase : the damping is divided by the first
        after an accepted step and multiplied by the second after a rejected
        trial (the usual asymmetric Levenberg-Marquardt schedule).
    initial_gradient_step : first steepest-descent step, as a fraction of the
        mean bound range per unit of gradient norm (later steps are
        Barzilai-Borwein).
    stuck_fraction : a loop whose O is still above this fraction of its O
        at the start of the current targets is "stuck near its start", which
        enables the bound probes of a restart.
    probe_fractions : how far a restart probes inwards from a bound, as
        fractions of the range.
    probe_gain : a probe is taken only if it lowers O by this relative amount
        (a real improvement, not round-off).
    trial_newton : Newton iterations a line-search trial's equilibrium
        may take, its sub-steps along the branch included (the starting
        pose and restarts: ``equilibrium``'s own limit). A trial stays on
        the current iterate's stable branch (plush_opt/solve/branch.py): past a
        limit point it fails (0-35 iterations on the P2 hexapod), and the
        step is cut instead of followed across a snap-through.
    equilibrium : options of every equilibrium solve.
    """

    bounds: str = "reparam"
    direction: str = "gauss-newton"
    max_iterations: int = 100
    max_time: float | None = None
    ftol: float = 1e-9
    gtol: float = 1e-7
    objective_floor: float = 1e-14
    patience: int = 2
    blend: float = 0.02
    slope_floor: float = 0.1
    max_step: float = 0.2
    max_backtracks: int = 12
    initial_damping: float = 1e-3
    min_damping: float = 1e-9
    damping_decrease: float = 3.0
    damping_increase: float = 10.0
    initial_gradient_step: float = 0.1
    stuck_fraction: float = 0.5
    probe_fractions: tuple[float, ...] = (0.05, 0.15, 0.4)
    probe_gain: float = 1e-3
    trial_newton: int = 100
    equilibrium: EquilibriumOptions = field(
        default_factory=lambda: EquilibriumOptions(eigenvalue=False))

    def __post_init__(self):
        if self.bounds not in BOUNDS:
            raise ValueError(f"bounds: expected one of {BOUNDS}, got {self.bounds!r}")
        if self.direction not in DIRECTIONS:
            raise ValueError(f"direction: expected one of {DIRECTIONS}, got {self.direction!r}")
        if self.max_iterations < 0:
            raise ValueError(f"max_iterations: expected >= 0, got {self.max_iterations!r}")
        if not 0 < self.min_damping <= self.initial_damping:
            raise ValueError("damping: expected 0 < min_damping <= initial_damping, got "
                             f"{self.min_damping!r}, {self.initial_damping!r}")
        if not (self.damping_decrease > 1 and self.damping_increase > 1):
            raise ValueError("damping_decrease, damping_increase: expected > 1, got "
                             f"{self.damping_decrease!r}, {self.damping_increase!r}")
        if not all(0 < f < 1 for f in self.probe_fractions):
            raise ValueError(f"probe_fractions: expected fractions in (0, 1), got {self.probe_fractions!r}")
        if not (isinstance(self.trial_newton, int) and self.trial_newton >= 1):
            raise ValueError(f"trial_newton: expected an integer >= 1, got {self.trial_newton!r}")
        if not 0 < self.slope_floor <= 1:
            raise ValueError(f"slope_floor: expected 0 < slope_floor <= 1, got {self.slope_floor!r}")


# Every accepted iterate is a ControlIterate carrying its certified equilibrium.
Iterate = ControlIterate


class Controller:
    """The anytime gradient loop for one model.

    Parameters
    ----------
    model : the energy model.
    targets : where body points should go.
    contraction : (n_winches,) start (default: the scene's), within bounds.
    frozen : (n_winches,) bool, winches that keep their contraction
        (default: the scene's ``frozen`` flags).
    x0 : a starting pose near the equilibrium at ``contraction`` (optional).
    options : :class:`ControlOptions`.
    plant : the :class:`~plush_opt.solve.plant.Plant` of ``model`` the loop drives
        (default: ``make_plant(model)``): from its committed state, each trial
        from the current iterate, committing every accepted iterate.
    """

    def __init__(self, model: Model, targets: Targets, contraction=None, frozen=None,
                 x0=None, options: ControlOptions | None = None, *, plant: Plant | None = None):
        self.plant = make_plant(model) if plant is None else plant
        self.model = model
        self.options = options or ControlOptions()
        self.targets = targets
        c = model.scene.contraction if contraction is None else np.array(contraction, dtype=np.float64)
        if c.shape != (model.n_winches,):
            raise SolverError(f"contraction: expected {model.n_winches} values, got {c.size}")
        if np.any(c < model.lower) or np.any(c > model.upper):
            raise SolverError("contraction: outside the winch bounds "
                              f"{list(zip(model.lower.tolist(), model.upper.tolist()))}: {c.tolist()}")
        self.frozen = model.scene.frozen.copy() if frozen is None else np.array(frozen, dtype=bool)
        self.bounds = bounds_strategy(self.options.bounds, model.lower, model.upper, self.options.blend)
        self.xi = self.bounds.to_xi(c)
        self.contraction = c.copy()
        self.status = "not started"
        self.reason = "no_decrease"
        self.converged = False
        self.history: list[Iterate] = []
        self._x0 = x0
        self._solves = 0
        self._newton = 0
        self._t0 = None
        self._mu = self.options.initial_damping      # Levenberg-Marquardt damping
        self._bb_step = None     # Barzilai-Borwein step (gradient direction)
        self._eq: Equilibrium | None = None
        self._dirty = False      # targets or frozen set changed since the last iterate
        self._finished = False
        # restart moves used since the targets / frozen set last changed
        # (each at most once per winch, so the loop cannot cycle through them)
        self._restarted: set[int] = set()

    # -- what a caller may change between iterates ------------------------

    @property
    def floor(self) -> float:
        """The stopping floor in the objective's own scale (see ``objective_floor``)."""
        weight = float(np.mean(self.targets.weight)) if self.targets.n_targets else 1.0
        return self.options.objective_floor * weight

    def set_targets(self, targets: Targets) -> None:
        """New targets; the loop continues from the current pose."""
        self.targets = targets
        self._reset_memory()

    def set_frozen(self, name_or_index, frozen: bool = True) -> None:
        """Freeze (or release) a winch: a frozen winch keeps its contraction bit for bit."""
        i = name_or_index if isinstance(name_or_index, (int, np.integer)) \
            else self.model.winch_names.index(name_or_index)
        self.frozen[i] = bool(frozen)
        self._reset_memory()

    def _reset_memory(self):
        self._mu = self.options.initial_damping
        self._bb_step = None
        self.status = "running"
        self.converged = False
        self._dirty = bool(self.history)

    # -- the loop ---------------------------------------------------------

    def _solve(self, c, x0, options: EquilibriumOptions | None = None) -> Equilibrium:
        eq = self.plant.drive(c, x0, options or self.options.equilibrium, origin=CONTROL_ORIGIN)
        self._solves += 1
        self._newton += eq.iterations
        return eq

    def _f(self, xi):
        return self.bounds.f(xi)

    def _iterate(self, eq: Equilibrium, grad_c: np.ndarray) -> Iterate:
        # the history keeps poses, not Cholesky factors (the loop keeps the
        # current one itself): long interactive sessions stay small
        eq = dataclasses.replace(eq, factor=None) if eq.factor is not None else eq
        it = ControlIterate(
            iteration=len(self.history), t_wall=time.perf_counter() - self._t0,
            contraction=eq.contraction.copy(), objective=self.targets.value(eq.x), equilibrium=eq,
            gradient=grad_c, active_bounds=self._active(eq.contraction, grad_c),
            equilibrium_solves=self._solves, newton_iterations=self._newton)
        self.history.append(it)
        return it

    def _active(self, c, grad_c) -> tuple[str, ...]:
        """Winches whose bound stops them from going where the gradient points."""
        tol = self.bounds.margin()
        up = (c >= self.model.upper - tol) & (grad_c < 0)
        lo = (c <= self.model.lower + tol) & (grad_c > 0)
        names = self.model.winch_names
        return tuple(names[i] for i in np.flatnonzero((up | lo) & ~self.frozen))

    def _gradient(self, eq: Equilibrium, need_jacobian: bool):
        """dO/dc (adjoint) and, for Gauss-Newton, the residual Jacobian."""
        free = np.flatnonzero(~self.frozen)
        if need_jacobian:
            dxdc = self.plant.sensitivity(eq, columns=free)
            B = self.targets.selection(self.model.n_dofs)
            J = (np.repeat(np.sqrt(self.targets.weight), 2)[:, None] * (B @ dxdc))
            r = self.targets.residual(eq.x)
            grad = J.T @ r
            grad[self.frozen] = 0.0
            return grad, J, dxdc
        grad = self.plant.objective_gradient(eq, self.targets.gradient(eq.x), columns=free)
        grad[self.frozen] = 0.0
        return grad, None, None

    def _start(self) -> Iterate:
        self._t0 = time.perf_counter()
        eq = self._solve(self.contraction, self._x0)
        if not eq.converged:
            raise SolverError(f"the starting equilibrium is not certified: {eq.status}")
        self._eq = eq
        self.plant.commit(eq)
        self._grad, self._J, self._dxdc = self._gradient(eq, self.options.direction == "gauss-newton")
        self.status = "running"
        first = self._iterate(eq, self._grad)
        self._objective_at_start = first.objective
        return first

    def iterates(self):
        """Run the loop, yielding every accepted :class:`Iterate` (the first
        is the starting equilibrium). Stops with ``self.status`` and
        ``self.converged`` set; :meth:`result` collects the run."""
        opts = self.options
        if not self.history:
            yield self._start()
        stall = 0
        steps = 0
        self._finished = False
        while True:
            if self._dirty:
                # same certified pose, re-scored for the new targets / frozen set
                self._dirty = False
                self._restarted = set()
                self._grad, self._J, self._dxdc = self._gradient(
                    self._eq, opts.direction == "gauss-newton")
                stall = 0
                yield self._iterate(self._eq, self._grad)
                self._objective_at_start = self.history[-1].objective
            last = self.history[-1]
            reason = _stop_reason(self, last, stall, steps)
            step = self._step(last) if reason is None else None
            if step is None:
                if reason is not None:
                    self.converged, self.reason, self.status = reason
                if not self._out_of_budget(steps, last):
                    moved = self._restart(last)
                    if moved is not None:
                        stall = 0
                        yield moved
                        continue
                self.status += self._slack_note(last)
                self._finished = True
                return
            steps += 1
            if step.objective > last.objective * (1 - opts.ftol):
                stall += 1
            else:
                stall = 0
            yield step

    def _out_of_budget(self, steps: int, last: Iterate) -> bool:
        opts = self.options
        return (steps >= opts.max_iterations or last.objective <= self.floor
                or (opts.max_time is not None and last.t_wall >= opts.max_time))

    def _slack_winches(self, last: Iterate) -> list[int]:
        """Free winches with zero gradient because all their tendons are slack."""
        return slack_winches(self.model, last.x, last.contraction, ~self.frozen, last.gradient)

    def _slack_note(self, last: Iterate) -> str:
        slack = self._slack_winches(last)
        if not slack:
            return ""
        names = ", ".join(self.model.winch_names[w] for w in slack)
        return f"; winch {names}: all tendons slack (zero gradient)"

    def _restart(self, last: Iterate) -> Iterate | None:
        """Where the loop would stop, look a little further (see :mod:`.restart`)."""
        found = restart_move(self, last)
        return None if found is None else self._jump(*found)

    def _jump(self, c, eq) -> Iterate:
        """Continue the loop from a certified equilibrium found off the line search."""
        self.xi = self.bounds.to_xi(c)
        self.contraction = c
        self._eq = eq
        self.plant.commit(eq)
        self._grad, self._J, self._dxdc = self._gradient(eq, self.options.direction == "gauss-newton")
        self._mu = self.options.initial_damping
        self.status = "running"
        self.converged = False
        return self._iterate(eq, self._grad)

    def _step(self, last: Iterate) -> Iterate | None:
        opts = self.options
        gn = opts.direction == "gauss-newton"
        for attempt in range(opts.max_backtracks):
            step = _direction(self, last, self._mu)
            if not gn:
                step = step * 0.5 ** attempt
            xi_t = self.xi + step
            xi_t = self.bounds.clamp(xi_t)
            xi_t[self.frozen] = self.xi[self.frozen]
            c_t = self._f(xi_t)
            c_t[self.frozen] = self.contraction[self.frozen]      # bit-identical
            if np.array_equal(c_t, self.contraction):
                self.converged, self.reason, self.status = True, "stationary", self._at_bounds_status(last)
                return None
            eq = _trial(self, c_t)
            if eq.converged and self.targets.value(eq.x) < last.objective:
                self._accept(xi_t, eq, last)
                if gn:
                    self._mu = max(self._mu / opts.damping_decrease, opts.min_damping)
                return self._iterate(eq, self._grad)
            if gn:
                self._mu *= opts.damping_increase
        self.converged, self.reason = False, "no_decrease"
        self.status = ("cannot decrease the objective further: line search failed"
                       + (f"; bound active: {', '.join(last.active_bounds)}" if last.active_bounds else ""))
        return None

    def _at_bounds_status(self, last: Iterate) -> str:
        return ("stationary: every free winch is held at a bound"
                + (f"; bound active: {', '.join(last.active_bounds)}" if last.active_bounds else ""))

    def _predict(self, c_t):
        """First-order predictor x + dx/dc (c_t - c), if it is admissible."""
        x = self._eq.x
        if self._dxdc is not None:
            xp = x + self._dxdc @ (c_t - self.contraction)
            if self.model.admissible(xp):
                return xp
        return x

    def _accept(self, xi_t, eq, last):
        grad, self._J, self._dxdc = self._gradient(eq, self.options.direction == "gauss-newton")
        if self.options.direction == "gradient":
            # Barzilai-Borwein: s^T s / s^T y on xi
            s = xi_t - self.xi
            y = grad - last.gradient
            sy = float(s @ y)
            if sy > 0:
                self._bb_step = float(s @ s) / sy
        self.xi = xi_t
        self.contraction = eq.contraction.copy()
        self._eq = eq
        self.plant.commit(eq)
        self._grad = grad

    def result(self, eigenvalue: bool = True) -> ControlResult:
        """Run to the end (if not done yet) and collect the outcome.

        The final pose is certified once more by the plant as the end of the
        path of iterates (:meth:`Plant.finish`, with its smallest Hessian
        eigenvalue), so callers need no further solve for the result file."""
        if not self._finished:
            for _ in self.iterates():
                pass
        last = self.history[-1]
        eq = self.plant.finish(self._eq, np.array([it.contraction for it in self.history]),
                               EquilibriumOptions(eigenvalue=eigenvalue, escape_saddles=False), origin=CONTROL_ORIGIN)
        if eq is self._eq and not eigenvalue:
            eq = last.equilibrium            # nothing added: the last iterate as it is
        elif eq is not self._eq:             # the path's certified end: the history ends there
            self.history[-1], self._eq = dataclasses.replace(last, equilibrium=eq), eq
        converged = self.converged and eq.converged
        status = self.status if eq.converged else f"{self.status}; final pose: {eq.status}"
        names = self.model.winch_names
        stats = ControlStats(solver="gradient-loop", iterations=len(self.history) - 1,
                             equilibrium_solves=last.equilibrium_solves,
                             newton_iterations=last.newton_iterations,
                             t_wall=time.perf_counter() - self._t0)
        return ControlResult(
            method=self.options.bounds, converged=converged,
            reason=self.reason if eq.converged else "not_certified", status=status,
            equilibrium=eq, objective=float(self.targets.value(eq.x)),
            active_bounds=last.active_bounds,
            frozen=tuple(n for n, f in zip(names, self.frozen) if f),
            history=tuple(self.history), stats=stats, model=self.model, targets=self.targets)


def solve_control(model: Model, targets: Targets, contraction=None, frozen=None, x0=None,
                  options: ControlOptions | None = None) -> ControlResult:
    """Run the gradient loop to the end (see :class:`Controller`)."""
    return Controller(model, targets, contraction, frozen, x0, options).result()


def _stop_reason(ctl: "Controller", last: Iterate, stall: int, steps: int):
    """(converged, reason, status) when the loop should stop at ``last``, else None."""
    opts = ctl.options
    names = ctl.model.winch_names
    free = ~ctl.frozen
    bound_note = (f"; bound active: {', '.join(last.active_bounds)}" if last.active_bounds else "")
    if ctl.targets.n_targets == 0:
        return True, "targets_reached", "no targets"
    if not free.any():
        return True, "stationary", "every winch is frozen"
    if last.objective <= ctl.floor:
        return True, "targets_reached", "targets reached" + bound_note
    proj = last.gradient.copy()
    proj[[names.index(n) for n in last.active_bounds]] = 0.0
    span = float(np.mean(ctl.model.upper - ctl.model.lower))
    if np.all(last.gradient[free] == 0.0):
        slack = [names[i] for i in np.flatnonzero(free)]
        return False, "no_decrease", ("no free winch moves the targets (zero gradient: all tendons of "
                       f"{', '.join(slack)} slack)")
    if np.linalg.norm(proj) * span <= opts.gtol * max(last.objective, ctl.floor):
        return True, "stationary", "stationary: projected gradient below tolerance" + bound_note
    if stall >= opts.patience:
        return True, "stationary", "objective stopped decreasing (relative decrease below ftol)" + bound_note
    if steps >= opts.max_iterations:
        return False, "max_iterations", f"iteration limit ({opts.max_iterations}) reached" + bound_note
    if opts.max_time is not None and last.t_wall >= opts.max_time:
        return False, "max_time", f"time limit ({opts.max_time:g} s) reached" + bound_note
    return None


def _trial(ctl: "Controller", c_t) -> Equilibrium:
    """A line-search trial's equilibrium at ``c_t``, warm-started from the predictor.

    The plant reaches it from the current iterate (:meth:`Plant.trial`):
    on its stable branch where the pose does not depend on the path (a
    trial past a limit point fails in a few iterations instead of
    wandering after a snap-through), along the path where it does."""
    x0 = ctl._predict(c_t)
    eq = ctl.plant.trial(c_t, x0, _trial_options(ctl.options), origin=CONTROL_ORIGIN)
    ctl._solves += 1
    ctl._newton += eq.iterations
    return eq


def _trial_options(options: ControlOptions) -> EquilibriumOptions:
    """A line-search trial's equilibrium options: at most ``trial_newton`` iterations."""
    eo = options.equilibrium
    return dataclasses.replace(eo, max_iterations=min(eo.max_iterations, options.trial_newton))


def _direction(ctl: "Controller", last: Iterate, mu: float) -> np.ndarray:
    """A step on xi (or on c for clipping) for the free winches.

    Winches sitting on a bound whose step would push them further out
    are held (projected Gauss-Newton): otherwise a winch that cannot
    move would still take the length of the step from the others.
    """
    slope = ctl.bounds.slope(ctl.xi, ctl.options.slope_floor)
    g = last.gradient * slope
    lo_edge, hi_edge = ctl.bounds.edges()
    span = ctl.model.upper - ctl.model.lower
    at_lower = ctl.xi <= lo_edge + 1e-12 * span
    at_upper = ctl.xi >= hi_edge - 1e-12 * span
    held = ctl.frozen.copy()
    for _ in range(ctl.model.n_winches + 1):
        step = np.zeros_like(ctl.xi)
        move = ~held
        if not move.any():
            break
        if ctl.options.direction == "gauss-newton":
            J = ctl._J[:, move] * slope[move][None, :]
            A = J.T @ J
            # Levenberg damping on the scale of the largest curvature, so a
            # winch with a tiny column cannot take a huge step
            damp = mu * max(float(np.max(np.diag(A))), 1e-300)
            step[move] = -np.linalg.solve(A + damp * np.eye(A.shape[0]), g[move])
        else:
            if ctl._bb_step is None:
                ctl._bb_step = ctl.options.initial_gradient_step * float(np.mean(span)) / max(np.linalg.norm(g[move]), 1e-300)
            step[move] = -ctl._bb_step * g[move]
        outward = move & ((at_lower & (step < 0)) | (at_upper & (step > 0)))
        if not outward.any():
            break
        held |= outward
    limit = ctl.options.max_step * span
    ratio = np.max(np.abs(step) / limit)
    return step / ratio if ratio > 1 else step
