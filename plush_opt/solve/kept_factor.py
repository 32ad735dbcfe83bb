"""Steps without a factorisation of their own, for Newton
(:mod:`plush_opt.solve.newton`): steps with a kept factor of a nearby
Hessian (chord steps), the same with the low-rank tendon term set up
afresh, and inexact Newton steps (conjugate gradients on the current
Hessian preconditioned by the kept factor). Each is taken whole only if
it passes a Newton step's admissibility and energy tests and cuts the
residual by ``CHORD_CUT``; none ever certifies a pose (the solve factors
the pose they reach afresh).
"""

from __future__ import annotations

import logging

import numpy as np

from ..base.linalg import Factor
from ..base.low_rank import LowRankHessian
from ..fem.model import Evaluation, Model
from .certificate import EquilibriumOptions

log = logging.getLogger("plush_opt.solve.equilibrium")   # one channel for every backend

# Round-off of E relative to its size (|E|, the elastic scale, the work of
# gravity): a few hundred machine epsilons, the error of summing O(mu)
# element terms whose difference is E.
ENERGY_ROUNDOFF = 1e-13
# Energy changes within this many round-off allowances are noise: the full
# Newton step is then judged by the residual it leaves instead.
ROUNDOFF_BAND = 100.0
# A step with a kept factor (of a nearby Hessian: the last Newton step's,
# or one the caller hands in) is taken only while each cuts the residual at
# least this much: at a slower rate its evaluations cost more than the
# factorisation it saves (near round-off a rate of 0.3 is still worth it).
CHORD_CUT = 0.5
# ... and at most this many in a row with one factor (then a fresh factorisation).
CHORD_STEPS = 12
# Kept-factor steps stop where a fresh factorisation is predicted to reach
# the tolerance more cheaply (_chord_pays): a factorisation costs about
# sqrt(n_dofs / this) kept-factor steps (a 2D mesh's factorisation grows as
# n^1.5, a step's evaluation and solve as n) ...
FRESH_COST_DOFS = 150.0
# ... times the Hessian's entries per row over this many (a P1 mesh's: a
# node and its six neighbours, two dofs each; tendons and P2 fill more)
P1_ROW_ENTRIES = 14.0
# ... and the evaluation of a Hessian not yet in hand about this many more
# (the evaluation itself and the Hessian's assembly).
HESSIAN_COST = 2.0
# They go on below the tolerance, to this fraction of it: a converging
# Newton step lands decades below it, and callers that difference poses
# (finite differences, sensitivities checked against re-solves) rely on
# that; a step with a kept factor costs a fraction of one.
CHORD_DEPTH = 1e-3
# Where a step with a kept factor of a low-rank Hessian fails, the factor's
# sparse part is kept and the tendons' own low-rank terms (U'' l' l'^T,
# which change fastest: their stretch sits in the smoothing zone) are set up
# afresh at the current pose, the rest of the low-rank term kept (in the
# split form the segments' couplings pair with their blocks in the kept
# sparse part), this many times per run of such steps (the set-up
# substitutes the tendons' columns alone: a tenth of a factorisation); and
# a factor the caller hands in takes the start's tendon terms first (0:
# neither) ...
FRESH_LOW_RANK = 1
# ... and only in the local phase: relative residual at most this (and
# above the tolerance: a converged pose needs its certificate, no more steps).
FRESH_BELOW = 1e-3
# An inexact Newton step instead of a factorisation: conjugate gradients on
# the current Hessian preconditioned by the factor kept from a nearby pose
# (one solve and one product with H per iteration), tried before each
# Newton step's factorisation with the last one's factor, and where
# kept-factor steps stall; at most this many per run of such steps ...
KRYLOV_STEPS = 2
# ... and where the relative residual is at most this: from farther away
# the kept factor's Hessian is no preconditioner for this one (a first step
# from rest starts at 1; 0.5 instead cost the gripper's control run at
# 10,000 nodes 2.75 factorisations per iterate instead of 2.00).
KRYLOV_BELOW = 1.0
# ... and on models of at least this many unknowns: below, a factorisation
# costs about what a dozen solves and products with H do (at 1,000 nodes
# the steps saved two factorisations of eight and no time).
KRYLOV_MIN_DOFS = 10_000
# Each runs at most this many iterations (where it converges it took 4-8
# on the gripper; past a dozen, the solves cost what a factorisation does) ...
KRYLOV_ITERATIONS = 12
# ... and stops after this many if |H dx + g| is still above this fraction
# of |g| (it will not reach the tolerance below in time) ...
KRYLOV_CHECK, KRYLOV_CHECK_CUT = 5, 0.1
# ... or once |H dx + g| is this fraction of |g|: the step then cuts the
# residual about as far, and the kept-factor steps after it go on.
KRYLOV_TOL = 1e-3
# In the local phase, kept-factor steps that cut the residual by less than
# this each give way to a fresh low-rank term (where one is left) or an
# inexact Newton step: conjugate gradients preconditioned by the same factor
# cut it by about (sqrt(k) - 1) / (sqrt(k) + 1) a solve, k = (1 + rate) /
# (1 - rate) (0.24 where the steps cut it by 0.45, as a dozen of them did at
# the end of the gripper's forward solve at 30,000 nodes), and a step costs
# a solve and an evaluation (1.0: never; docs/notes/benchmarks-history.md).
KRYLOV_AFTER_RATE = 0.3
# An inexact step that lands below the tolerance but leaves more than this
# many times the residual its conjugate gradients predicted has met the
# residual's round-off floor (that near the equilibrium its nonlinear error
# is decades smaller): the steps stop there, where a further one would only
# repeat that residual.
ROUNDOFF_FLOOR_GAP = 2.0


def energy_slack(model: Model, ev_energy: float, x: np.ndarray) -> float:
    """Round-off allowance for comparing energies near convergence.

    The Neo-Hookean density is a small difference of O(mu) terms
    (tr F^T F - 2 against 2 ln J), so E carries an absolute round-off of
    about machine epsilon times mu, lambda and the body volume, however
    small E itself is.
    """
    size = abs(ev_energy) + model.energy_roundoff_scale
    if model.has_gravity:
        size += abs(model.f_gravity @ x)
    return ENERGY_ROUNDOFF * size


def _chord_pays(H, rate: float, norm: float, target: float, room: int, in_hand: bool) -> bool:
    """Whether a step with a kept factor, whose steps cut the residual by
    ``rate`` each, reaches ``target`` from ``norm`` (or takes the ``room``
    steps left to the factor) more cheaply than a fresh factorisation here
    (``FRESH_COST_DOFS`` and ``P1_ROW_ENTRIES`` on the size and entries of
    ``H``, the kept factor's matrix; and ``HESSIAN_COST`` unless this
    pose's Hessian is ``in_hand``). A fresh factor's steps are taken to
    cut it by ``rate`` squared: the factors' difference from the Hessian
    shrinks with the distance to the equilibrium, and this pose is nearer
    by at least the kept factor's cut."""
    if rate >= CHORD_CUT:
        return False
    if rate <= 0.0:
        return True
    need = np.log(target / norm)
    keep, fresh = min(need / np.log(rate), room), need / np.log(rate * rate)
    n = H.shape[0]
    entries = H.body.nnz + H.Q.nnz if isinstance(H, LowRankHessian) else H.nnz
    factorisation = np.sqrt(n / FRESH_COST_DOFS) * entries / (n * P1_ROW_ENTRIES)
    return keep <= fresh + factorisation + (0.0 if in_hand else HESSIAN_COST)


def kept_factor_steps(model: Model, c, x, ev: Evaluation, factor: Factor,
                 options: EquilibriumOptions, start_inexact: bool = False) -> tuple[np.ndarray, Evaluation, int]:
    """Steps -F^-1 g with a kept positive definite ``factor`` F of a nearby
    Hessian, no factorisation: each is taken whole (never beyond
    ``Model.max_step``) only if it is admissible, does not raise the energy
    (Armijo, or at round-off level) and cuts the residual by
    ``CHORD_CUT``; they stop at the first that does not, when the residual
    is ``CHORD_DEPTH`` times the tolerance, after ``CHORD_STEPS`` with one
    factor, or where a fresh factorisation is predicted to get there more
    cheaply (:func:`_chord_pays`, on the rate the last step cut the
    residual by; before the first, on the cut predicted from the Hessian
    in hand: g + H dx = (H - F) dx). Where they would stop short of the
    tolerance in the local phase (``FRESH_BELOW``), or go on there more slowly
    than ``KRYLOV_AFTER_RATE`` a step (:func:`_slow`), a factor of a low-rank
    Hessian goes on with the tendons' low-rank terms set up afresh at the
    current pose (``FRESH_LOW_RANK``), and where that stalls too, an inexact Newton
    step preconditioned by the kept factor is tried (:func:`krylov_step`,
    ``KRYLOV_STEPS``): on the Hessian of this pose, or of the last pose of
    these steps where one was evaluated in the local phase (near enough:
    the step is tested as any other), its first solve the failed step's
    own; with that Hessian in hand the next step is inexact too (a
    kept-factor step right after an inexact one cuts the residual little),
    as is the first where ``start_inexact`` says the caller's last step was one
    (landing in the local phase). They stop where an inexact step lands
    below the tolerance at the residual's round-off floor
    (``ROUNDOFF_FLOOR_GAP``).
    Returns the pose, its evaluation (with the Hessian if any step was taken, else
    ``ev`` as given) and the number of steps. The certificate is untouched:
    the pose they reach is factored afresh."""
    steps, since, refreshed, krylov = 0, 0, 0, 0    # steps; with this factor; refreshes; inexact Newton
    ev1 = ev
    last = 0.0                             # the residual before the last step
    local = _local_hessian(ev1, None)      # a Hessian of these steps' local phase
    floor = False                          # an inexact step met the round-off floor
    again = start_inexact                  # the next step inexact (on the local Hessian)
    while True:
        g = ev1.gradient
        norm = float(np.linalg.norm(g))
        target = CHORD_DEPTH * options.gtol * ev1.force_scale
        if norm <= target or floor:
            break
        skip = again or since > 0 and _slow(ev1, norm, last, krylov, options)
        dx, pays = (None, False) if skip else _chord_dx(factor, ev1, norm, target, since, last)
        last = norm
        taken = _kept_step(model, c, x, ev1, dx, norm, options) if pays else None
        if taken is None:
            rel = norm / ev1.force_scale
            refresh = not again and refreshed < FRESH_LOW_RANK and options.gtol < rel <= FRESH_BELOW and \
                isinstance(factor.H, LowRankHessian)         # (else nothing to refresh)
            inexact = krylov < KRYLOV_STEPS and _inexact_pays(g, rel, options)
            if not (refresh or inexact):
                break                   # (converged: its certificate next; or far from it)
            if ev1.hessian_form is None and (refresh or local is None):
                ev1 = model.evaluate(x, c, order=2)
                local = _local_hessian(ev1, local)
            # the tendons' stiffness changes fastest: the kept factor with
            # the tendon terms of this pose
            fresh = factor.with_low_rank_of(ev1.hessian_form) if refresh else None
            if fresh is not None:
                factor, refreshed, since = fresh, refreshed + 1, 0
                continue
            # the rest of the Hessian moved too: an inexact Newton step
            # (the failed step's solve is its first: the same factor, the same g)
            H = ev1.hessian_form if ev1.hessian_form is not None else local
            stepped = _inexact_step(model, c, x, ev1, factor, norm, options, H, dx) if inexact else None
            if stepped is None:
                break
            taken, floor, above = stepped
            krylov, since = krylov + 1, 0
            # with the local Hessian in hand, the next step is inexact too:
            # a kept-factor step right after one cuts the residual little
            again = H is local and krylov < KRYLOV_STEPS and above
        else:
            again = False
        (x, ev1), steps, since = taken, steps + 1, since + 1
    if steps:
        log.debug("newton: %d step(s) with a kept factor (%d low-rank refresh(es), %d inexact Newton), "
                  "residual %.3e", steps, refreshed, krylov, np.linalg.norm(ev1.gradient) / ev1.force_scale)
        return x, (ev1 if ev1.hessian_form is not None else model.evaluate(x, c, order=2)), steps
    return x, ev, 0


def _slow(ev: Evaluation, norm: float, last: float, krylov: int, options: EquilibriumOptions) -> bool:
    """Whether a kept-factor step that took the residual from ``last`` to
    ``norm`` (at ``ev``) cut it by less than ``KRYLOV_AFTER_RATE`` in the
    local phase where an inexact step may follow (``krylov`` taken so far)."""
    rel = norm / ev.force_scale
    return norm > KRYLOV_AFTER_RATE * last and rel <= FRESH_BELOW and krylov < KRYLOV_STEPS and \
        _inexact_pays(ev.gradient, rel, options)


def _chord_dx(factor: Factor, ev: Evaluation, norm: float, target: float, since: int, last: float):
    """(the kept-factor step -F^-1 g at ``ev``, residual norm ``norm``,
    or None; whether it pays): ``since`` steps taken with ``factor``, the
    last from residual ``last`` (:func:`_chord_pays` on its rate; before the
    first, on the rate predicted from the Hessian in hand, the step solved
    for either way)."""
    g = ev.gradient
    if since >= CHORD_STEPS:
        return None, False
    if since == 0 and ev.hessian_form is not None:
        dx = -factor.solve(g)
        rate = float(np.linalg.norm(ev.hessian_form @ dx - factor.H @ dx)) / norm
        return dx, _chord_pays(factor.H, rate, norm, target, CHORD_STEPS, True)
    if since > 0 and not _chord_pays(factor.H, norm / last, norm, target, CHORD_STEPS - since, False):
        return None, False
    return -factor.solve(g), True


def _inexact_step(model: Model, c, x, ev: Evaluation, factor: Factor, norm: float,
                  options: EquilibriumOptions, H, dx: np.ndarray | None):
    """An inexact step of :func:`kept_factor_steps` on ``H`` (``dx``: the
    failed kept-factor step's solve F^-1 (-g), or None): None, or ((pose,
    evaluation of order 1), whether it landed below the tolerance at the
    round-off floor (``ROUNDOFF_FLOOR_GAP``), whether it landed above the
    tolerance)."""
    taken = krylov_step(model, c, x, ev, factor, norm, options, H, dx, True)
    if taken is None:
        return None
    (xk, ek), predicted = taken
    landed = float(np.linalg.norm(ek.gradient))
    below = landed <= options.gtol * ek.force_scale
    return (xk, ek), below and landed > ROUNDOFF_FLOOR_GAP * predicted, not below


def _local_hessian(ev: Evaluation, kept):
    """``ev``'s Hessian where it has one at a relative residual of at most
    ``FRESH_BELOW`` (the local phase: near enough the equilibrium's for an
    inexact step's operator further on), else ``kept``."""
    if ev.hessian_form is None or np.linalg.norm(ev.gradient) > FRESH_BELOW * ev.force_scale:
        return kept
    return ev.hessian_form


def krylov_step(model: Model, c, x, ev: Evaluation, factor: Factor, norm: float,
                options: EquilibriumOptions, H=None, first: np.ndarray | None = None,
                predicted: bool = False):
    """An inexact Newton step from (``x``, ``ev``, residual norm ``norm``):
    H dx = -g by conjugate gradients preconditioned with the kept
    ``factor`` (``KRYLOV_ITERATIONS``, ``KRYLOV_TOL``), then the tests of a
    kept-factor step. ``H``: ``ev``'s Hessian unless given (a nearby
    pose's); ``first``: F^-1 (-g) where already solved for. None where CG
    meets a curvature that is not positive (H is not positive definite
    along its search), does not converge, or the step fails its tests;
    else (pose, evaluation of order 1), with ``predicted`` as
    ((pose, evaluation), |H dx + g| of the step)."""
    g = ev.gradient
    H = ev.hessian_form if H is None else H
    r = -g
    z = factor.solve(r) if first is None else first
    p, rz = z.copy(), float(r @ z)
    dx = np.zeros_like(g)
    for i in range(KRYLOV_ITERATIONS):
        Hp = H @ p
        curvature = float(p @ Hp)
        if not curvature > 0:
            return None
        alpha = rz / curvature
        dx += alpha * p
        r -= alpha * Hp
        left = float(np.linalg.norm(r))
        if left <= KRYLOV_TOL * norm:
            taken = _kept_step(model, c, x, ev, dx, norm, options)
            return (taken, left) if predicted and taken is not None else taken
        if i + 1 == KRYLOV_CHECK and left > KRYLOV_CHECK_CUT * norm:
            return None
        z = factor.solve(r)
        rz, rz_old = float(r @ z), rz
        p = z + (rz / rz_old) * p
    return None


def _kept_step(model: Model, c, x, ev: Evaluation, dx, norm: float,
               options: EquilibriumOptions) -> tuple[np.ndarray, Evaluation] | None:
    """The step ``dx`` from (``x``, ``ev``, residual norm ``norm``) taken
    whole with no factorisation of its own: (pose, evaluation of order 1)
    if it stays within ``Model.max_step``, is admissible, does not raise
    the energy (Armijo, or at round-off level) and cuts the residual by
    ``CHORD_CUT``; else None."""
    g = ev.gradient
    if model.max_step(x, dx) < 1.0:
        return None
    xt = x + dx
    et = model.evaluate(xt, c, order=1)
    if not (et.admissible and np.isfinite(et.energy)):
        return None
    slack = energy_slack(model, ev.energy, x)
    lower = et.energy <= ev.energy + options.armijo * float(g @ dx) + slack
    if not ((lower or et.energy <= ev.energy + ROUNDOFF_BAND * slack)
            and np.linalg.norm(et.gradient) <= CHORD_CUT * norm):
        return None
    return xt, et


def _inexact_pays(g: np.ndarray, relative: float, options: EquilibriumOptions) -> bool:
    """Whether an inexact Newton step is worth trying at a pose with
    gradient ``g`` and relative residual ``relative``: not converged, within
    ``KRYLOV_BELOW``, and a model of at least ``KRYLOV_MIN_DOFS`` unknowns."""
    return g.size >= KRYLOV_MIN_DOFS and options.gtol < relative <= KRYLOV_BELOW


def inexact_first(model: Model, c, x, ev: Evaluation, factor: Factor, options: EquilibriumOptions):
    """Before factoring at (``x``, ``ev``): an inexact Newton step with the
    last Newton step's ``factor`` (:func:`krylov_step`) where the relative
    residual is at most ``KRYLOV_BELOW`` (and above the tolerance), then the
    kept-factor steps after it (from another inexact step where it landed
    in the local phase): (pose, evaluation with its Hessian) or None."""
    norm = float(np.linalg.norm(ev.gradient))
    if KRYLOV_STEPS == 0 or not _inexact_pays(ev.gradient, norm / ev.force_scale, options):
        return None
    taken = krylov_step(model, c, x, ev, factor, norm, options)
    if taken is None:
        return None
    landed = float(np.linalg.norm(taken[1].gradient)) / taken[1].force_scale
    xs, es, _ = kept_factor_steps(model, c, taken[0], taken[1], factor, options,
                                  options.gtol < landed <= FRESH_BELOW)
    return xs, (es if es.hessian_form is not None else model.evaluate(xs, c, order=2))
