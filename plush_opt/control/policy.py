"""The policy both control methods share: stop rules, the look-further
probe, the Levenberg-Marquardt damping rule and the first-order warm start.

The gradient loop (:class:`~plush_opt.control.gradient.Controller`) and the
reduced bilevel search (:class:`~plush_opt.control.bilevel_search.ReducedRun`)
judge an iterate by the same rules, so that both stop at the same accuracy
and look past the same traps (docs/control.md, docs/bilevel.md). Every rule
here is a function of what it is given; what a rule remembers between
iterates is a small explicit state, passed in and returned new
(:meth:`StopRules.init_state` / :meth:`StopRules.update`, the ``tried``
map of :func:`look_further`), never read from the caller's fields.

Where the two methods genuinely differ, the difference is a parameter:
the order in which the stop rules are checked (:data:`LOOP_ORDER`,
:data:`REDUCED_ORDER`), how close to a bound a winch counts as held (the
loop's bounds strategy, IPOPT's barrier), whether a held winch whose rest
of the way is not negligible still counts (``negligible`` of
:func:`projected_gradient`), whether a winch may be probed again
(:attr:`ProbeRule.retry`), and the damping's cap and floors
(:class:`Damping`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping

import numpy as np

from .slack import take_up

# A slack take-up leaves the pose unchanged, so O may only move by round-off:
# it is kept if O has not risen by more than this (relative).
TAKE_UP_TOLERANCE = 1e-9


# -- stop rules ---------------------------------------------------------

#: The stop rules by name, as :meth:`StopRules.first` reports them:
#: ``reached`` (O at or below the floor), ``no_gradient`` (every free winch
#: has a zero gradient), ``stationary`` (projected gradient below gtol),
#: ``stalled`` (O stopped decreasing), ``iterations`` and ``time`` (budget).
RULES = ("reached", "no_gradient", "stationary", "stalled", "iterations", "time")
#: The gradient loop checks the iterate first, the budget last.
LOOP_ORDER = ("reached", "no_gradient", "stationary", "stalled", "iterations", "time")
#: The reduced search checks the budget around the iterate (IPOPT's
#: iteration callback); a winch with no gradient is left to IPOPT's KKT test.
REDUCED_ORDER = ("time", "reached", "iterations", "stationary", "stalled")


@dataclass(frozen=True)
class StallState:
    """What the stall rule remembers: ``count`` iterates in a row within
    ftol of ``best``, the lowest O since the last reset."""

    count: int = 0
    best: float = math.inf


@dataclass(frozen=True)
class StopRules:
    """When an iterate ends a run.

    Attributes
    ----------
    gtol : stationary once the projected gradient (:func:`projected_gradient`,
        length^2) is at most gtol * max(O, floor).
    ftol, patience : stalled once ``patience`` iterates in a row lowered O
        by less than ftol (relative) below the best so far.
    floor : O at or below this (length^2) counts as targets reached.
    max_iterations : iterations at most.
    max_time : seconds at most (None: no limit).
    """

    gtol: float
    ftol: float
    patience: int
    floor: float
    max_iterations: int
    max_time: float | None = None

    def init_state(self, objective: float = math.inf) -> StallState:
        """A fresh stall count, measured against ``objective`` (the iterate
        the run starts or restarts from; inf: the first iterate seen)."""
        return StallState(0, objective)

    def update(self, state: StallState, objective: float) -> StallState:
        """The stall state after an iterate with this O: the count is one
        more where O is within ftol of the best, back to zero where it is
        lower by more. An O above the best by more than ftol leaves the
        count as it is: IPOPT accepts a rise to follow its barrier (a winch
        near its bound pushed about mu / |g| inside, then walked back as mu
        falls), which is not a stall. (The loop only takes steps that lower
        O, so for it this is the plain relative-decrease test.)"""
        if objective <= state.best * (1 - self.ftol):
            count = 0
        elif objective > state.best * (1 + self.ftol):
            count = state.count
        else:
            count = state.count + 1
        return StallState(count, min(state.best, objective))

    def reached(self, objective: float) -> bool:
        return objective <= self.floor

    def stationary(self, projected: float, objective: float) -> bool:
        return projected <= self.gtol * max(objective, self.floor)

    def stalled(self, state: StallState) -> bool:
        return state.count >= self.patience

    def out_of_iterations(self, iterations: int) -> bool:
        return iterations >= self.max_iterations

    def out_of_time(self, t: float) -> bool:
        return self.max_time is not None and t >= self.max_time

    def exhausted(self, objective: float, iterations: int, t: float) -> bool:
        """The budget is spent or the targets are reached: a stop with
        nothing to look further for."""
        return self.out_of_iterations(iterations) or self.reached(objective) or self.out_of_time(t)

    def first(self, order: tuple[str, ...], state: StallState, *, objective: float | None = None,
              projected: float | None = None, no_gradient: bool = False, iterations: int = 0,
              t: float = 0.0) -> str | None:
        """The first rule in ``order`` (names from :data:`RULES`) that stops
        at this iterate, or None. ``objective`` and ``projected`` None (no
        certified iterate) skip the rules on the iterate."""
        facts = {
            "reached": lambda: objective is not None and self.reached(objective),
            "no_gradient": lambda: no_gradient,
            "stationary": lambda: (objective is not None and projected is not None
                                   and self.stationary(projected, objective)),
            "stalled": lambda: objective is not None and self.stalled(state),
            "iterations": lambda: self.out_of_iterations(iterations),
            "time": lambda: self.out_of_time(t),
        }
        for name in order:
            if facts[name]():
                return name
        return None


def held_at_bounds(c, g, lower, upper, tol, frozen) -> list[int]:
    """Free winches within ``tol`` (scalar or (n_winches,)) of a bound whose
    gradient ``g`` points out of it, ascending."""
    up = (c >= upper - tol) & (g < 0)
    lo = (c <= lower + tol) & (g > 0)
    return [int(w) for w in np.flatnonzero((up | lo) & ~np.asarray(frozen, dtype=bool))]


def projected_gradient(g, held, span, c=None, lower=None, upper=None,
                       negligible: float = math.inf) -> float:
    """|P g| x the mean bound range (length^2, as O): the gradient ``g``
    (n_winches,) less the components of the ``held`` winches.

    A held winch is projected out only where going the rest of the way to
    its bound (contractions ``c`` within ``lower``, ``upper``) would change
    O by at most ``negligible``: a method that keeps a winch a little inside
    its bound (IPOPT's barrier) is not yet at the answer when its gradient
    is steep. The default (inf) projects out every held winch (the loop
    holds a winch on its bound)."""
    p = np.array(g, dtype=np.float64)
    for w in held:
        if math.isinf(negligible):
            p[w] = 0.0
            continue
        gap = c[w] - lower[w] if p[w] > 0 else upper[w] - c[w]
        if abs(p[w]) * gap <= negligible:
            p[w] = 0.0
    return float(np.linalg.norm(p)) * float(np.mean(span))


# -- look further where a run would stop ------------------------------------

@dataclass(frozen=True)
class ProbeRule:
    """How far to look past a stop (docs/control.md "Restart moves").

    Attributes
    ----------
    stuck_fraction : a run whose O is still above this fraction of its O
        at the start of the current targets is "stuck near its start",
        which enables the bound probes.
    fractions : how far a probe goes inwards from a bound, as fractions of
        the range.
    gain : a probe is taken only if it lowers O by this relative amount.
    retry : False: each winch is tried once per set of targets (the loop:
        it then stops); True: a winch is tried again from an O lower by
        ``gain`` than where it was last tried (the reduced search, whose
        later IPOPT rounds may have made its slack matter).
    """

    stuck_fraction: float
    fractions: tuple[float, ...]
    gain: float
    retry: bool = False


@dataclass(frozen=True)
class ProbeSite:
    """Where a run stopped: contractions (n_winches,), pose, O, O at the
    start of the current targets, and the winches whose tendons are all
    slack and that are held at a bound (indices)."""

    contraction: np.ndarray
    x: np.ndarray
    objective: float
    objective_at_start: float
    slack: list[int]
    held: list[int]


@dataclass(frozen=True)
class Move:
    """A look-further move taken: the winches ``winches`` (one, or the held
    set probed together) to their ``contraction`` (n_winches,), ``kind``
    'slack' (taken up) or 'probe', ``result`` what ``solve`` gave."""

    winches: tuple[int, ...]
    contraction: np.ndarray
    kind: str
    result: Any

    @property
    def winch(self) -> int:
        """The first (for a single-winch move, the only) winch moved."""
        return self.winches[0]

    def describe(self, names) -> str:
        """The move in words, e.g. ``a to 1`` or ``a, b to 1, 1``
        (``names``: the model's winch names)."""
        return (", ".join(names[w] for w in self.winches) + " to "
                + ", ".join(f"{self.contraction[w]:.4g}" for w in self.winches))


def probe_candidates(rule: ProbeRule, site: ProbeSite, tried: Mapping[int, float]) -> list[int]:
    """The winches to look further along: the slack ones, and (if the run
    is stuck near its start) the held ones, that ``tried`` allows."""
    stuck = site.objective > rule.stuck_fraction * site.objective_at_start
    held = site.held if stuck else []
    again = site.objective * (1 + rule.gain)
    return [w for w in dict.fromkeys(site.slack + held)
            if w not in tried or (rule.retry and tried[w] > again)]


def look_further(rule: ProbeRule, site: ProbeSite, tried: Mapping[int, float], model,
                 solve: Callable[[np.ndarray], tuple[float, Any] | None],
                 gradient: Callable[[Any], np.ndarray]) -> tuple[Move | None, dict[int, float]]:
    """Where a run would stop, look a little further before giving up.

    Two situations fool a local method here: a winch whose tendons are all
    slack has a zero gradient (nothing tells whether pulling would help);
    a winch held at a bound may only see the first millimetres of pull,
    which engage the "wrong" tendon first, although pulling further helps.
    For those winches the slack is reeled in (:func:`~.slack.take_up`,
    which leaves the pose unchanged) and kept if pulling then helps; and
    when the run is stuck near its start, the held winches are probed
    inwards (:func:`_probe_held`).

    ``tried`` maps a winch to O where its moves were last tried;
    ``solve(c)`` gives (O, result) at contractions c (n_winches,) for a
    certified equilibrium, else None; ``gradient(result)`` gives dO/dc
    (n_winches,) there. Returns (the move taken or None, the new ``tried``).
    """
    tried = dict(tried)
    lower, upper = model.lower, model.upper
    span = upper - lower
    c0 = site.contraction
    candidates = probe_candidates(rule, site, tried)
    for w in (w for w in candidates if w in site.slack):
        # a winch counts as tried once its moves are spent or one is taken
        tried[w] = site.objective
        for frac in (0.0, *rule.fractions):
            c = c0.copy()
            c[w] = float(np.clip(take_up(model, site.x, c0, w) + frac * span[w], lower[w], upper[w]))
            if c[w] == c0[w]:
                continue
            found = solve(c)
            if found is None:
                continue
            value, result = found
            if frac == 0.0:
                # slack reeled in: keep it if pulling now helps
                if gradient(result)[w] < 0 and value <= site.objective * (1 + TAKE_UP_TOLERANCE):
                    return Move((w,), c, "slack", result), tried
            elif value < site.objective * (1 - rule.gain):
                return Move((w,), c, "probe", result), tried
    held = [w for w in candidates if w not in site.slack]
    move = _probe_held(rule, site, held, model, solve)
    tried.update((w, site.objective) for w in (held if move is None else move.winches))
    return move, tried


def _probe_held(rule: ProbeRule, site: ProbeSite, held: list[int], model, solve) -> Move | None:
    """The probes of the ``held`` winches: each one alone, and where
    several are held, all of them together, inwards (away from the nearer
    bound) by each of ``rule.fractions`` of their ranges in turn; at the
    first fraction where some probe lowers O by ``rule.gain``, the one
    that lowers it most (the first on a tie: single winches before the
    set). Probing the set together matters where winches act together (a
    robot's legs lifting its body): a gradient that points out of every
    bound says nothing about moving them all, and where the pose depends
    on the path (friction), moving one alone first can lead where the
    others cannot undo it. None where no probe lowers O."""
    lower, upper = model.lower, model.upper
    span = upper - lower
    c0 = site.contraction
    groups = [(w,) for w in held] + ([tuple(held)] if len(held) > 1 else [])
    for frac in rule.fractions:
        best = None
        for group in groups:
            c = c0.copy()
            for w in group:
                inward = 1.0 if c[w] <= lower[w] + 0.5 * span[w] else -1.0
                c[w] = float(np.clip(c[w] + inward * frac * span[w], lower[w], upper[w]))
            if np.array_equal(c, c0):
                continue
            found = solve(c)
            if found is not None and found[0] < site.objective * (1 - rule.gain) and \
                    (best is None or found[0] < best[0]):
                best = (found[0], Move(group, c, "probe", found[1]))
        if best is not None:
            return best[1]
    return None


# -- warm start ---------------------------------------------------------

def predict(model, x, dxdc, c0, c) -> np.ndarray:
    """The first-order predictor x + dx/dc (c - c0) of the equilibrium at
    contractions ``c`` from the one (pose ``x``, sensitivity ``dxdc``
    (n_dofs, n_winches) or None) at ``c0``, if it is admissible, else x."""
    if dxdc is not None:
        xp = x + dxdc @ (c - c0)
        if model.admissible(xp):
            return xp
    return x


# -- Levenberg-Marquardt damping ----------------------------------------

@dataclass(frozen=True)
class Damping:
    """The Levenberg-Marquardt damping schedule: mu falls after a step that
    went well and rises after one that did not (the usual asymmetric
    schedule), and damps relative to the largest curvature, so that a
    winch with a tiny column cannot take a huge step.

    Attributes
    ----------
    initial : mu at the start and after every restart (small: the first
        step is nearly Gauss-Newton).
    minimum : mu never falls below this (keeps J^T J + damping well
        conditioned when a column vanishes).
    decrease, increase : mu is divided by the first after a good step and
        multiplied by the second after a bad one.
    maximum : mu never rises above this (inf: no cap).
    curvature_floor : the curvature scale never falls below this (a
        positive damping where every column vanishes).
    """

    initial: float = 1e-3
    minimum: float = 1e-9
    decrease: float = 3.0
    increase: float = 10.0
    maximum: float = math.inf
    curvature_floor: float = 1e-300

    def accepted(self, mu):
        """mu after a good step (scalar or per winch)."""
        return _same_kind(mu, np.maximum(mu / self.decrease, self.minimum))

    def rejected(self, mu, times: int = 1):
        """mu after ``times`` bad trials (scalar or per winch)."""
        return _same_kind(mu, np.minimum(mu * self.increase ** times, self.maximum))

    def scale(self, curvature) -> float:
        """The curvature the damping is relative to: the largest of
        ``curvature`` (the diagonal of J^T J), at least the floor."""
        return max(float(np.max(curvature, initial=0.0)), self.curvature_floor)

    def with_cap(self, cap: float, **changes) -> "Damping":
        """This schedule started at and capped by ``cap``, its floor at most ``cap``."""
        return replace(self, initial=cap, maximum=cap, minimum=min(self.minimum, cap), **changes)


#: The schedule's defaults (the gradient loop's options).
LEVENBERG_MARQUARDT = Damping()


def _same_kind(mu, value):
    return value if np.ndim(mu) else float(value)
