"""One reduced-space bilevel run: IPOPT rounds on c, stop rules, probes.

:class:`ReducedRun` drives :mod:`.bilevel_reduced` for
:class:`~plush_opt.control.bilevel.BilevelSolver`: an IPOPT round from the
certified start, then, where IPOPT stops at a point a local method cannot
judge (a winch whose tendons are all slack has a zero gradient; a winch
held at a bound may only see the first millimetres of a pull that engage
the "wrong" tendon first), the same look-further moves as the gradient
loop (:mod:`.policy`, docs/control.md): reel the slack in, probe inwards
from the bound; a move that lowers O starts a new IPOPT round from there.
A winch whose moves found nothing is tried again only once O has dropped
by probe_gain since (a later round may have moved the others so that its
slack now matters), so the rounds end. IPOPT is stopped by the loop's
stop rules too (:class:`~.policy.StopRules`, checked in
:data:`~.policy.REDUCED_ORDER` from its iteration callback).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ..base.errors import raise_if_interrupted
from ..fem.model import Model
from ..fem.objective import Targets
from ..solve.ipopt_equilibrium import build_interruptibly
from .bilevel_nlp import jsonable
from .bilevel_options import BilevelStats
from .bilevel_reduced import Evaluator, Point, build_solver, history_point
from .policy import (REDUCED_ORDER, ProbeSite, StallState, held_at_bounds, look_further,
                     projected_gradient)
from .slack import slack_winches

log = logging.getLogger(__name__)

#: The head of the status where the loop's stop rules stopped IPOPT (which
#: reports it as User_Requested_Stop, a word for the user's own stop).
STOPPED_BY_RULES = "stopped by the stop rules"
#: IPOPT return statuses counted as a KKT point.
KKT_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
# A winch within this fraction of its range from a bound, with the gradient
# pointing out, is held there (IPOPT's barrier keeps it about mu / |g| inside).
HELD_FRACTION = 1e-4
# The run "ended at its start" when no contraction moved by more than this
# fraction of its range.
START_FRACTION = 1e-9


class ReducedRun:
    """IPOPT on the free contractions from a certified start, with probes."""

    def __init__(self, model: Model, targets: Targets, options, frozen: np.ndarray, start, t_start):
        self.model, self.targets, self.options = model, targets, options
        self.frozen = frozen
        self.free = np.flatnonzero(~frozen)
        self.span = model.upper - model.lower
        self.t_start = t_start
        eq_opts = options.equilibrium
        self.ev = Evaluator(model, targets, start.contraction, self.free, start,
                            eq_opts if not eq_opts.eigenvalue else _no_eigenvalue(eq_opts),
                            options.hessian_damping, options.hessian_secant)
        self.start = self.ev.derivatives(self.ev.points[-1])
        self.history = [history_point(self.start, self.ev, 0, time.perf_counter() - t_start,
                                      self._held(self.start))]
        self.o_start = self.start.objective
        self.iterations = 0
        self.rounds: list[dict] = []
        self.moves: list[str] = []
        self.stop = None                  # our own stop: 'max_time', 'targets_reached'
        self.stationary = ""              # why the round ended by the loop's tests, if it did
        self.rules = options.stop_rules()
        self._stall: StallState = self.rules.init_state()
        self.return_status = "not run"
        self.t_build = 0.0
        self.t_ipopt = 0.0
        self.calls = {"ipopt_rounds": 0}

    # -- the stop rules IPOPT is given through its iteration callback ------

    def _rules(self, c_free) -> bool:
        """Record IPOPT's iterate at ``c_free``; True where the run stops there.

        The gradient loop's rules (:class:`~.policy.StopRules`), so both
        methods stop at the same accuracy: IPOPT's own tol is on its scaled
        KKT error, which the Newton tolerance of the evaluations can keep
        it from reaching (it then spends its line search on noise)."""
        t = time.perf_counter() - self.t_start
        point = self.ev.at(c_free)
        if point is not None:
            self.ev.accept(point)
            self.history.append(history_point(point, self.ev, len(self.history), t, self._held(point)))
            self._stall = self.rules.update(self._stall, point.objective)
        self.iterations += 1
        rule = self.rules.first(
            REDUCED_ORDER, self._stall, iterations=self.iterations, t=t,
            objective=None if point is None else point.objective,
            projected=None if point is None else self._projected(point))
        if rule in ("time", "reached", "iterations"):
            self.stop = {"time": "max_time", "reached": "targets_reached",
                         "iterations": "max_iterations"}[rule]
        elif rule == "stationary":
            self.stationary = "projected gradient below gtol"
        elif rule == "stalled":
            self.stationary = "objective stopped decreasing (relative decrease below ftol)"
        return self.stop is not None or bool(self.stationary)

    def _projected(self, point: Point) -> float:
        """|projected gradient| x the mean bound range (length^2, as O).

        A winch near a bound with its gradient pointing out counts as held
        only if going the rest of the way would change O by at most
        ftol x O: IPOPT's barrier keeps it a little inside, and with a steep
        gradient that little is not yet the answer."""
        g = self.gradient(point)
        opts = self.options
        negligible = opts.ftol * max(point.objective, opts.objective_floor)
        return projected_gradient(g, self._held_mask(point.c, g), self.span, point.c,
                                  self.model.lower, self.model.upper, negligible)

    # -- the run ------------------------------------------------------------

    def solve(self) -> None:
        n = len(self.free)
        m = self.ev.B.shape[0] + n
        t0 = time.perf_counter()
        solver, self._residual, self._recorder = build_interruptibly(
            build_solver, self.ev, n, m, self.options.reduced_ipopt_options(), self._rules)
        self.t_build = time.perf_counter() - t0
        lbx, ubx = self.model.lower[self.free], self.model.upper[self.free]
        point, tried = self.start, {}
        while True:
            if self.iterations >= self.options.max_iter:
                self.stop = "max_iterations"
                break
            self.stationary, self._stall = "", self.rules.init_state()
            self.ev.new_round()            # no secant pair, nor adapted damping, across a jump
            point = self._round(solver, point, lbx, ubx)
            if self.stop is not None or not self._kkt():
                break
            moved = self._look_further(point, tried)
            if moved is None:
                break
            point = moved
        self.end = self.ev.derivatives(self._best(point))

    def _round(self, solver, point: Point, lbx, ubx) -> Point:
        t0 = time.perf_counter()
        try:
            sol = solver(x0=point.c[self.free], lbx=lbx, ubx=ubx)
        except RuntimeError:
            raise_if_interrupted()         # a signal that reached a callback
            self.ev.raise_error()          # the callback's own error, if it was one
            raise
        finally:
            self.t_ipopt += time.perf_counter() - t0
        # an exception inside a callback stopped IPOPT: it is the real error
        raise_if_interrupted()
        self.ev.raise_error()
        stats = solver.stats()
        self.calls["ipopt_rounds"] += 1
        self.return_status = str(stats.get("return_status", "unknown"))
        c = np.clip(np.asarray(sol["x"], dtype=np.float64).reshape(-1), lbx, ubx)
        self.rounds.append({"from": point.c.tolist(), "status": self.return_status,
                            "iterations": int(stats.get("iter_count", 0))})
        end = self.ev.at(c)
        return end if end is not None else self._best(point)

    def _kkt(self) -> bool:
        """Did the last round end at a KKT point (IPOPT's or ours)?"""
        return self.return_status in KKT_STATUSES or bool(self.stationary)

    def _best(self, fallback: Point) -> Point:
        """The lowest certified point IPOPT has seen (its last iterate is
        normally it; a failed round may end elsewhere)."""
        seen = [h for h in self.history if h.equilibrium is not None]
        best = min(seen, key=lambda h: h.objective, default=None)
        if best is None or best.objective >= fallback.objective:
            return fallback
        return self.ev.at(best.contraction[self.free]) or fallback

    # -- look further where IPOPT stopped -----------------------------------

    def _held(self, point: Point) -> tuple[str, ...]:
        if point.J is None:
            return ()
        g = np.zeros(self.model.n_winches)
        g[self.free] = point.gradient()
        return tuple(self.model.winch_names[w] for w in self._held_mask(point.c, g))

    def _held_mask(self, c, g) -> list[int]:
        return held_at_bounds(c, g, self.model.lower, self.model.upper, HELD_FRACTION * self.span,
                              self.frozen)

    def gradient(self, point: Point) -> np.ndarray:
        g = np.zeros(self.model.n_winches)
        g[self.free] = self.ev.derivatives(point).gradient()
        return g

    def _look_further(self, point: Point, tried: dict) -> Point | None:
        """The gradient loop's restart moves (:func:`~.policy.look_further`), from ``point``.

        ``tried`` maps a winch to O where its moves were last tried (updated
        here): it is tried again only from a point lower by probe_gain (each
        later round lowers O, so this ends)."""
        model = self.model
        g = self.gradient(point)
        site = ProbeSite(point.c, point.eq.x, point.objective, self.o_start,
                         slack_winches(model, point.eq.x, point.c, ~self.frozen, g),
                         self._held_mask(point.c, g))

        def solve(c):
            trial = self.ev.at(c[self.free], on_branch=False)
            return None if trial is None else (trial.objective, trial)

        move, now = look_further(self.options.probe, site, tried, model, solve, self.gradient)
        tried.update(now)
        if move is None:
            return None
        name = model.winch_names[move.winch]
        if move.kind == "slack":
            return self._moved(move.result, f"took up the slack of {name}")
        return self._moved(move.result, f"probe moved {move.describe(model.winch_names)}")

    def _moved(self, point: Point, what: str) -> Point:
        log.info("bilevel: %s (O = %.6g)", what, point.objective)
        self.moves.append(what)
        t = time.perf_counter() - self.t_start
        self.history.append(history_point(self.ev.derivatives(point), self.ev, len(self.history), t,
                                          self._held(point)))
        return point

    # -- verdict ------------------------------------------------------------

    def verdict(self) -> tuple[bool, str, str]:
        """(converged, reason, status) of the run."""
        end, opts = self.end, self.options
        # IPOPT reports a stop by our own rules as User_Requested_Stop: say whose rule it was
        ours = self.return_status == "User_Requested_Stop" and (self.stop is not None or self.stationary)
        head = f"ipopt (reduced): {STOPPED_BY_RULES if ours else self.return_status}"
        g = self.gradient(end)
        pg = self._projected(end)
        at_start = bool(np.all(np.abs(end.c - self.start.c) <= START_FRACTION * self.span))
        note = self._notes(end, g)
        if self.stop == "targets_reached":
            return True, "targets_reached", f"{head}; targets reached (O <= objective_floor){note}"
        if self.stop == "max_time":
            return False, "max_time", f"{head}; time limit ({opts.max_time:g} s) reached{note}"
        if self.stop == "max_iterations" or self.return_status == "Maximum_Iterations_Exceeded":
            return False, "max_iterations", f"{head}; iteration limit ({opts.max_iter}) reached{note}"
        if not self._kkt():
            # NaN residuals are how a point with no certified equilibrium
            # reaches IPOPT: say so, or Invalid_Number_Detected reads as a bug
            failed = (f"; no certified equilibrium at {self.ev.failures} of the "
                      f"{self.ev.solves} points tried" if self.ev.failures else "")
            return False, "solver_failed", (f"{head}{failed}; returned the best certified iterate "
                                            f"(projected gradient {pg:.3g}){note}")
        slack = slack_winches(self.model, end.eq.x, end.c, ~self.frozen, g)
        gn = float(np.linalg.norm(g)) * float(np.mean(self.span))
        if at_start and (slack or gn > opts.gtol * max(end.objective, opts.objective_floor)):
            # a KKT point with a bound held (or a winch with no gradient at
            # all) where it started: the look-further moves found nothing
            # better, but nothing shows it is a minimum either
            return False, "no_decrease", (f"{head}; ended at its start (gradient {gn:.3g}, "
                                          f"projected {pg:.3g}); no move lowered O{note}")
        how = f"; {self.stationary}" if self.stationary else ""
        return True, "stationary", f"{head}{how}; certified{note}"

    def _notes(self, end: Point, g) -> str:
        names = self.model.winch_names
        held = [names[w] for w in self._held_mask(end.c, g)]
        slack = slack_winches(self.model, end.eq.x, end.c, ~self.frozen, g)
        out = ""
        if self.moves:
            out += "; " + "; ".join(self.moves)
        if held:
            out += f"; bound active: {', '.join(held)}"
        if slack:
            out += f"; winch {', '.join(names[w] for w in slack)}: all tendons slack (zero gradient)"
        return out

    # -- report -------------------------------------------------------------

    def stats(self, start_info: dict) -> BilevelStats:
        """What the run measured (the result file's ``bilevel`` section);
        ``start_info`` describes the starting equilibrium."""
        model, options, end = self.model, self.options, self.end
        names = model.winch_names
        g = self.gradient(end)
        t_eval = self.ev.t_evaluations
        return BilevelStats(
            start=start_info, objective_certified=end.objective, formulation="reduced",
            moves=self.moves, rounds=self.rounds, return_status=self.return_status,
            ipopt_success=self.return_status in KKT_STATUSES, iter_count=self.iterations,
            stopped_by_time_limit=self.stop == "max_time", t_build=self.t_build, cached_solver=False,
            t_ipopt_total=self.t_ipopt, t_function_evaluations=t_eval,
            t_inside_ipopt=max(self.t_ipopt - t_eval, 0.0),
            calls={**self.calls, "equilibrium_solves": self.ev.solves, "failed_equilibrium_solves":
                   self.ev.failures, "known_past_branch_end": self.ev.past_end},
            options={"ipopt": jsonable(options.reduced_ipopt_options()), "gtol": options.gtol,
                     "ftol": options.ftol, "patience": options.patience,
                     "objective_floor": options.objective_floor, "max_time": options.max_time},
            frozen=[names[i] for i in np.flatnonzero(self.frozen)],
            contraction_ipopt={names[i]: float(end.c[i]) for i in range(model.n_winches)},
            bound_violation=0.0, objective_ipopt=end.objective,
            kkt={"gradient": {names[i]: float(g[i]) for i in self.free}},
            active_bounds=[names[w] for w in self._held_mask(end.c, g)],
            slack_winches=[names[w] for w in slack_winches(model, end.eq.x, end.c, ~self.frozen, g)],
            equilibrium_solves=self.ev.solves + 1, history_points=len(self.history))


def _no_eigenvalue(options):
    from dataclasses import replace
    return replace(options, eigenvalue=False)
