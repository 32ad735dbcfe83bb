"""The Newton backend of :func:`~plush_opt.solve.equilibrium.solve_equilibrium`.

Newton on the exact sparse Hessian (one factorisation per step, its
symbolic analysis kept by the model's factoriser), with a backtracking
line search that never accepts a non-admissible pose (some J <= 0) or a
non-finite energy, a multiple of the identity added where the Hessian is
not positive definite, and an escape along the most negative curvature
direction at a saddle and off a symmetric branch. Its tuning is
:class:`~plush_opt.solve.certificate.EquilibriumOptions`. A full step that
raises the energy may be taken tentatively, one at a time (a watchdog): it
stands only if the step after it ends below where it started, else the
solve goes back there and backtracks (``TENTATIVE_FAILURES``).

A factorisation is kept where it still serves (a chord step, no new
factorisation): after a full Newton step that cut the residual by
``CHORD_START`` (the local phase), and from the start when the caller
hands in the factor of a nearby certified equilibrium (a control trial
from its iterate; of a low-rank Hessian, it first takes the start's own
tendon terms). Where the pose they reach has a Hessian that is not
positive definite, they are undone and the solve goes on without them.
Each such step must cut the residual by ``CHORD_CUT`` and pass the same
admissibility and energy tests as a Newton step; at most ``CHORD_STEPS``
follow one factorisation. Where they stall on a low-rank Hessian, the
kept factor serves on with the current pose's tendon terms
(``FRESH_LOW_RANK``). Before each Newton step's factorisation, and where
kept-factor steps stall, an inexact Newton step is tried: conjugate
gradients on the current Hessian preconditioned by the kept factor, to
``KRYLOV_TOL`` of the residual, taken only if it passes the same tests
(``KRYLOV_STEPS``). They are not iterations: ``iterations`` (and
``max_iterations``) count Newton steps, each with its own factorisation.
The certificate never rests on a kept factor: the pose they reach is
factored afresh, and only that factor certifies it. Those steps and their
tuning are :mod:`plush_opt.solve.kept_factor`.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ..base.errors import SolverError
from ..base.eigenpair import smallest_eigenpair
from ..base.linalg import Factor, NotPositiveDefinite
from ..fem.model import Evaluation, Model
from .certificate import LEFT_BRANCH, Equilibrium, EquilibriumOptions, certified, try_factor
from .contact_step import corrected_step
from .free_fall import free_fall
from . import kept_factor
from .kept_factor import ROUNDOFF_BAND, energy_slack, inexact_first, kept_factor_steps

log = logging.getLogger("plush_opt.solve.equilibrium")   # one channel for every backend

# ... and is taken if it cuts the residual by at least this factor.
ROUNDOFF_RESIDUAL_CUT = 0.5
# The factor of a full Newton step is kept only if that step cut the
# residual this much (the local phase, where the Hessian changes little).
CHORD_START = 0.25
# A mode whose net displacement is below this fraction of its 1-norm has
# none (an antisymmetric mode): its sign is fixed by its largest component.
NO_NET_DISPLACEMENT = 1e-8
# A full Newton step that fails the energy test is still taken, one at a
# time, as a tentative step (the watchdog of nonmonotone line searches):
# where a stiff tendon pulls a soft body the energy's valley is so curved
# that a full step climbs its wall, yet the step after it lands far below
# the start. That next step must end at least the full step's Armijo
# decrease below the start, else the solve goes back to the start and
# backtracks as usual, and takes no more tentative steps. This many may
# fail before they stop: one failure says the steps are not converging.
TENTATIVE_FAILURES = 1


def _regularised_factor(model: Model, H, options: EquilibriumOptions,
                        previous: float | None = None) -> Factor:
    """Cholesky of H + shift I with the smallest shift (by factors of
    ``options.shift_growth``) that makes it positive definite, starting one
    factor below the ``previous`` shift of the same solve (the next Hessian
    is usually alike)."""
    diag = np.abs(H.diagonal())
    floor = options.shift_floor * max(float(diag.mean()), 1e-300)   # (a zero diagonal: still > 0)
    shift = floor if previous is None else max(floor, previous / options.shift_growth)
    for _ in range(options.max_shifts):
        try:
            return model.factorizer.factor(H, shift)
        except NotPositiveDefinite:
            shift *= options.shift_growth
    raise SolverError("Hessian regularisation failed: no shift made it positive definite")


def escape_saddle(model: Model, c, x, ev: Evaluation, options: EquilibriumOptions,
                  pair=None) -> tuple[np.ndarray, Evaluation] | None:
    """Step from a saddle along its most negative curvature direction.

    The sign is fixed (net displacement of the mode positive) so the outcome
    is deterministic; both signs are tried, the lower energy wins (the first
    sign on a tie: a symmetric scene always buckles the same way).
    """
    lam, v = pair if pair is not None else smallest_eigenpair(ev.hessian_form)
    if lam >= 0:
        return None
    # sign rule: the mode's net displacement (sum of components) positive,
    # or, for a mode with none, its largest component positive
    net = float(np.sum(v))
    v = v * (np.sign(net) if abs(net) > NO_NET_DISPLACEMENT * np.abs(v).sum()
             else np.sign(v[np.argmax(np.abs(v))]))
    h = np.sqrt(np.mean(model.rest_area))
    best = None
    for s in h * 2.0 ** -np.arange(0, options.escape_halvings):
        for sign in (1.0, -1.0):
            xt = x + sign * s * v / np.abs(v).max()
            et = model.evaluate(xt, c, order=0)
            if et.admissible and np.isfinite(et.energy) and et.energy < ev.energy - energy_slack(model, ev.energy, x):
                if best is None or et.energy < best[0] - energy_slack(model, et.energy, xt):
                    best = (et.energy, xt)
        if best is not None:
            break
    if best is None:
        return None
    log.info("escaped a saddle (lambda_min = %.3g) by a step of %.3g", lam, s)
    return best[1], model.evaluate(best[1], c, order=2)


def _escape_at_saddle(model: Model, c, x, ev: Evaluation, options: EquilibriumOptions, escapes: int):
    """At a converged pose whose Hessian is not positive definite: the
    escaped (pose, evaluation) (:func:`escape_saddle`), or None where
    escapes are off, used up, or find nothing. (Not when staying on a
    branch: a converged point with an indefinite Hessian there is the fold
    at its end, past which the escape would snap through.)"""
    if options.escape_saddles and options.regularise and escapes < options.max_escapes:
        return escape_saddle(model, c, x, ev, options)
    return None


def _left_branch(it: int) -> str:
    return f"{LEFT_BRANCH}: Hessian not positive definite after {it} iteration(s)"


def _stalled_status(history: list[float], options: EquilibriumOptions) -> str:
    """The status of a solve stopped by :func:`_stalled`."""
    return (f"residual stalled at {min(history):.1e} of the force scale, above gtol "
            f"{options.gtol:g} (a round-off floor: badly shaped elements or an "
            "ill-conditioned Hessian)")


def _stalled(history: list[float], options: EquilibriumOptions) -> bool:
    """No progress over the last ``stall_window`` relative residuals of
    ``history`` near the tolerance (see :class:`EquilibriumOptions`)."""
    return history[-1] < options.stall_residual and _no_progress(history, options.stall_window, options)


def _stop_without_progress(history: list[float], definite: bool, handover: int, options: EquilibriumOptions,
                           it: int) -> str:
    """The status Newton stops with after the relative residuals
    ``history`` (``definite``: the Hessian at the last is positive
    definite), or "": a stall near the tolerance (round-off, a sliver
    element or an ill-conditioned H, sets a floor above gtol), or no
    progress at all where another method can take over (``handover``)."""
    if definite and _stalled(history, options):
        return _stalled_status(history, options)
    if handover and _no_progress(history, handover, options):
        return _handover_status(history, handover, it)
    return ""


def _no_progress(history: list[float], window: int, options: EquilibriumOptions) -> bool:
    """More than 2 ``window`` relative residuals in ``history``, and the
    best of the last ``window`` not below ``stall_gain`` times the best before."""
    return len(history) > 2 * window and min(history[-window:]) > options.stall_gain * min(history[:-window])


#: The status of a solve handed over (``solve_newton``'s ``handover``) begins so.
NO_PROGRESS = "no progress"


def _handover_status(history: list[float], window: int, it: int) -> str:
    return (f"{NO_PROGRESS} after {it} iterations: the best residual ({min(history):.1e} of the "
            f"force scale) not halved in the last {window}")


def _line_search(model: Model, c, x, ev: Evaluation, dx, options: EquilibriumOptions,
                 tentative: bool = False, first: int = 0):
    """Backtracking from the full step ``dx``: the accepted (x, evaluation
    with its Hessian), the step length and whether the step is tentative,
    or (None, 0.0, False). A step is never accepted at a non-admissible
    pose or a non-finite energy, and never starts beyond the fraction of
    ``dx`` the model allows (contact: the first time of impact). With
    ``tentative``, a whole admissible step that fails the energy test is
    returned as tentative (``TENTATIVE_FAILURES``). ``first``: the
    backtracking cuts already made (after a tentative step went back)."""
    g = ev.gradient
    slope = float(g @ dx)
    slack = energy_slack(model, ev.energy, x)
    alpha = model.max_step(x, dx) * options.backtrack ** first
    for k in range(first, options.max_backtracks):
        xt = x + alpha * dx
        et = model.evaluate(xt, c, order=2 if k == 0 else 0)
        if not (et.admissible and np.isfinite(et.energy)):
            alpha *= options.backtrack
            continue
        if et.energy <= ev.energy + options.armijo * alpha * slope + slack:
            return (xt, et if k == 0 else model.evaluate(xt, c, order=2)), alpha, False
        if k == 0 and et.energy <= ev.energy + ROUNDOFF_BAND * slack and \
                np.linalg.norm(et.gradient) < ROUNDOFF_RESIDUAL_CUT * np.linalg.norm(g):
            # energy differences at round-off level: judge the full
            # Newton step by the residual it leaves instead
            return (xt, et), alpha, False
        if k == 0 and tentative and alpha == 1.0:
            return (xt, et), alpha, True
        alpha *= options.backtrack
    return None, 0.0, False


def _start_with(model: Model, c, x, ev: Evaluation, chord: Factor | None, options: EquilibriumOptions):
    """Kept-factor steps from the start with the caller's ``chord`` factor
    (a positive definite one of this model), with the start's own tendon
    terms where it is of a low-rank Hessian and the start is not converged
    (:meth:`~plush_opt.base.linalg.Factor.with_low_rank_of`: they change
    fastest from the caller's pose to this one): (pose, evaluation, where
    they began or None, whether the body fell). A body nothing holds yet is
    first moved onto what will (:func:`~plush_opt.solve.free_fall.free_fall`)."""
    start = x
    x, ev = free_fall(model, c, x, ev)
    if chord is None or chord.shift != 0.0 or chord.H.shape != (model.n_dofs, model.n_dofs):
        return x, ev, None, x is not start
    if kept_factor.FRESH_LOW_RANK and np.linalg.norm(ev.gradient) > options.gtol * ev.force_scale:
        chord = chord.with_low_rank_of(ev.hessian_form) or chord
    xs, es, steps = kept_factor_steps(model, c, x, ev, chord, options)
    return xs, es, ((x, ev) if steps else None), x is not start


def _keep_factor(model: Model, c, accepted, alpha: float, g, factor: Factor | None, options: EquilibriumOptions,
                 allowed: bool) -> tuple[np.ndarray, Evaluation, int]:
    """After a Newton step to ``accepted`` (pose, evaluation) from a pose
    with gradient ``g``: in the local phase (a full step with a positive
    definite ``factor`` that cut the residual by ``CHORD_START``) that
    factor serves a few more steps (:func:`~plush_opt.solve.kept_factor.kept_factor_steps`); (pose,
    evaluation, steps taken)."""
    x, ev = accepted
    if not _in_local_phase(ev, alpha, g, factor, allowed):
        return x, ev, 0
    return kept_factor_steps(model, c, x, ev, factor, options)


def _in_local_phase(ev: Evaluation, alpha: float, g, factor: Factor | None, allowed: bool) -> bool:
    """Whether a Newton step to the pose of ``ev`` from a pose with gradient
    ``g`` keeps its ``factor`` (:func:`_keep_factor`): allowed, positive
    definite, a full step, and the residual cut by ``CHORD_START``."""
    return allowed and factor is not None and alpha == 1.0 and \
        np.linalg.norm(ev.gradient) <= CHORD_START * np.linalg.norm(g)


def _off_symmetric_branch(model: Model, c, x, ev: Evaluation, step_factor: Factor,
                          options: EquilibriumOptions):
    """At an indefinite Hessian (``step_factor`` its regularised factor):
    (the escaped pose and evaluation, or None; whether to keep checking).

    A gradient blind to the unstable direction (a symmetric scene on its
    symmetric branch) would let a regularised step pick a side by
    round-off: leave along the negative curvature by the same rule as at a
    saddle. Once the gradient is seen to have a component along it, the
    scene is not on a symmetric branch: no more checks this solve."""
    g = ev.gradient
    pair = step_factor.most_negative_eigenpair()
    if pair is not None and abs(g @ pair[1]) <= options.symmetric_gradient * np.linalg.norm(g):
        escaped = escape_saddle(model, c, x, ev, options, pair)
        if escaped is not None:
            return escaped, True
    return None, pair is None


class _Watchdog:
    """Newton's tentative full steps (``TENTATIVE_FAILURES``): where the one
    under watch started (its pose, evaluation, step and the energy the step
    after it must reach), and how many were undone."""

    def __init__(self):
        self.start, self.failures = None, 0
        self._back_to = None        # the factor of the start a judged step went back to

    def factor_of_step(self, factor: Factor | None) -> Factor | None:
        """The factor of the step just taken with ``factor``: the watched
        start's where the judge went back there, else ``factor``."""
        back, self._back_to = self._back_to, None
        return back if back is not None else factor

    def allows(self, factor: Factor | None) -> bool:
        """Whether the next (unregularised) step may be tentative."""
        return self.start is None and factor is not None and self.failures < TENTATIVE_FAILURES

    def watch(self, model: Model, x, ev: Evaluation, dx, options: EquilibriumOptions, factor: Factor) -> None:
        """Watch the tentative step ``dx`` (by ``factor``) from (``x``,
        ``ev``): the step after it must end the whole step's Armijo
        decrease below ``ev``."""
        slope = float(ev.gradient @ dx)
        self.start = (x, ev, dx, ev.energy + options.armijo * slope + energy_slack(model, ev.energy, x), factor)

    def judge(self, model: Model, c, accepted, alpha: float, options: EquilibriumOptions):
        """The step after a tentative one (``accepted``, None where it failed
        or met an indefinite Hessian) stands if it ends below the watched
        start's mark; else back to that start and its line search without
        the whole step. (accepted, step length); as given with nothing under
        watch."""
        start, self.start, self._back_to = self.start, None, None
        if start is None or (accepted is not None and accepted[1].energy <= start[3]):
            return accepted, alpha
        self.failures, self._back_to = self.failures + 1, start[4]
        log.debug("newton: the tentative step did not pay off; backtracking from its start")
        accepted, alpha, _ = _line_search(model, c, start[0], start[1], start[2], options, first=1)
        return accepted, alpha


def _step(model: Model, c, x, ev: Evaluation, step_factor: Factor, factor: Factor | None, dog: _Watchdog,
          keep: bool, options: EquilibriumOptions, it: int, fell: bool = False):
    """One Newton step from (``x``, ``ev``) with ``step_factor`` (``factor``:
    H's own, or None where it was regularised): the line search, a
    tentative step or the judging of the one before (``dog``), then the
    kept-factor steps (``keep``: allowed). (pose, evaluation, the pose to
    go back to if kept-factor steps were taken, whether they were tried:
    their inexact step too) or None (line search failed). ``fell``: the
    body fell onto what holds it (the step is corrected for the contact
    barrier's curvature, :func:`~plush_opt.solve.contact_step.corrected_step`)."""
    g = ev.gradient
    dx = -step_factor.solve(g)
    dx = corrected_step(model, c, x, g, dx, step_factor) if fell else dx
    accepted, alpha, tentative = _line_search(model, c, x, ev, dx, options, dog.allows(factor))
    log.debug("newton %d: residual %.3e, shift %.3e, step %.3e%s", it, np.linalg.norm(g) / ev.force_scale,
              step_factor.shift, alpha, " (tentative)" if tentative else "")
    if tentative:
        dog.watch(model, x, ev, dx, options, step_factor)
        return accepted[0], accepted[1], None, False
    accepted, alpha = dog.judge(model, c, accepted, alpha, options)
    if accepted is None:
        return None
    tried = _in_local_phase(accepted[1], alpha, g, factor, keep)
    x, ev, kept = _keep_factor(model, c, accepted, alpha, g, factor, options, keep)
    return x, ev, (accepted if kept else None), tried


#: the status of a solve whose line search found no admissible step that lowers the energy
LINE_SEARCH_FAILED = "line search failed: no admissible step decreases the energy"


def _why_not(model: Model, c, x, converged: bool, status: str) -> str:
    """``status``, or for a body without pins that found no equilibrium,
    the net force along a free rigid motion that explains it (it slides)."""
    if converged or not model.unpinned:
        return status
    return model.unbalanced(x, c) or status


def solve_newton(model: Model, c, x, options: EquilibriumOptions, chord: Factor | None = None, handover: int = 0):
    """Newton from the pose ``x`` (n_dofs,) at ``c`` (n_winches,): the
    certified :class:`Equilibrium` where it converges, else an honest
    status (iteration limit, stall, saddle, left the branch, line search).
    ``chord``: a positive definite factor of a nearby Hessian for the first
    steps (module docstring). ``handover`` > 0: stop where the best residual
    has not halved in this many iterations (status :data:`NO_PROGRESS`)."""
    t0 = time.perf_counter()
    ev = model.evaluate(x, c, order=2)
    if not ev.admissible:
        return Equilibrium(x, c, False, f"initial pose not admissible ({model.violation(x)})", np.inf, np.inf,
                           np.nan, False, None, 0, time.perf_counter() - t0, "newton")
    x, ev, undo, fell = _start_with(model, c, x, ev, chord, options)
    keep, it, escapes = True, 0, 0    # kept-factor steps allowed (until they led to an indefinite H)
    status = f"iteration limit ({options.max_iterations}) reached"
    best: list[float] = []        # relative residual per iteration (stall detection)
    watch_symmetry = True         # look for a gradient blind to negative curvature
    last_shift = None             # regularisation of the previous indefinite step
    converged, last = False, None     # (last: the last Newton step's factor, for an inexact step)
    dog = _Watchdog()             # tentative full steps
    while True:
        g, H = ev.gradient, ev.hessian_form
        if last is not None and keep and dog.start is None:
            inexact, last = inexact_first(model, c, x, ev, last, options), None
            if inexact is not None:       # (undone as kept-factor steps are, to the same pose)
                x, ev, undo = inexact[0], inexact[1], ((x, ev) if undo is None else undo)
                continue
        factor = try_factor(model, H)
        if factor is None and undo is not None:    # kept-factor steps led there: undone
            (x, ev), undo, keep = undo, None, False
            continue
        if factor is None and dog.start is not None:   # a tentative step led there: back, backtrack
            accepted, _ = dog.judge(model, c, None, 0.0, options)
            if accepted is None:
                status = LINE_SEARCH_FAILED
                break
            x, ev = accepted
            continue
        small = np.linalg.norm(g) <= options.gtol * ev.force_scale
        if small and factor is not None:
            converged = True
            status = "converged" if escapes == 0 else f"converged (escaped {escapes} saddle(s))"
            break
        if small:
            escaped = _escape_at_saddle(model, c, x, ev, options, escapes)
            if escaped is None:
                status = "saddle: the gradient vanishes but the Hessian is not positive definite"
                break
            (x, ev), escapes = escaped, escapes + 1
            continue
        if it >= options.max_iterations:
            break
        best.append(np.linalg.norm(g) / ev.force_scale)
        if stop := _stop_without_progress(best, factor is not None, handover, options, it):
            status = stop
            break
        if factor is None and not options.regularise and not options.escape_saddles:
            status = _left_branch(it)      # (no symmetric-branch check to make first)
            break
        step_factor = factor if factor is not None else _regularised_factor(model, H, options, last_shift)
        last_shift = last_shift if factor is not None else step_factor.shift
        if factor is None and watch_symmetry and options.escape_saddles and escapes < options.max_escapes:
            escaped, watch_symmetry = _off_symmetric_branch(model, c, x, ev, step_factor, options)
            if escaped is not None:
                x, ev = escaped
                escapes += 1
                it += 1
                continue
        if factor is None and not options.regularise and escapes == 0:
            status = _left_branch(it)
            break
        it += 1
        stepped = _step(model, c, x, ev, step_factor, factor, dog, keep, options, it, fell)
        if stepped is None:
            status = LINE_SEARCH_FAILED
            break
        x, ev, undo, tried = stepped
        last = None if tried else dog.factor_of_step(factor)     # (tried: at this pose with factor)
    return certified(model, c, x, ev, factor, converged, _why_not(model, c, x, converged, status), it, t0,
                     options, "newton", escapes)
