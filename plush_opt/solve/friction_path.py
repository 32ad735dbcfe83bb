"""Forward solves with friction at via points: follow a contraction path.

Which equilibrium a robot with friction is in depends on how it got there,
so a state is a pose *and* the segment rest lengths (plush_opt/fem/friction.py),
advanced along a path of contractions in steps. One step (docs/model.md,
"Friction at via points"):

1. The winch reels in (or lets out) at its winch-end segments: predicted
   rest lengths r_pred.
2. Each interior via point i is stuck (delta_i = 0), slips toward the winch
   (delta_i >= 0, T_hi = T_lo exp(mu theta)) or toward the stopper
   (delta_i <= 0, T_lo = T_hi exp(mu theta)); delta_i is the material moved
   through it in this step, r = r_pred + D delta.
3. For a set of modes, Newton on the slip amounts solves the capstan
   equalities, the pose being the equilibrium at r (the equilibrium Newton,
   its factor reused for dx/dr).
4. Modes are switched (a stuck point whose inequality fails slips that way;
   a slipping point that moved the wrong way sticks) until none changes.

:func:`check_state` verifies the model's inequalities at a state from its
pose and rest lengths alone; every state a step returns as converged has
passed it. A failing step is retried in halves; an honest status otherwise.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..base.reprs import compact_repr
from .equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium
from ..fem.friction import FrictionModel
from ..base.linalg import NotPositiveDefinite

log = logging.getLogger(__name__)

STICK, SLIP_WINCH, SLIP_STOPPER = 0, 1, -1
# how far past the slack edge a point that slipped a segment slack carries
# it, as a fraction of the smoothing width (where its energy is flat)
SLACK_MARGIN = 0.01
# A set of modes is first solved to this (relative gradient and capstan
# residual): enough to tell which bounds fail, and most sets are switched
# away from; only the set that holds is then solved to the full tolerance.
LOOSE_TOL = 1e-6
ARMIJO = 1e-4     # sufficient decrease of the line searches' merit (the usual Newton choice)
MODE_NAMES = {STICK: "stick", SLIP_WINCH: "slip toward the winch", SLIP_STOPPER: "slip toward the stopper"}


@dataclass(frozen=True)
class FrictionOptions:
    """Options of the path-following friction solver.

    Attributes
    ----------
    tol : capstan equality tolerance of the Newton solves, relative to
        the tension scale (largest tension, at least the smoothing-zone
        tension K eps / 2).
    stick_tol : inequality tolerance, relative to the tension scale: a
        point sticks while its bound holds to this, and a segment whose
        tension is below it counts as slack. Far below any tension that
        moves the body, it keeps the vanishing tails of the smoothing zone
        (a nearly slack segment pulling 1e-5 of the scale, its stretch in the last 1e-4 of the smoothing zone) from making
        points slip back and forth by nothing.
    check_tol : tolerance :func:`check_state` applies to a returned state
        (looser than ``tol``: the check recomputes everything from x, r).
    max_newton : Newton iterations on the slip amounts per set of modes.
    max_backtracks : step halvings of that Newton before it gives up.
    max_mode_changes : rounds of mode switching per step before it reports
        a cycling set of modes.
    max_splits : how many times a failing step is retried as two halves.
    equilibrium : options of the inner equilibrium solves.
    """

    tol: float = 1e-10
    stick_tol: float = 1e-4
    check_tol: float = 1e-8
    max_newton: int = 40
    max_backtracks: int = 30
    max_mode_changes: int = 30
    max_splits: int = 6
    equilibrium: EquilibriumOptions = field(
        default_factory=lambda: EquilibriumOptions(eigenvalue=False, escape_saddles=False))

    def __post_init__(self):
        if not (0 < self.stick_tol < 1):
            raise ValueError(f"stick_tol: expected 0 < stick_tol < 1, got {self.stick_tol!r}")
        if not (0 < self.tol <= self.check_tol < 1):
            raise ValueError(f"tol, check_tol: expected 0 < tol <= check_tol < 1, got "
                             f"{self.tol!r}, {self.check_tol!r}")


@dataclass(frozen=True)
class FrictionState:
    """One state on a contraction path.

    Attributes
    ----------
    x : (n_dofs,) flat pose.
    contraction : (n_winches,).
    rest : (n_segments,) segment rest lengths of the friction tendons.
    tension : (n_segments,) their tensions at (x, rest).
    wrap : (n_interior,) wrap angles at the interior via points, radians.
    mode : (n_interior,) STICK, SLIP_WINCH or SLIP_STOPPER in the last step.
    slip : (n_interior,) material moved through each point in the last step
        (toward the winch positive).
    converged, status : the step's outcome.
    equilibrium : the pose's equilibrium solve (its factor for sensitivities).
    step_dx, step_dc : pose and contraction change of the last step (the
        next step's predictor), or None.
    """

    x: np.ndarray
    contraction: np.ndarray
    rest: np.ndarray
    tension: np.ndarray
    wrap: np.ndarray
    mode: np.ndarray
    slip: np.ndarray
    converged: bool
    status: str
    equilibrium: Equilibrium | None = field(default=None, repr=False, compare=False)
    step_dx: np.ndarray | None = field(default=None, repr=False, compare=False)
    step_dc: np.ndarray | None = field(default=None, repr=False, compare=False)

    __repr__ = compact_repr

    @property
    def nodes(self) -> np.ndarray:
        return self.x.reshape(-1, 2)


def tension_scale(fm: FrictionModel, tension: np.ndarray) -> float:
    """The size tensions are judged against."""
    floor = fm.K * fm.eps / 2     # U'(0): the tension of a segment at its rest length
    return float(max(np.max(tension, initial=0.0), floor))


def capstan(fm: FrictionModel, x, r, c, seg=None):
    """Per interior point: f_winch = T_hi - T_lo e, f_stopper = T_lo - T_hi e
    (e = exp(mu theta)), with the segment data and wraps they came from."""
    seg = fm.segments(x, r, c) if seg is None else seg
    if "wrap" not in seg:          # the wraps of this pose, once
        seg["wrap"] = fm.wraps(x)
    theta, dtheta = seg["wrap"]
    T = seg["tension"]
    e = np.exp(fm.mu * theta)
    return T[fm.hi] - T[fm.lo] * e, T[fm.lo] - T[fm.hi] * e, seg, theta, dtheta, e


def check_state(fm: FrictionModel, state: FrictionState, tol: float | None = None,
                stick_tol: float | None = None) -> list[str]:
    """The model's conditions at ``state``, recomputed from its pose and rest
    lengths: every rest length positive and each tendon's summing to
    a_t - c_w; at every interior via point T_hi <= T_lo exp(mu theta) and
    T_lo <= T_hi exp(mu theta); a point that slipped in the last step has
    the equality of its direction. Returns the violations (empty: all hold).
    ``tol`` (default the options' ``check_tol``) applies to the sums and
    equalities, ``tol + stick_tol`` to the inequalities."""
    tol = FrictionOptions().check_tol if tol is None else tol
    stick_tol = FrictionOptions().stick_tol if stick_tol is None else stick_tol
    x, r, c = state.x, state.rest, state.contraction
    out = []
    if fm.n_segments == 0:
        return out
    if np.any(r <= 0):
        out.append(f"segment rest length {float(r.min()):.3g} <= 0")
        return out
    total = np.bincount(fm.seg_tendon, weights=r, minlength=fm.model.n_tendons)[fm.seg_tendon]
    want = fm.rest_total(c)
    if np.max(np.abs(total - want) / want) > tol:
        out.append(f"rest lengths sum to {total} instead of a - c = {want}")
    f_w, f_s, seg, theta, _, _ = capstan(fm, x, r, c)
    scale = tension_scale(fm, seg["tension"])
    names = [fm.model.scene.tendons[t].name for t in fm.seg_tendon[fm.hi]]
    for i in range(fm.n_interior):
        where = f"tendon {names[i]!r}, via point {fm.via_index[i]}"
        for f, side in ((f_w[i], "T_winch_side > T_stopper_side exp(mu theta)"),
                        (f_s[i], "T_stopper_side > T_winch_side exp(mu theta)")):
            if f > (tol + stick_tol) * scale:
                out.append(f"{where}: {side} by {f / scale:.2e} of the tension scale")
        mode = int(state.mode[i])
        if mode != STICK:
            f = f_w[i] if mode == SLIP_WINCH else f_s[i]
            if abs(f) > tol * scale:
                out.append(f"{where}: slips ({MODE_NAMES[mode]}) off the capstan equality by "
                           f"{abs(f) / scale:.2e} of the tension scale")
            if state.slip[i] * mode < -tol * float(r.mean()):
                out.append(f"{where}: moved {state.slip[i]:.3g} against its slip direction")
    return out


def state_at(fm, x, r, c, mode, slip, converged, status, eq=None) -> FrictionState:
    """The friction state at pose x, segment rest lengths r, contractions c,
    modes and slips as given (its tensions and wrap angles computed)."""
    seg = fm.segments(x, r, c)
    theta, _ = fm.wraps(x)
    return FrictionState(x=np.asarray(x, dtype=np.float64).copy(), contraction=np.asarray(c, dtype=np.float64).copy(),
                         rest=np.asarray(r, dtype=np.float64).copy(), tension=seg["tension"], wrap=theta,
                         mode=np.asarray(mode, dtype=np.int8).copy(), slip=np.asarray(slip, dtype=np.float64).copy(),
                         converged=bool(converged), status=status, equilibrium=eq)


def start_state(fm: FrictionModel, options: FrictionOptions | None = None) -> FrictionState:
    """The scene's start state: zero contraction, each friction tendon's rest
    length shared in proportion to its segments' lengths in X, and the
    equilibrium reached from X with those rest lengths."""
    zero = np.zeros(fm.n_winches)
    at_rest = state_at(fm, fm.X, fm.start_rest_lengths(), zero, np.zeros(fm.n_interior),
                     np.zeros(fm.n_interior), True, "rest")
    return step(fm, at_rest, zero, options)


def step(fm: FrictionModel, state: FrictionState, contraction, options: FrictionOptions | None = None,
         _splits: int = 0) -> FrictionState:
    """The state reached from ``state`` when the contractions go to
    ``contraction`` (a static friction equilibrium reachable from it);
    a failing step is retried as two halves, ``max_splits`` deep."""
    options = options or FrictionOptions()
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    if state.converged and state.equilibrium is not None and np.array_equal(c, state.contraction):
        # the winches stand still: a static friction state stays as it is
        # (solving again could only move it by the tolerances)
        return state
    out = _step(fm, state, c, options)
    if out.converged or _splits >= options.max_splits or np.array_equal(c, state.contraction):
        return out
    log.info("friction step to %s failed (%s); trying two halves", c, out.status)
    mid = step(fm, state, (state.contraction + c) / 2, options, _splits + 1)
    if not mid.converged:
        return mid
    return step(fm, mid, c, options, _splits + 1)


def follow(fm: FrictionModel, state: FrictionState, path, options: FrictionOptions | None = None,
           on_step=None) -> list[FrictionState]:
    """States along ``path`` ((n_steps, n_winches) contractions), each from
    the previous; stops after the first step that does not converge.
    ``on_step(k, state)``, if given, is called after step k (from 1)."""
    states = []
    for c in np.atleast_2d(np.asarray(path, dtype=np.float64)):
        state = step(fm, state, c, options)
        states.append(state)
        if on_step is not None:
            on_step(len(states), state)
        if not state.converged:
            break
    return states


def _step(fm, state, c, options) -> FrictionState:
    r_pred = state.rest.copy()
    dc = c - state.contraction
    r_pred[fm.seg_last] -= dc[fm.seg_winch[fm.seg_last]]
    if np.any(r_pred <= 0):
        return replace(state, converged=False,
                       status="a winch-end segment would have no rest length left (step too large)")
    mode = state.mode.astype(np.int8).copy()
    mode[_slack(fm, state.tension, options.stick_tol * tension_scale(fm, state.tension))] = STICK
    if state.step_dc is not None and float(dc @ state.step_dc) < 0:
        mode[:] = STICK       # the path turns back: what slipped on the way out sticks first
    x, delta = _predict(fm, state, c, mode, r_pred)
    seen, last = set(), {}       # last: the latest evaluation, which the next round starts at
    for _ in range(options.max_mode_changes):
        key = mode.tobytes() + (delta != 0).tobytes()    # stuck points may hold a slip
        if key in seen:
            return state_at(fm, x, r_pred + fm.D @ delta, c, mode, delta, False,
                          "the stick/slip modes cycle without settling")
        seen.add(key)
        solved = _solve_modes(fm, x, r_pred, c, mode, delta, options, loose=True, last=last)
        if isinstance(solved, str):
            return state_at(fm, x, r_pred + fm.D @ delta, c, mode, delta, False, solved)
        x, delta, eq = solved
        new, reset = _switch(fm, x, r_pred + fm.D @ delta, c, mode, delta, options)
        if eq is None and np.array_equal(new, mode) and not reset.any():
            # these modes hold: now to the full tolerance (a step or two)
            solved = _solve_modes(fm, x, r_pred, c, mode, delta, options, last=last)
            if isinstance(solved, str):
                return state_at(fm, x, r_pred + fm.D @ delta, c, mode, delta, False, solved)
            x, delta, eq = solved
            new, reset = _switch(fm, x, r_pred + fm.D @ delta, c, mode, delta, options)
        if reset.any():
            # slips undone; the pose stays where this round's solve put it
            # (near the step's equilibrium: the step's start pose was tried,
            # and from it the next round met indefinite Hessians, 29
            # factorisations of a nested solve at the gripper's turn)
            delta[reset] = 0.0
        if np.array_equal(new, mode) and not reset.any():
            result = state_at(fm, x, r_pred + fm.D @ delta, c, mode, delta, True, "converged", eq)
            problems = check_state(fm, result, options.check_tol, options.stick_tol)
            if problems:
                return replace(result, converged=False, status="state check failed: " + "; ".join(problems))
            return replace(result, step_dx=result.x - state.x, step_dc=dc)
        mode = new
    return state_at(fm, x, r_pred + fm.D @ delta, c, mode, delta, False,
                  f"stick/slip modes still changing after {options.max_mode_changes} rounds")


def _predict(fm, state, c, mode, r_pred):
    """Start of a step's Newton: the last step's pose change and slips,
    scaled to this step (a secant predictor), where this step goes on the
    way the last one went; the last step's pose change retraced, without
    slips, where it turns back; the state's pose otherwise. (The
    tangent from the state's factor was tried: with tendons this much
    stiffer than the body its linear response overshoots, and Newton took
    twice as many iterations.)"""
    rest = state.x, np.zeros(fm.n_interior)
    if state.step_dc is None or not state.step_dc.any():
        return rest
    dc = c - state.contraction
    s = float(dc @ state.step_dc) / float(state.step_dc @ state.step_dc)
    if s == 0:
        return rest
    if s < 0:
        # the path turns back: every point sticks, and the pose retraces the
        # last step (the loading pose there is near, the hysteresis small;
        # from the state's own pose the slackened tendon lets the body spring
        # back through indefinite Hessians: 20-30 regularised iterations)
        x = state.x + max(s, -1.0) * state.step_dx
        return (x, rest[1]) if fm.model.admissible(x) else rest
    delta = np.where((mode != STICK) & (state.slip * mode > 0), s * state.slip, 0.0)
    x = state.x + s * state.step_dx
    if np.any(r_pred + fm.D @ delta <= 0) or not fm.model.admissible(x):
        return rest
    return x, delta


def _switch(fm, x, r, c, mode, delta, options) -> tuple[np.ndarray, np.ndarray]:
    """The modes the solution at (x, r) calls for, and the points whose slip
    in this step is undone (they moved against their direction). A point
    gone slack on both sides sticks where it is, keeping the slip it made."""
    f_w, f_s, seg, *_ = capstan(fm, x, r, c)
    tol = options.stick_tol * tension_scale(fm, seg["tension"])
    new = mode.copy()
    slack = _slack(fm, seg["tension"], tol)
    reset = (mode != STICK) & (delta * mode < 0) & ~slack
    new[reset | slack] = STICK
    stuck = new == STICK
    new[stuck & (f_w > tol)] = SLIP_WINCH
    new[stuck & (f_s > tol)] = SLIP_STOPPER
    return new, reset & (new == STICK)


def _slack(fm, tension, tol) -> np.ndarray:
    """Interior points with both neighbouring segments slack (tension within
    ``tol`` of 0): both capstan bounds hold there whatever the wrap (0 <= 0),
    so such a point is held stuck rather than given a degenerate equality
    (material lying slack on both sides of a via point does not move)."""
    return (tension[fm.lo] <= tol) & (tension[fm.hi] <= tol)


def _equilibrium(fm, x, r, c, options):
    if np.any(r <= 0):
        return None
    eq = solve_equilibrium(fm.fixed(r), c, x, options.equilibrium)
    return eq if eq.converged else None


def capstan_residual(fm, x, r, c, active, mode, seg=None):
    """Capstan residuals h of the slipping points (tension units) twice (the
    convergence test's and Newton's), with Newton's Jacobian in x (dense
    rows) and r. A slip that drives a segment to slack has a double root in
    T, where this Newton converges only linearly until the joint Newton sees
    the point slack and stops it (docs/model.md, "Friction at via points")."""
    f_w, f_s, seg, theta, dtheta, e = capstan(fm, x, r, c, seg)
    i = np.flatnonzero(active)
    up = mode[i] == SLIP_WINCH
    h = np.where(up, f_w[i], f_s[i])
    # winch-side: h = T_hi - e T_lo; stopper-side: h = T_lo - e T_hi
    a = np.where(up, fm.hi[i], fm.lo[i])          # the segment whose tension is bounded
    b = np.where(up, fm.lo[i], fm.hi[i])          # the one that bounds it
    T, gT, Tr = seg["tension"], seg["dtension_dx"], seg["dtension_dr"]
    vals = np.hstack([gT[a], -e[i, None] * gT[b], -(T[b] * e[i] * fm.mu[i])[:, None] * dtheta[i]])
    pdofs = np.hstack([fm.seg_p[a], fm.seg_p[b], fm.wrap_p[i]])
    dhs_dx = fm.to_x(vals, pdofs)
    dhs_dr = np.zeros((len(i), fm.n_segments))
    dhs_dr[np.arange(len(i)), a] += Tr[a]
    dhs_dr[np.arange(len(i)), b] -= e[i] * Tr[b]
    return h, h, dhs_dx, dhs_dr, tension_scale(fm, T)


def _past_slack(fm, x, r, c, mode, delta, points):
    """Slips of ``points`` (slipping, now slack on both sides) carried on
    until the segment they feed is slack by ``SLACK_MARGIN`` of the
    smoothing width, where its energy is flat: left at the slack edge
    (stretch -eps, where the law's second derivative vanishes and its third
    jumps) it would keep the pose Newton converging only linearly. Both
    tensions stay 0, so this is still the equality of the slip's direction
    (0 = e 0); skipped where the other segment would leave its slack."""
    delta = delta.copy()
    R = fm.rest_total(c)
    L = fm.segment_lengths(x)
    for i in points:
        up = mode[i] == SLIP_WINCH
        a, b = (fm.hi[i], fm.lo[i]) if up else (fm.lo[i], fm.hi[i])
        target = L[a] / (1 - fm.eps * (1 + SLACK_MARGIN) / R[a])      # (L - r) R / r = -eps (1 + margin)
        move = target - r[a]                                           # material into segment a
        if move <= 0:
            continue
        rb = r[b] - move
        if rb <= 0 or (L[b] - rb) * R[b] / rb > -fm.eps:
            continue
        delta[i] += move if up else -move
    return delta


def _solve_modes(fm, x, r_pred, c, mode, delta, options, loose=False, last=None):
    """Pose and slip amounts for a set of modes: the joint Newton
    (:func:`_joint_newton`), or where it fails the nested one. ``loose``:
    to ``LOOSE_TOL`` only, without the factor (the equilibrium is None)."""
    joint = _joint_newton(fm, x, r_pred, c, mode, delta, options, loose, last)
    if joint is not None:
        return joint
    return _nested_newton(fm, x, r_pred, c, mode, delta, options)


def _joint_newton(fm, x, r_pred, c, mode, delta, options, loose=False, last=None):
    """Newton on (x, delta_slipping) together: grad_x E = 0 and the capstan
    equalities h = 0, one factorisation of H per iteration, the slip
    unknowns eliminated by their Schur complement. Backtracks on the sum of
    the two relative residuals squared (trial points at order 1: only an
    accepted one needs its Hessian); None when it gets stuck (a Hessian
    that is not positive definite, no decrease), for the nested Newton.
    ``last`` (a dict) keeps the latest evaluation: a round of the step
    starts where the one before it stopped, and need not evaluate again."""
    t0 = time.perf_counter()
    active = mode != STICK
    Ds = fm.D[:, active].toarray()
    delta = delta.copy()
    gtol = options.equilibrium.gtol

    def merit(x, delta, order):
        r = r_pred + fm.D @ delta
        if np.any(r <= 0):
            return None
        ev, seg = _evaluated(fm, x, r, c, order, last)
        if not ev.admissible:
            return None
        f_w, f_s, _, theta, dtheta, e = capstan(fm, x, r, c, seg)
        h = np.where(mode == SLIP_WINCH, f_w, f_s)[active]
        scale = tension_scale(fm, seg["tension"])
        value = (np.linalg.norm(ev.gradient) / ev.force_scale) ** 2 + (np.linalg.norm(h) / scale) ** 2
        return value, ev, h, scale, r, seg

    now = merit(x, delta, 2)
    for it in range(options.max_newton):
        if now is None:
            return None
        value, ev, h, scale, r, seg = now
        tension = seg["tension"]
        # a slipping point gone slack on both sides stops here, holding its
        # slip (_switch then sticks it): its equality has a double root at
        # the slack end, where Newton would crawl
        done = _slack(fm, tension, options.stick_tol * scale) & active
        if done.any():
            active = active & ~done
            Ds = fm.D[:, active].toarray()
            delta = _past_slack(fm, x, r, c, mode, delta, np.flatnonzero(done))
            now = merit(x, delta, 2)
            continue
        if loose and np.linalg.norm(ev.gradient) <= LOOSE_TOL * ev.force_scale \
                and np.max(np.abs(h), initial=0.0) <= LOOSE_TOL * scale:
            return x, delta, None
        if ev.hessian_form is None:
            ev = fm.evaluate(x, c, r, 2, seg)
        try:
            factor = fm.factorizer.factor(ev.hessian_form)
        except NotPositiveDefinite:
            log.debug("joint newton %d: Hessian not positive definite", it)
            return None
        gnorm = float(np.linalg.norm(ev.gradient))
        if gnorm <= gtol * ev.force_scale and np.max(np.abs(h), initial=0.0) <= options.tol * scale:
            eq = Equilibrium(x, np.asarray(c, dtype=np.float64).copy(), True, "converged", ev.energy, gnorm,
                             ev.force_scale, True, None, it, time.perf_counter() - t0, "newton",
                             factor=factor)
            return x, delta, eq
        dx, dd = _joint_step(fm, factor, ev.gradient, x, r, c, active, mode, seg, Ds)
        log.debug("joint newton %d: |g|/f %.2e, |h|/T %.2e, slipping %s", it, gnorm / ev.force_scale,
                  np.max(np.abs(h), initial=0.0) / scale, np.flatnonzero(active))
        alpha = 1.0
        for _ in range(options.max_backtracks):
            trial = delta.copy()
            trial[active] += alpha * dd
            # the full step usually succeeds near the solution: its Hessian is the next one
            nxt = merit(x + alpha * dx, trial, 2 if alpha == 1.0 else 1)
            if nxt is not None and nxt[0] < (1 - ARMIJO * alpha) * value:
                x, delta, now = x + alpha * dx, trial, nxt
                break
            alpha /= 2
        else:
            log.debug("joint newton %d: no decrease along the Newton step", it)
            return None
    return None


def _evaluated(fm, x, r, c, order, last):
    """The evaluation (to ``order``) and segment data at (x, r, c), reused
    from ``last`` (a dict keeping the latest, or None) if it was there."""
    key = (x.tobytes(), r.tobytes())
    if last is not None and last.get("key") == key and last["order"] >= order:
        return last["ev"], last["seg"]
    seg = fm.segments(x, r, c)
    ev = fm.evaluate(x, c, r, order, seg)
    if last is not None:
        last.update(key=key, order=order, ev=ev, seg=seg)
    return ev, seg


def _joint_step(fm, factor, gradient, x, r, c, active, mode, seg, Ds):
    """The joint Newton step (dx, d delta_slipping): the pose's Newton step
    corrected by the slips that keep the capstan equalities (their Schur
    complement on H's factor)."""
    Hg = factor.solve(gradient)
    if not active.any():
        return -Hg, np.zeros(0)
    _, hs, dh_dx, dh_dr, _ = capstan_residual(fm, x, r, c, active, mode, seg)
    HB = factor.solve(fm.mixed_r(x, r, c, seg) @ Ds)
    dd = np.linalg.lstsq(dh_dr @ Ds - dh_dx @ HB, -hs + dh_dx @ Hg, rcond=None)[0]
    return -Hg - HB @ dd, dd


def _nested_newton(fm, x, r_pred, c, mode, delta, options):
    """Newton on the slip amounts of the slipping points (the others held at
    0) with the pose at equilibrium: (x, delta, equilibrium), or a status."""
    active = mode != STICK
    delta = delta.copy()
    eq = _equilibrium(fm, x, r_pred + fm.D @ delta, c, options)
    if eq is None:
        return "the pose equilibrium at these rest lengths did not converge"
    if not active.any():
        return eq.x, delta, eq
    Ds = fm.D[:, active].toarray()
    for _ in range(options.max_newton):
        r = r_pred + fm.D @ delta
        h, hs, dh_dx, dh_dr, scale = capstan_residual(fm, eq.x, r, c, active, mode)
        if np.max(np.abs(h)) <= options.tol * scale:
            return eq.x, delta, eq
        norm = float(np.max(np.abs(hs)))
        dx_dd = -eq.factor.solve(fm.mixed_r(eq.x, r, c) @ Ds)
        J = dh_dr @ Ds + dh_dx @ dx_dd
        d = np.linalg.lstsq(J, -hs, rcond=None)[0]
        alpha, accepted = 1.0, None
        for _ in range(options.max_backtracks):
            trial = delta.copy()
            trial[active] += alpha * d
            r_t = r_pred + fm.D @ trial
            eq_t = _equilibrium(fm, eq.x + alpha * (dx_dd @ d), r_t, c, options) \
                or _equilibrium(fm, eq.x, r_t, c, options)
            if eq_t is not None:
                h_t = capstan_residual(fm, eq_t.x, r_t, c, active, mode)[1]
                if np.max(np.abs(h_t)) < (1 - ARMIJO * alpha) * norm:
                    accepted = (trial, eq_t)
                    break
            alpha /= 2
        if accepted is None:
            return "the capstan Newton found no step that reduces the residual"
        delta, eq = accepted
    return f"the capstan Newton did not converge in {options.max_newton} iterations"
