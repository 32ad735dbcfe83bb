"""Method 2: the bilevel problem (the equilibrium as a constraint of the
control problem), solved by IPOPT; the front of the method.

:class:`BilevelSolver` checks the start, solves the certified starting
equilibrium (with the slack of slack winches taken up) and runs one of two
formulations (``BilevelOptions.formulation``):

* 'reduced' (the default, :mod:`.bilevel_search` over
  :mod:`.bilevel_reduced`): IPOPT on the contractions alone, the pose
  eliminated through the certified equilibrium; every iterate is a stable
  equilibrium, and the gradient loop's stop rules and look-further moves
  apply (:mod:`.policy`);
* 'full' (:mod:`.bilevel_full` over :mod:`.bilevel_nlp`): IPOPT on pose
  and contractions with grad_x E = 0 as a constraint, certified afterwards.
  The solver keeps each built NLP per (frozen set, target triangles,
  options): moving a target within its triangle does not rebuild it.

Both give one :class:`~plush_opt.control.result.ControlResult` whose
equilibrium is certified (a saddle is never returned as a pose).
docs/bilevel.md has the formulations and the options that matter.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np

from ..solve.equilibrium import certify, solve_equilibrium
from ..solve.ipopt_equilibrium import build_interruptibly
from ..base.errors import SolverError
from ..fem.model import Model
from ..fem.objective import Targets
from .bilevel_full import FullRun
from .bilevel_nlp import build_nlp
from .bilevel_options import ALPHA_FOR_Y, FORMULATIONS, BilevelOptions, BilevelStats
from .bilevel_search import ReducedRun
from .result import INTERRUPTED, ControlResult, ControlStats
from .slack import slack_winches, take_up

__all__ = ["ALPHA_FOR_Y", "FORMULATIONS", "BilevelOptions", "BilevelSolver", "BilevelStats",
           "solve_bilevel"]

log = logging.getLogger(__name__)


class BilevelSolver:
    """The bilevel method for one model, keeping its built NLPs.

    Building IPOPT's NLP (and its exact Lagrangian Hessian) is the
    expensive part; a solver keeps one per (frozen set, target triangles,
    options), so moving a target or re-running is cheap.
    """

    def __init__(self, model: Model):
        self.model = model
        self._entries: dict = {}
        self._store: dict = {}     # grad_x E, shared by every entry

    def clear(self) -> None:
        """Drop the built NLPs."""
        self._entries.clear()

    def _entry(self, frozen: np.ndarray, targets: Targets, options: BilevelOptions):
        """The NLP for this frozen set, target triangles and options; (entry, built_now)."""
        key = (tuple(bool(f) for f in frozen), targets.nodes.tobytes(), targets.n_targets,
               repr(sorted(options.ipopt_options().items())), options.min_jacobian, options.expand)
        if key not in self._entries:
            self._entries[key] = build_interruptibly(build_nlp, self.model, frozen, targets.nodes, options,
                                                     self._store)
            return self._entries[key], True
        return self._entries[key], False

    def solve(self, targets: Targets, contraction0=None, frozen=None, x0=None,
              options: BilevelOptions | None = None) -> ControlResult:
        """Contractions that bring the equilibrium to the targets, by IPOPT on
        the KKT formulation, certified by Newton.

        Parameters
        ----------
        targets : where body points should go.
        contraction0 : (n_winches,) start, within bounds (default: the scene's).
            The equilibrium there (Newton) is IPOPT's starting point.
        frozen : (n_winches,) bool, winches kept at ``contraction0`` (default:
            the scene's ``frozen`` flags).
        x0 : starting pose for that first Newton solve (flat or (n_nodes, 2)).
        options : :class:`BilevelOptions`.

        Raises
        ------
        SolverError
            Bad sizes, a start outside the bounds, or a starting equilibrium
            that cannot be certified.
        SceneError
            A scene whose pose depends on the path (friction at via
            points): the method has no history.
        """
        from ..solve.plant import make_plant     # a pose that depends on the path: refuse, never solve without it
        make_plant(self.model).require_history_free("the bilevel method",
                                                    "use --method reparam or clip (they follow the path)")
        options = options or BilevelOptions()
        t_start = time.perf_counter()
        c0, frozen = _checked_start(self.model, contraction0, frozen)
        start, taken = _start(self.model, targets, c0, frozen, x0, options)
        start_info = {"contraction": start.contraction.tolist(),
                      "objective": float(targets.value(start.x)),
                      "t_wall": time.perf_counter() - t_start,
                      "slack_taken_up": [self.model.winch_names[w] for w in taken]}
        if targets.n_targets == 0 or frozen.all():
            status = "no targets" if targets.n_targets == 0 else "every winch is frozen"
            stats = BilevelStats(start=start_info, objective_certified=float(targets.value(start.x)))
            return self._result(targets, frozen, start, True,
                                "targets_reached" if targets.n_targets == 0 else "stationary",
                                status, (), 0, 0.0, stats, t_start)
        if options.formulation == "reduced":
            return self._solve_reduced(targets, frozen, start, start_info, options, t_start)
        run = FullRun(self.model, targets, options, frozen, start, taken, start_info)
        try:        # (a signal during the final certification too)
            run.entry, run.built = self._entry(frozen, targets, options)
            run.solve()
            run.certify()
            return self._result(targets, frozen, run.eq, run.ok, run.reason(), run.status(),
                                run.history, run.iterations, run.entry.t_build if run.built else 0.0,
                                run.stats(), t_start)
        except KeyboardInterrupt as exc:      # IPOPT's iterates are not poses: the start is the last certified one
            exc.partial_result = self._interrupted(targets, frozen, start, getattr(run, "history", ()), start_info,
                                                   "full", t_start, exc)
            raise

    def _solve_reduced(self, targets, frozen, start, start_info, options, t_start) -> ControlResult:
        run = ReducedRun(self.model, targets, options, frozen, start, t_start)
        try:        # (a signal during the final certification too)
            run.solve()
            ok, reason, status = run.verdict()
            return self._result(targets, frozen, run.end.eq, ok, reason, status, run.history,
                                run.iterations, run.t_build, run.stats(start_info), t_start)
        except KeyboardInterrupt as exc:      # the lowest certified iterate so far
            seen = [h for h in run.history if h.dispatchable]
            best = min(seen, key=lambda h: h.objective).equilibrium if seen else start
            exc.partial_result = self._interrupted(targets, frozen, best, run.history, start_info, "reduced",
                                                   t_start, exc)
            raise

    def _result(self, targets, frozen, eq, ok, reason, status, history, iterations, t_setup,
                stats: BilevelStats, t_start) -> ControlResult:
        model = self.model
        names = model.winch_names
        eq = certify(model, eq)
        common = ControlStats(solver="ipopt", iterations=int(iterations),
                              equilibrium_solves=int(stats.equilibrium_solves or 1),
                              newton_iterations=int(eq.iterations),
                              t_wall=time.perf_counter() - t_start, t_setup=float(t_setup),
                              details=stats)
        log.info("bilevel: %s; O = %.6g; %d iterations", status, stats.objective_certified, iterations)
        return ControlResult(
            method="bilevel", converged=bool(ok), reason=reason, status=status, equilibrium=eq,
            objective=float(stats.objective_certified), active_bounds=tuple(stats.active_bounds or ()),
            frozen=tuple(names[i] for i in np.flatnonzero(frozen)), history=tuple(history),
            stats=common, model=model, targets=targets)


    def _interrupted(self, targets, frozen, eq, history, start_info, formulation, t_start,
                     exc: BaseException) -> ControlResult:
        """The run so far, ended by a signal: ``eq`` (a certified equilibrium,
        not certified again), ``history`` (the iterates recorded), ``converged`` false, reason ``interrupted``, the
        signal's name in ``status`` (``interrupted by SIGTERM``)."""
        from ..base.errors import interrupt_status
        names = self.model.winch_names
        objective = float(targets.value(eq.x))
        iterates = tuple(history)
        stats = BilevelStats(start=start_info, objective_certified=objective, formulation=formulation,
                             history_points=len(iterates))
        common = ControlStats(solver="ipopt", iterations=max(len(iterates) - 1, 0), equilibrium_solves=1,
                              newton_iterations=int(eq.iterations), t_wall=time.perf_counter() - t_start,
                              details=stats)
        return ControlResult(
            method="bilevel", converged=False, reason=INTERRUPTED,
            status=f"{INTERRUPTED} by {interrupt_status(exc)[0]}", equilibrium=eq, objective=objective,
            active_bounds=(), frozen=tuple(names[i] for i in np.flatnonzero(frozen)), history=iterates,
            stats=common, model=self.model, targets=targets)


def solve_bilevel(model: Model, targets: Targets, contraction0=None, frozen=None, x0=None,
                  options: BilevelOptions | None = None, solver: BilevelSolver | None = None
                  ) -> ControlResult:
    """:meth:`BilevelSolver.solve` with ``solver`` (a new one if None: no NLP reuse)."""
    return (solver or BilevelSolver(model)).solve(targets, contraction0, frozen, x0, options)


def _checked_start(model: Model, contraction0, frozen) -> tuple[np.ndarray, np.ndarray]:
    c0 = model.scene.contraction.copy() if contraction0 is None \
        else np.array(contraction0, dtype=np.float64).reshape(-1)
    if c0.shape != (model.n_winches,):
        raise SolverError(f"contraction: expected {model.n_winches} values, got {c0.size}")
    if np.any(c0 < model.lower) or np.any(c0 > model.upper):
        raise SolverError("contraction: outside the winch bounds "
                          f"{list(zip(model.lower.tolist(), model.upper.tolist()))}: {c0.tolist()}")
    frozen = model.scene.frozen.copy() if frozen is None else np.array(frozen, dtype=bool).reshape(-1)
    if frozen.shape != (model.n_winches,):
        raise SolverError(f"frozen: expected {model.n_winches} flags, got {frozen.size}")
    return c0, frozen


def _start(model: Model, targets: Targets, c0, frozen, x0, options: BilevelOptions):
    """The certified starting equilibrium, with the slack taken up; (eq, winches taken up)."""
    quick = replace(options.equilibrium, eigenvalue=False)
    start = solve_equilibrium(model, c0, x0, replace(quick, continuation=options.start_continuation))
    if not start.converged:
        raise SolverError(f"the starting equilibrium is not certified: {start.status}")
    if not (options.take_up_slack and targets.n_targets):
        return start, []
    free = ~frozen
    taken = slack_winches(model, start.x, c0, free)
    if not taken:
        return start, []
    c1 = c0.copy()
    for w in taken:
        c1[w] = min(take_up(model, start.x, c0, w), model.upper[w])
    moved = solve_equilibrium(model, c1, start.x, quick)
    return (moved, taken) if moved.converged else (start, [])
