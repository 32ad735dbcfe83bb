"""One reduced-space bilevel run: IPOPT rounds on c, stop rules, probes.

:class:`ReducedRun` drives :mod:`.bilevel_reduced` for
:class:`~plush_opt.control.bilevel.BilevelSolver`: an IPOPT round from the
certified start, then, where IPOPT stops at a point a local method cannot
judge (a winch whose tendons are all slack has a zero gradient; a winch
held at a bound may only see the first millimetres of a pull that engage
the "wrong" tendon first), the same look-further moves as the gradient
loop (docs/control.md): reel the slack in, probe inwards from the bound;
a move that lowers O starts a new IPOPT round from there. A winch whose
moves found nothing is tried again only once O has dropped by probe_gain
since (a later round may have moved the others so that its slack now
matters: the 3,303-node tentacle's left_tip), so the rounds end.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from ..fem.model import Model
from ..fem.objective import Targets
from .bilevel_reduced import Evaluator, Point, build_solver, history_point
from .slack import slack_winches, take_up

log = logging.getLogger(__name__)

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
        self._stall, self._last = 0, math.inf
        self.return_status = "not run"
        self.t_build = 0.0
        self.t_ipopt = 0.0
        self.calls = {"ipopt_rounds": 0}

    # -- the stop rules IPOPT is given through its iteration callback ------

    def _rules(self, c_free) -> bool:
        t = time.perf_counter() - self.t_start
        point = self.ev.at(c_free)
        if point is not None:
            self.ev.accept(point)
            self.history.append(history_point(point, self.ev, len(self.history), t, self._held(point)))
        self.iterations += 1
        opts = self.options
        if opts.max_time is not None and t >= opts.max_time:
            self.stop = "max_time"
        elif point is not None and point.objective <= opts.objective_floor:
            self.stop = "targets_reached"
        elif self.iterations >= opts.max_iter:
            self.stop = "max_iterations"
        elif point is not None:
            # the gradient loop's stationarity tests, so both methods stop at
            # the same accuracy (IPOPT's own tol is on its scaled KKT error,
            # which the Newton tolerance of the evaluations can keep it from
            # reaching: it then spends its line search on noise)
            self._stall = self._stalled(point.objective)
            self._last = min(self._last, point.objective)
            if self._projected(point) <= opts.gtol * max(point.objective, opts.objective_floor):
                self.stationary = "projected gradient below gtol"
            elif self._stall >= opts.patience:
                self.stationary = "objective stopped decreasing (relative decrease below ftol)"
        return self.stop is not None or bool(self.stationary)

    def _stalled(self, objective: float) -> int:
        """The stall count after an iterate with this O: one more where O
        is within ftol of the best so far (the loop's test), back to zero
        where it is lower by more. An iterate where O rose by more than ftol
        leaves the count as it is: the loop only ever takes a step that
        lowers O, but IPOPT accepts a rise to follow its barrier (a winch
        with a small gradient near its bound is pushed about mu / |g|
        inside, then walked back as mu falls), and counting those rises as
        a stall stopped it half-way back (16 % above the loop's O on a
        hexapod whose targets are almost reached)."""
        ftol = self.options.ftol
        if objective <= self._last * (1 - ftol):
            return 0
        if objective > self._last * (1 + ftol):
            return self._stall
        return self._stall + 1

    def _projected(self, point: Point) -> float:
        """|projected gradient| x the mean bound range (length^2, as O).

        A winch near a bound with its gradient pointing out counts as held
        only if going the rest of the way would gain less than ftol x O:
        IPOPT's barrier keeps it a little inside, and with a steep gradient
        that little is not yet the answer (0.065 of O = 200 on the
        finger with its optimum on a bound)."""
        g = self.gradient(point)
        lower, upper = self.model.lower, self.model.upper
        scale = self.options.ftol * max(point.objective, self.options.objective_floor)
        for w in self._held_mask(point.c, g):
            gap = point.c[w] - lower[w] if g[w] > 0 else upper[w] - point.c[w]
            if abs(g[w]) * gap <= scale:
                g[w] = 0.0
        g[self.frozen] = 0.0
        return float(np.linalg.norm(g)) * float(np.mean(self.span))

    # -- the run ------------------------------------------------------------

    def solve(self) -> None:
        n = len(self.free)
        m = self.ev.B.shape[0] + n
        t0 = time.perf_counter()
        solver, self._residual, self._recorder = build_solver(
            self.ev, n, m, self.options.reduced_ipopt_options(), self._rules)
        self.t_build = time.perf_counter() - t0
        lbx, ubx = self.model.lower[self.free], self.model.upper[self.free]
        point, tried = self.start, {}
        while True:
            if self.iterations >= self.options.max_iter:
                self.stop = "max_iterations"
                break
            self.stationary, self._stall, self._last = "", 0, math.inf
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
            self.ev.raise_error()          # the callback's own error, if it was one
            raise
        finally:
            self.t_ipopt += time.perf_counter() - t0
        # an exception inside a callback stopped IPOPT: it is the real error
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
        tol = HELD_FRACTION * self.span
        lo = (c <= self.model.lower + tol) & (g > 0)
        up = (c >= self.model.upper - tol) & (g < 0)
        return [int(w) for w in np.flatnonzero((lo | up) & ~self.frozen)]

    def gradient(self, point: Point) -> np.ndarray:
        g = np.zeros(self.model.n_winches)
        g[self.free] = self.ev.derivatives(point).gradient()
        return g

    def _look_further(self, point: Point, tried: dict) -> Point | None:
        """The gradient loop's restart moves (docs/control.md), from ``point``.

        ``tried`` maps a winch to O where its moves were last tried: it is
        tried again only from a point lower by probe_gain (each later round
        lowers O, so this ends)."""
        model, opts = self.model, self.options
        g = self.gradient(point)
        slack = slack_winches(model, point.eq.x, point.c, ~self.frozen, g)
        stuck = point.objective > opts.stuck_fraction * self.o_start
        held = self._held_mask(point.c, g) if stuck else []
        again = point.objective * (1 + opts.probe_gain)
        for w in [w for w in dict.fromkeys(slack + held) if tried.get(w, math.inf) > again]:
            tried[w] = point.objective
            for frac in (0.0, *opts.probe_fractions):
                c = point.c.copy()
                if w in slack:
                    c[w] = take_up(model, point.eq.x, point.c, w)
                    inward = 1.0
                elif frac == 0.0:
                    continue
                else:
                    inward = 1.0 if c[w] <= model.lower[w] + 0.5 * self.span[w] else -1.0
                c[w] = float(np.clip(c[w] + inward * frac * self.span[w], model.lower[w], model.upper[w]))
                if c[w] == point.c[w]:
                    continue
                trial = self.ev.at(c[self.free], on_branch=False)
                if trial is None:
                    continue
                if frac == 0.0:
                    if self.gradient(trial)[w] < 0 and trial.objective <= point.objective * (1 + 1e-9):
                        return self._moved(trial, f"took up the slack of {model.winch_names[w]}")
                elif trial.objective < point.objective * (1 - opts.probe_gain):
                    return self._moved(trial, f"probe moved {model.winch_names[w]} to {c[w]:.4g}")
        return None

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
        head = f"ipopt (reduced): {self.return_status}"
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


def _no_eigenvalue(options):
    from dataclasses import replace
    return replace(options, eigenvalue=False)
