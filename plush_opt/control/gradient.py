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

Its options are :mod:`.gradient_options`; the step (direction and line
search) is :mod:`.step`; the stop rules and the look-further moves are
:mod:`.policy`, shared with the reduced bilevel search.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from ..solve.equilibrium import Equilibrium, EquilibriumOptions
from ..base.errors import SolverError
from ..fem.model import Model
from ..fem.objective import Targets
from ..solve.plant import Plant, make_plant
from .bounds import bounds_strategy
from .kink import kink_verdict, probe_kink
from .gradient_options import BOUNDS, DIRECTIONS, ControlOptions  # noqa: F401 (re-exported)
from .policy import (LOOP_ORDER, ProbeSite, StallState, StopRules, held_at_bounds, look_further, predict,
                     projected_gradient)
from .result import INTERRUPTED, ControlIterate, ControlResult, ControlStats
from .slack import slack_winches
from .step import line_search, search_direction

log = logging.getLogger(__name__)

# where a path-dependent plant's iterates were driven from (recorded on them)
CONTROL_ORIGIN = "the control run's starting state, then its accepted iterates in order"


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
        # restart moves used since the targets / frozen set last changed: winch
        # -> O where it was tried (each at most once, so the loop cannot cycle)
        self._restarted: dict[int, float] = {}

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
        model = self.model
        held = held_at_bounds(c, grad_c, model.lower, model.upper, self.bounds.margin(), self.frozen)
        return tuple(model.winch_names[i] for i in held)

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
        eq = self._solve(self.contraction, self._x0, _start_options(self.options, self.plant))
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
        # the stall count, measured from the iterate the loop (re)starts at
        stall = self._rules().init_state(self.history[-1].objective)
        steps = 0
        self._finished = False
        while True:
            if self._dirty:
                # same certified pose, re-scored for the new targets / frozen set
                self._dirty = False
                self._restarted = {}
                self._grad, self._J, self._dxdc = self._gradient(self._eq, opts.direction == "gauss-newton")
                yield self._iterate(self._eq, self._grad)
                stall = self._rules().init_state(self.history[-1].objective)
                self._objective_at_start = self.history[-1].objective
            last = self.history[-1]
            reason = _stop(self.options, self._rules(), last, stall, steps, self.targets.n_targets,
                           self.frozen, self.model)
            step = self._step(last) if reason is None else None
            if step is None:
                if reason is not None:
                    self.converged, self.reason, self.status = reason
                if not self._rules().exhausted(last.objective, steps, last.t_wall):
                    moved = self._restart(last)
                    if moved is None:
                        moved = self._kink(last, searched=reason is None)
                        steps += moved is not None      # (a move at the kink is a step of the budget)
                    if moved is not None:
                        stall = self._rules().init_state(moved.objective)
                        yield moved
                        continue
                self.status += _slack_note(self.model, last, self.frozen)
                self._finished = True
                return
            steps += 1
            stall = self._rules().update(stall, step.objective)
            yield step

    def _rules(self) -> StopRules:
        """The stop rules, with the floor of the current targets."""
        return self.options.stop_rules(self.floor)

    def _restart(self, last: Iterate) -> Iterate | None:
        """Where the loop would stop, look a little further (:func:`_look_further`)."""
        def solve(c):
            eq = self._solve(c, last.x)
            return (self.targets.value(eq.x), eq) if eq.converged else None

        move, self._restarted = _look_further(
            self.options, self.model, last, self._objective_at_start, _slack(self.model, last, self.frozen),
            self._restarted, solve, lambda eq: self._gradient(eq, False)[0])
        return None if move is None else self._jump(move.contraction, move.result)

    def _kink(self, last: Iterate, searched: bool) -> Iterate | None:
        """The test at the kink (:func:`.kink.probe_kink`) where a path-dependent plant's loop would
        stop after a line search (``searched``) or stationary: its move, or None with the verdict set."""
        rule = self.options.kink
        if not (self.plant.path_dependent and rule.steps and (searched or self.reason == "stationary")):
            return None
        found = probe_kink(rule, last.contraction, last.objective, self.frozen, self.model.lower,
                           self.model.upper, self._trial, lambda eq: self.targets.value(eq.x))
        if found.moved:
            log.info("at the kink: O %.6g -> %.6g by %s", last.objective, found.objective, found.contraction)
            return self._jump(found.contraction, found.equilibrium)
        self.converged, self.reason, self.status = kink_verdict(
            rule, found, (self.converged, self.reason, self.status), self.plant.path_cause,
            _bound_note(last, self.model, self.options.gtol))
        return None

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
        """The next iterate by a line search from ``last``, or None (status set)."""
        roundoff, history = self.targets.roundoff(last.x), self.plant.path_dependent
        found = line_search(self.xi, self.contraction, self.frozen, self.bounds, last.objective,
                            self.options, self._mu, lambda mu: self._direction(last, mu),
                            self._trial, lambda eq: self.targets.value(eq.x), self.options.predicted_trials(history),
                            None if history else last.gradient, roundoff)   # (history: O is not smooth in c)
        self._mu = found.mu
        if found.kind == "accepted":
            self._accept(found.xi, found.equilibrium, last)
            return self._iterate(found.equilibrium, self._grad)
        self.converged, self.reason, self.status = _search_verdict(found, last, self.model, self.options,
                                                                   self.plant, roundoff)
        return None

    def _direction(self, last: Iterate, mu: float) -> np.ndarray:
        """The step on xi from ``last`` with damping ``mu`` (:func:`.direction.search_direction`)."""
        step, self._bb_step = search_direction(last.gradient, self._J, self.xi, self.frozen, self.bounds,
                                               self.model.upper - self.model.lower, self.options, mu,
                                               self._bb_step)
        return step

    def _predict(self, c_t):
        """First-order predictor x + dx/dc (c_t - c), if it is admissible."""
        return predict(self.model, self._eq.x, self._dxdc, self.contraction, c_t)

    def _trial(self, c_t) -> Equilibrium:
        """A line-search trial's equilibrium at ``c_t``, warm-started from the
        predictor and reached by the plant from the current iterate
        (:meth:`Plant.trial`: on its stable branch, or along the path)."""
        eq = self.plant.trial(c_t, self._predict(c_t), _trial_options(self.options), origin=CONTROL_ORIGIN)
        self._solves += 1
        self._newton += eq.iterations
        return eq

    def _accept(self, xi_t, eq, last):
        grad, self._J, self._dxdc = self._gradient(eq, self.options.direction == "gauss-newton")
        if self.options.direction == "gradient":
            s, y = xi_t - self.xi, grad - last.gradient     # Barzilai-Borwein: s^T s / s^T y on xi
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
        try:              # (a signal during the final certification too)
            for _ in () if self._finished else self.iterates():
                pass
            last = self.history[-1]
            eq = self.plant.finish(self._eq, np.array([it.contraction for it in self.history]),
                                   EquilibriumOptions(eigenvalue=eigenvalue, escape_saddles=False), origin=CONTROL_ORIGIN)
        except KeyboardInterrupt as exc:      # Ctrl-C, or SIGTERM/SIGHUP as Interrupted
            # the caller may still report where the run got to
            exc.partial_result = interrupted_result(self, exc) if self.history else None
            raise
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


def interrupted_result(ctrl: Controller, exc: BaseException) -> ControlResult:
    """The run of ``ctrl`` so far, ended by a signal: its last accepted
    iterate (a certified equilibrium, not certified again), ``converged``
    false, reason :data:`INTERRUPTED`, the signal's name in ``status``
    (``interrupted by SIGTERM``)."""
    from ..base.errors import interrupt_status
    last = ctrl.history[-1]
    names = ctrl.model.winch_names
    stats = ControlStats(solver="gradient-loop", iterations=len(ctrl.history) - 1,
                         equilibrium_solves=ctrl._solves, newton_iterations=ctrl._newton,
                         t_wall=time.perf_counter() - ctrl._t0)
    return ControlResult(
        method=ctrl.options.bounds, converged=False, reason=INTERRUPTED,
        status=f"{INTERRUPTED} by {interrupt_status(exc)[0]}", equilibrium=last.equilibrium,
        objective=float(last.objective), active_bounds=last.active_bounds,
        frozen=tuple(n for n, f in zip(names, ctrl.frozen) if f),
        history=tuple(ctrl.history), stats=stats, model=ctrl.model, targets=ctrl.targets)


def solve_control(model: Model, targets: Targets, contraction=None, frozen=None, x0=None,
                  options: ControlOptions | None = None) -> ControlResult:
    """Run the gradient loop to the end (see :class:`Controller`)."""
    return Controller(model, targets, contraction, frozen, x0, options).result()


def _slack(model: Model, last: Iterate, frozen) -> list[int]:
    """Free winches with zero gradient at ``last`` because all their tendons are slack."""
    return slack_winches(model, last.x, last.contraction, ~frozen, last.gradient)


def _slack_note(model: Model, last: Iterate, frozen) -> str:
    """``; winch NAMES: all tendons slack (zero gradient)``, or empty."""
    slack = _slack(model, last, frozen)
    if not slack:
        return ""
    return f"; winch {', '.join(model.winch_names[w] for w in slack)}: all tendons slack (zero gradient)"


def _stop(options: ControlOptions, rules: StopRules, last: Iterate, stall: StallState, steps: int,
          n_targets: int, frozen: np.ndarray, model: Model):
    """The loop's (converged, reason, status) when it should stop at
    ``last`` (after ``steps`` steps, with stall state ``stall``), else None."""
    if n_targets == 0:
        return True, "targets_reached", "no targets"
    free = ~frozen
    if not free.any():
        return True, "stationary", "every winch is frozen"
    names = model.winch_names
    held = [names.index(n) for n in last.active_bounds]
    rule = rules.first(
        LOOP_ORDER, stall, objective=last.objective, iterations=steps, t=last.t_wall,
        projected=projected_gradient(last.gradient, held, model.upper - model.lower),
        no_gradient=bool(np.all(last.gradient[free] == 0.0)))
    if rule is None:
        return None
    return _verdict(rule, last, options, [names[i] for i in np.flatnonzero(free)], model)


def _look_further(options: ControlOptions, model: Model, last: Iterate, objective_at_start: float,
                  slack: list[int], tried: dict, solve, gradient):
    """The loop's look-further move from ``last`` (:func:`~.policy.look_further`,
    each winch once per set of targets, so the loop cannot cycle through
    the moves); (move or None, the new ``tried``)."""
    names = model.winch_names
    site = ProbeSite(last.contraction, last.x, last.objective, objective_at_start, slack,
                     [names.index(n) for n in last.active_bounds])
    move, tried = look_further(options.probe, site, tried, model, solve, gradient)
    if move is not None and move.kind == "slack":
        log.info("took up the slack of %s", names[move.winch])
    elif move is not None:
        log.info("probe: moving %s lowered O", move.describe(names))
    return move, tried


def _start_options(options: ControlOptions, plant: Plant) -> EquilibriumOptions:
    """The starting solve's options: continuation where it fails from the
    start pose, on a history-free plant (with history the path is the physics)."""
    steps = 0 if plant.path_dependent else options.start_continuation
    return dataclasses.replace(options.equilibrium, continuation=steps)


def _search_verdict(found, last: Iterate, model: Model, options: ControlOptions, plant: Plant,
                    roundoff: float = 0.0):
    """The loop's (converged, reason, status) after a line search from
    ``last`` that accepted nothing (``found``: its outcome, :func:`.step.line_search`;
    ``roundoff``: O's round-off at ``last``). A step that vanished under
    the damping is a failed search, not one that moves no winch (on a
    path-dependent plant its stop is then tested at the kink, :mod:`.kink`)."""
    note = _bound_note(last, model, options.gtol, _unheld_gradient(last, model) if found.kind == "below_roundoff"
                       else 0.0)
    if found.kind == "stationary":
        return True, "stationary", "stationary: every free winch is held at a bound" + note
    if found.kind == "below_roundoff":
        return True, "stationary", (f"stationary to the objective's round-off: no step tried could lower O by "
                                    f"more than {max(found.predicted, 0.0):.2g} to first order, below its "
                                    f"round-off {roundoff:.2g}" + note)
    if plant.path_dependent:
        failed = stalled_on(plant.path_cause)
    else:
        failed = LINE_SEARCH_FAILED + (BRANCH_AHEAD if found.branch_ends else "")
    return False, "no_decrease", failed + note


#: The status of a line search that found no decrease.
LINE_SEARCH_FAILED = "cannot decrease the objective further: line search failed"
#: ... where no trial had a certified pose because each left the stable branch
BRANCH_AHEAD = (" (the stable branch ends just ahead, a limit point where the pose would snap: every trial step "
                "left it)")


def stalled_on(cause: str) -> str:
    """The status of a line search that found no decrease where the pose
    depends on the path (``cause``: the plant's ``path_cause``, e.g.
    "friction at via points"): the objective is not smooth in the
    contractions there, and the step the sensitivities propose can raise
    it at any length."""
    return (f"stalled: no trial step lowered O ({cause}: O is not smooth in the contractions, "
            "the sensitivities hold for the current stick/slip state only); the pose is the best certified "
            "iterate, not a proven optimum (another path may end lower: --method clip, --direction gradient "
            "or other starting contractions)")


#: A held winch within this fraction of its range from its bound is "at" it.
AT_BOUND = 1e-9


def _bound_note(last: Iterate, model: Model, gtol: float, floor: float = 0.0) -> str:
    """``; bound active: NAMES``: the held winches at their bound, and those
    held inside it (the reparametrised bounds' blend zone) with how far,
    where their gradient times their range is not negligible (above
    ``gtol`` x O, as the loop's stationarity test, and above ``floor``):
    one there with a negligible gradient is at an interior stationary
    point, not held by its bound."""
    parts = []
    for name in last.active_bounds:
        w = model.winch_names.index(name)
        c, lo, hi = float(last.contraction[w]), float(model.lower[w]), float(model.upper[w])
        side, bound = ("lower", lo) if c - lo <= hi - c else ("upper", hi)
        gap = abs(c - bound)
        if gap <= AT_BOUND * (hi - lo):
            parts.append(name)
        elif abs(float(last.gradient[w])) * (hi - lo) > max(gtol * last.objective, floor):
            parts.append(f"{name} (held {gap:.3g} inside its {side} bound {bound:g} by the reparametrised bounds)")
    return "; bound active: " + ", ".join(parts) if parts else ""


def _unheld_gradient(last: Iterate, model: Model) -> float:
    """The largest |dO/dc| times range of the winches no bound holds (a
    frozen one's gradient is 0): where the loop stops on O's round-off, a
    gradient of that size moved none of them, so a winch inside its bound
    with one no larger is not held by the bound (the gripper's `right`
    0.24 inside its lower bound, where clip ends too)."""
    held = {model.winch_names.index(name) for name in last.active_bounds}
    return max((abs(float(last.gradient[w])) * float(model.upper[w] - model.lower[w])
                for w in range(len(model.winch_names)) if w not in held), default=0.0)


def _verdict(rule: str, last: Iterate, options: ControlOptions, free_names: list[str], model: Model):
    """The loop's (converged, reason, status) for stop rule ``rule``
    (:data:`~.policy.RULES`) at ``last``; ``free_names`` the free winches."""
    note = _bound_note(last, model, options.gtol)
    if rule == "no_gradient":
        return False, "no_decrease", ("no free winch moves the targets (zero gradient: all tendons of "
                                      f"{', '.join(free_names)} slack)")
    if rule == "reached":
        return True, "targets_reached", "targets reached" + note
    if rule == "stationary":
        return True, "stationary", "stationary: projected gradient below tolerance" + note
    if rule == "stalled":
        return True, "stationary", "objective stopped decreasing (relative decrease below ftol)" + note
    if rule == "iterations":
        return False, "max_iterations", f"iteration limit ({options.max_iterations}) reached" + note
    return False, "max_time", f"time limit ({options.max_time:g} s) reached" + note


def _trial_options(options: ControlOptions) -> EquilibriumOptions:
    """A line-search trial's equilibrium options: at most ``trial_newton`` iterations."""
    eo = options.equilibrium
    return dataclasses.replace(eo, max_iterations=min(eo.max_iterations, options.trial_newton))
