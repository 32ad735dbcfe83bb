"""Equilibria that stay on the stable branch: continuation in the contraction.

A move from a certified equilibrium (c0, x0) to a contraction c1 is what
the robot does when its winches turn slowly: the pose follows the branch
it is on. Newton from a predictor does that in a few steps, until the move
crosses a limit point of the branch (a leg that buckles, a snap-through):
past it no equilibrium is near, and a regularised Newton wanders along the
unstable direction for hundreds of iterations (a hexapod leg folding until
two via points of its tendon meet, where the tendon length |p_b - p_a| has
a kink and no step decreases the energy), or crawls through the "ghost" of
the lost equilibrium just past the limit point.

:func:`solve_on_branch` runs Newton without regularisation (it stops at
the first Hessian that is not positive definite); if that happens it
continues from (c0, x0) along the straight line to c1 in sub-steps, each
solved the same way, halving a sub-step that leaves the branch and
doubling the next after one that stays on it. It returns the certified
equilibrium at c1 on the branch, or, when the branch ends before c1, an
honest failure that says where (the caller cuts its move). Every returned
``converged`` pose is certified by the same test as any other solve.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np

from .equilibrium import LEFT_BRANCH, Equilibrium, EquilibriumOptions, IpoptEquilibrium, solve_equilibrium
from ..base.errors import SolverError
from ..base.low_rank import abs_product
from ..fem.model import Model

log = logging.getLogger(__name__)

# smallest sub-step, as a fraction of the move: the end of the branch only
# needs bracketing to where the caller would cut its move anyway
MIN_FRACTION = 1.0 / 32
# the first sub-step after the direct solve left the branch: half the move
FIRST_FRACTION = 0.5
# a smallest eigenvalue within this many eps |H|_inf of zero is round-off:
# the pose sits on the fold or bifurcation that ends the branch
ROUNDOFF_EIGENVALUE = 10.0
# inverse-iteration steps of the cheap screen, and how far above the
# round-off level its estimate must be to skip the Lanczos run (a near-null
# eigenvalue dominates after a step or two; the others decay as their ratio)
INVERSE_STEPS = 3
SAFETY = 100.0
# a sub-step that stayed on the branch lets the next be this much longer;
# one that left it is retried this much shorter (bisection of the end)
GROW, CUT = 2.0, 0.5
# how a move's status begins where the branch ends before its contraction
BRANCH_ENDS = "no stable equilibrium on the branch"


def branch_ended(status: str) -> bool:
    """Whether a move's ``status`` says the stable branch ended on the way
    (a limit point: past it the pose would snap), not some other failure."""
    return status.startswith(BRANCH_ENDS) or status.startswith(LEFT_BRANCH)


def solve_on_branch(model: Model, c0, x0, c1, guess=None, options: EquilibriumOptions | None = None,
                    ipopt: IpoptEquilibrium | None = None, chord=None) -> Equilibrium:
    """The equilibrium at ``c1`` on the stable branch through the certified
    equilibrium ``x0`` at ``c0`` (:func:`follow_branch` without where the
    branch ended)."""
    return follow_branch(model, c0, x0, c1, guess, options, ipopt, chord)[0]


def follow_branch(model: Model, c0, x0, c1, guess=None, options: EquilibriumOptions | None = None,
                  ipopt: IpoptEquilibrium | None = None, chord=None) -> tuple[Equilibrium, float | None]:
    """The equilibrium at ``c1`` on the stable branch through the certified
    equilibrium ``x0`` at ``c0``, and, where the branch ends before ``c1``,
    the fraction of the move c0 -> c1 at which a sub-step found no stable
    equilibrium left (the branch ends before it; None otherwise).

    ``guess`` : the start of the direct solve at c1 (a predictor; default
    x0). ``options.max_iterations`` bounds the Newton iterations of the
    whole move (every sub-step together). With the IPOPT backend this is
    one plain solve from ``guess`` (by ``ipopt``, the model's
    :class:`IpoptEquilibrium`, if given). A converged answer whose smallest
    Hessian eigenvalue is round-off (the pose on the fold or bifurcation
    ending the branch) is returned not converged. Only a converged answer
    carries that eigenvalue (with ``options.eigenvalue``). ``chord``: the
    factor of the equilibrium at c0, reused by the direct solve's first
    steps while they converge fast (:func:`~plush_opt.solve.newton.solve_newton`).
    """
    options = options or EquilibriumOptions()
    c0 = np.asarray(c0, dtype=np.float64).reshape(-1)
    c1 = np.asarray(c1, dtype=np.float64).reshape(-1)
    guess = x0 if guess is None else guess
    if options.backend != "newton":
        return solve_equilibrium(model, c1, guess, options, ipopt), None
    t0 = time.perf_counter()
    # no eigenvalue diagnostic on a pose that failed: without a factor it is
    # a Lanczos run on H itself, costlier than the solve, for a pose discarded.
    # Sub-steps stop at the first indefinite Hessian without looking for a
    # symmetric branch (a Lanczos run each); only where the branch seems to
    # end is that looked for (a pitchfork: the path goes on, buckled)
    strict = _strict(options)
    direct = solve_equilibrium(model, c1, guess, strict, chord=chord)
    if direct.converged:
        return _at_the_end(direct, time.perf_counter() - t0, options.eigenvalue), None
    if not _left(direct):
        return direct, None
    return _substeps(model, c0, x0, c1, guess, options, direct, t0)


def _substeps(model: Model, c0, x0, c1, guess, options: EquilibriumOptions, direct: Equilibrium,
              t0: float) -> tuple[Equilibrium, float | None]:
    """:func:`follow_branch` after the ``direct`` solve at c1 left the
    branch: sub-steps along the line c0 -> c1, each solved without
    regularisation, lengthened after one that stays on the branch and
    shortened after one that leaves it."""
    strict = _strict(options)
    used, escapes, failed = direct.iterations, 0, None
    done, h, steps, look = 0.0, FIRST_FRACTION, 0, False
    x = np.asarray(x0, dtype=np.float64).reshape(-1)
    # the first sub-step starts on the line from x0 to the guess (the
    # caller's first-order predictor is linear in c), later ones extrapolate
    # along the last sub-step
    x_prev, h_prev = 2 * x - np.asarray(guess, dtype=np.float64).reshape(-1), 1.0
    while True:
        h = min(h, 1.0 - done)
        if used >= options.max_iterations:
            status = f"iteration limit ({options.max_iterations}) reached on the branch"
            break
        if h < MIN_FRACTION and done + h < 1.0:
            if options.escape_saddles and not look:
                h, look = h / CUT, True     # the smallest step that failed, once more, looking
                continue
            reached = c0 + done * (c1 - c0)
            status = (f"{BRANCH_ENDS}: it ends (limit point) past "
                      f"contraction {np.array2string(reached, precision=6)} on the way to "
                      f"{np.array2string(c1, precision=6)}")
            return (replace(direct, status=status, iterations=used, t_wall=time.perf_counter() - t0),
                    failed)
        last = done + h >= 1.0
        c = c1 if last else c0 + (done + h) * (c1 - c0)
        sub = solve_equilibrium(model, c, _secant(model, x, x_prev, h, h_prev),
                                replace(strict, max_iterations=options.max_iterations - used,
                                        escape_saddles=look))
        used += sub.iterations
        escapes += sub.saddle_escapes
        if sub.converged:
            steps += 1
            if last:
                log.info("reached c = %s on the branch in %d sub-steps (%d Newton iterations)",
                         c1, steps, used)
                status = "converged" + (f" (escaped {escapes} saddle(s))" if escapes else "")
                return _at_the_end(replace(sub, iterations=used, saddle_escapes=escapes, status=status),
                                   time.perf_counter() - t0, options.eigenvalue), None
            x_prev, x, h_prev = x, sub.x, h
            done += h
            h, look = GROW * h, False
        elif look or _left(sub):
            failed = done + h
            h *= CUT                        # (after a look: nothing found, the branch ends)
        else:
            status = sub.status
            break
    return replace(direct, status=status, iterations=used, t_wall=time.perf_counter() - t0), None


def _at_the_end(eq: Equilibrium, t_wall: float, eigenvalue: bool) -> Equilibrium:
    """A converged answer, not converged if its smallest Hessian eigenvalue
    is round-off against |H| (there the pivots of the factor do not tell a
    singular H from a definite one: a caller creeping up to the end of the
    branch must not be handed it). With ``eigenvalue``, or where a few steps
    of inverse iteration say it may be round-off, the eigenvalue is computed
    (shift-invert Lanczos with the factor) and kept."""
    eq = replace(eq, t_wall=t_wall)
    rows = abs_product(eq.factor.H, np.ones(eq.factor.H.shape[0]))   # each row's sum of |H_ij| (a bound)
    roundoff = ROUNDOFF_EIGENVALUE * np.finfo(float).eps
    if not eigenvalue and _inverse_estimate(eq.factor) > SAFETY * roundoff * float(rows.sum()):
        return eq                     # (the sum of |H_ij| bounds |H|_inf from above)
    try:
        lam = eq.factor.min_eigenvalue()
    except SolverError as exc:       # a diagnostic: the certificate stands as it is
        log.warning("smallest Hessian eigenvalue not computed: %s", exc)
        return eq
    eq = replace(eq, min_eigenvalue=lam)
    margin = roundoff * float(rows.max())
    if lam > margin:
        return eq
    return replace(eq, converged=False,
                   status=(f"{LEFT_BRANCH}: smallest Hessian eigenvalue {lam:.2e} is round-off "
                           f"(below {margin:.1e}): the branch ends here"))


def _inverse_estimate(factor) -> float:
    """An estimate of the smallest eigenvalue of the factored H from above
    (the Rayleigh quotient after a few steps of inverse iteration, a solve
    each): accurate where that eigenvalue is far below the others."""
    v = _start(factor.H.shape[0])
    est = np.inf
    for _ in range(INVERSE_STEPS):
        w = factor.solve(v)
        est = float(v @ w) / float(w @ w)       # w^T H w / w^T w with H w = v
        v = w / np.linalg.norm(w)
    return est


def _start(n: int) -> np.ndarray:
    """A fixed generic unit vector (no mode of H is orthogonal to it).

    Drawn anew each time (not cached): n normal samples cost far less than
    the factor solves of the inverse iteration that uses them."""
    v = np.random.default_rng(0).standard_normal(n)
    return v / np.linalg.norm(v)


def _strict(options: EquilibriumOptions) -> EquilibriumOptions:
    """The options of a solve that stops at the first indefinite Hessian."""
    return replace(options, regularise=False, eigenvalue=False, escape_saddles=False)


def _left(eq: Equilibrium) -> bool:
    """A solve that stopped because its Hessian is not positive definite
    (with the escape off, a saddle counts too)."""
    return eq.status.startswith(LEFT_BRANCH) or eq.status.startswith("saddle")


def _secant(model: Model, x, x_prev, h, h_prev) -> np.ndarray:
    """The start of a sub-step of size ``h``: the pose extrapolated along the
    last sub-step (of size ``h_prev``) if that is admissible, else ``x``."""
    xp = x + (h / h_prev) * (x - x_prev)
    return xp if model.admissible(xp) else x
