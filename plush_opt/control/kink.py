"""Where the gradient loop on a path-dependent plant would stop: a
one-sided test of the kink (docs/control.md, "Where O has a kink").

With friction at via points the pose, and so O, is only piecewise smooth in
the contractions: a via point that slipped in the last step sticks when its
winch reverses, so the slope of O along a direction depends on the
direction. The sensitivities hold for the last step's stick/slip modes, and
the step they propose can point where the modes change and O rises at any
length. Then the loop stops (a failed line search, or a stationary or
stalled iterate in those modes) at a point that need not be stationary.

:func:`probe_kink` measures what the robot does instead of what the
sensitivities predict: every free winch alone, moved by ``h`` of its range
in each direction, for each ``h`` of :attr:`KinkRule.steps` from the largest
down, each move a certified trial driven from the committed state (nothing
is committed). The first ``h`` at which some move lowers O gives the move
(the one that lowers it most, lengthened by doubling while O keeps
falling); where no move at any ``h`` lowers O, every one-sided slope along
the winches' directions is non-negative down to the smallest ``h``: the
iterate is a (coordinate-wise) nonsmooth stationary point for the
friction state its path reached, and :func:`kink_verdict` says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np


@dataclass(frozen=True)
class KinkRule:
    """How the kink is tested.

    Attributes
    ----------
    steps : the single-winch moves, as fractions of each winch's range,
        largest first (empty: no test).
    gain : a move counts only if it lowers O by this relative amount (the
        loop's ``ftol``: a decrease the stall rule would count).
    doublings : how many times the move found is doubled while O keeps
        falling.
    max_step : no move goes further than this fraction of a winch's range
        (the loop's ``max_step``).
    """

    steps: tuple[float, ...]
    gain: float
    doublings: int
    max_step: float


@dataclass(frozen=True)
class KinkProbe:
    """What :func:`probe_kink` found: ``contraction`` (n_winches,),
    ``equilibrium`` and ``objective`` of the move taken (None where none
    lowered O), ``tried`` certified trials, ``failed`` trials that did not
    certify."""

    contraction: np.ndarray | None
    equilibrium: Any
    objective: float | None
    tried: int
    failed: int

    @property
    def moved(self) -> bool:
        return self.contraction is not None


def probe_kink(rule: KinkRule, contraction, objective: float, frozen, lower, upper,
               trial: Callable[[np.ndarray], Any], value: Callable[[Any], float]) -> KinkProbe:
    """Single-winch moves from the committed iterate (contractions
    ``contraction`` (n_winches,), O = ``objective``) within ``lower``,
    ``upper``; ``trial(c)`` is the certified-or-not equilibrium reached at
    c from the committed state, ``value(eq)`` its O. Frozen winches stay."""
    c0 = np.asarray(contraction, dtype=np.float64)
    span = np.asarray(upper, dtype=np.float64) - np.asarray(lower, dtype=np.float64)
    free = np.flatnonzero(~np.asarray(frozen, dtype=bool))
    tried = failed = 0
    for h in rule.steps:
        best = None
        for w in free:
            for sign in (1.0, -1.0):
                c = _moved(c0, w, sign * h * span[w], lower, upper)
                if c is None:
                    continue
                eq = trial(c)
                if not eq.converged:
                    failed += 1
                    continue
                tried += 1
                o = value(eq)
                if o < objective * (1 - rule.gain) and (best is None or o < best[0]):
                    best = (o, c, eq, w, sign)
        if best is not None:
            o, c, eq, extra = _lengthen(rule, c0, best, h * span[best[3]], span, lower, upper, trial, value)
            return KinkProbe(c, eq, o, tried + extra, failed)
    return KinkProbe(None, None, None, tried, failed)


def _moved(c0, w, move, lower, upper):
    """c0 with winch w moved by ``move``, kept within its bounds; None if it does not move."""
    c = c0.copy()
    c[w] = float(np.clip(c0[w] + move, lower[w], upper[w]))
    return None if c[w] == c0[w] else c


def _lengthen(rule, c0, best, move, span, lower, upper, trial, value):
    """The move ``best`` (O, c, eq, winch, sign) of length ``move``,
    doubled while O keeps falling (at most ``rule.doublings`` times, within
    ``rule.max_step`` of the range); (O, c, eq, trials)."""
    o, c, eq, w, sign = best
    extra = 0
    for _ in range(rule.doublings):
        move *= 2
        if move > rule.max_step * span[w]:
            break
        longer = _moved(c0, w, sign * move, lower, upper)
        if longer is None or longer[w] == c[w]:
            break
        found = trial(longer)
        extra += 1
        if not found.converged or value(found) >= o:
            break
        o, c, eq = value(found), longer, found
    return o, c, eq, extra


def kink_verdict(rule: KinkRule, test: KinkProbe, stop: tuple[bool, str, str], cause: str,
                 bound_note: str) -> tuple[bool, str, str]:
    """(converged, reason, status) after a test of the kink that found no move.

    ``stop``: the loop's (converged, reason, status) before the test;
    ``cause`` the plant's ``path_cause``; ``bound_note`` the held winches
    (``; bound active: ...`` or empty). A complete test (every trial
    certified) makes a failed line search an honest stationary stop;
    an incomplete one claims nothing more than the stop before it."""
    converged, reason, status = stop
    lo, hi = min(rule.steps), max(rule.steps)
    moves = f"move of any single winch by {lo:g} to {hi:g} of its range within its bounds"
    if test.failed:
        return converged, reason, (f"{status}; the test at the kink is incomplete: {test.failed} of "
                                   f"{test.failed + test.tried} single-winch moves did not reach a certified "
                                   "equilibrium")
    if converged:
        return True, reason, f"{status}; at the kink ({cause}) no {moves} lowers O either"
    return True, "stationary", (
        f"stationary (nonsmooth, {cause}): no step along the sensitivities lowered O, nor does a {moves}; "
        "a local optimum for the friction state this path reached (another path may end lower: the other "
        "--method or --direction, or other starting contractions)" + bound_note)
