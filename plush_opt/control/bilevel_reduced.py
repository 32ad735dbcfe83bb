"""The bilevel method in the reduced space: IPOPT on the contractions only.

The full-space NLP (:mod:`.bilevel_nlp`) keeps the pose x as variables and
grad_x E(x, c) = 0 as constraints. Here the constraint is eliminated by the
implicit function theorem instead of being handed to IPOPT: at every point
IPOPT asks for, x(c) is the certified stable equilibrium (Newton, warm
started with the first-order predictor), so the NLP is

    minimise    O(c) = 1/2 |r(x(c))|^2        over the free c
    subject to  lower <= c <= upper           (IPOPT variable bounds)

with r the weighted target residuals. Its derivatives come from the
equilibrium's own Cholesky factor: dx/dc = -H^-1 d2E/dxdc (one back
substitution per free winch), so dr/dc = sqrt(w) B dx/dc, the gradient is
J^T r and the Hessian IPOPT gets is the Gauss-Newton J^T J (the term with
the residuals times d2x/dc2 is dropped: it needs third derivatives of E,
and it vanishes where the targets are reached).

It is still the bilevel KKT point in IPOPT with explicit bounds: IPOPT's
stationarity and complementarity conditions on c are those of the full NLP
with the equilibrium multipliers eliminated (lambda = -H^-1 dO/dx, the
adjoint). What changes is that every iterate is a certified equilibrium,
so a saddle of E cannot be a KKT point of this NLP, the history is a list
of poses a robot could be sent to, and IPOPT's linear algebra is on
n_free variables instead of about 2 n_dofs + n_elems.

CasADi sees the residual as a :class:`casadi.Callback` whose Jacobian is
another callback, whose own Jacobian is declared zero: that makes CasADi's
exact Hessian of 1/2 |r|^2 the Gauss-Newton one. Nothing is generated or
compiled, so building the solver costs milliseconds.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..solve.branch import follow_branch
from ..solve.equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium
from ..fem.model import Model
from ..fem.objective import Targets
from ..solve.ipopt_equilibrium import IterationCallback
from ..solve.sensitivity import state_sensitivity
from .policy import LEVENBERG_MARQUARDT, predict
from .result import ControlIterate

# Equilibria kept for warm starts and for IPOPT's repeated calls at the
# same point (objective, gradient and Hessian are asked for separately).
CACHE_SIZE = 8
# A tendon whose stretch is below this fraction of -eps (the lower half of
# the smoothing zone, where the slack take-up leaves it) carries almost no
# force: a winch whose tendons all are there has a (nearly) zero column in
# dr/dc and gets the absolute damping floor.
NEAR_SLACK = 0.5
# Branch ends a point remembers (a direction, a distance): IPOPT's line
# search cuts its step back along one ray from its iterate.
MAX_ENDS = 32
# Two moves from the same point are along the same ray when their unit
# directions differ by less than this (round-off in IPOPT's c + alpha d).
SAME_RAY = 1e-6
# A secant pair (s, y) updates the second-order estimate only if its
# curvature s.y is at least this fraction of |s| |y| (BFGS's safeguard).
SECANT_CURVATURE = 1e-8
# The curvature scale of the slack winches' damping never falls below the
# smallest normal float (a positive damping where every column vanishes).
CURVATURE_FLOOR = float(np.finfo(float).tiny)


@dataclass
class Point:
    """One contraction vector with its certified equilibrium and derivatives."""

    c: np.ndarray              # (n_winches,)
    eq: Equilibrium
    r: np.ndarray              # (2 k,) weighted residuals
    J: np.ndarray | None       # (2 k, n_free) dr/dc_free, computed on demand
    dxdc: np.ndarray | None    # (n_dofs, n_winches), free columns filled
    # (unit direction, distance): the branch through this point ends before
    # that distance along that ray (it goes with the point out of the cache)
    ends: list = field(default_factory=list)

    @property
    def objective(self) -> float:
        return 0.5 * float(self.r @ self.r)

    def gradient(self) -> np.ndarray:
        """dO/dc_free."""
        return self.J.T @ self.r


def _ray(c0: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, float]:
    """Unit direction and length of the move c0 -> c (direction 0 for none)."""
    d = c - c0
    dist = float(np.linalg.norm(d))
    return (d / dist if dist > 0.0 else d), dist


class Evaluator:
    """O(c), r(c) and dr/dc by Newton and the implicit sensitivity, cached.

    A contraction at which Newton does not certify a stable equilibrium
    gives NaN residuals: IPOPT treats that as an evaluation error and cuts
    its step back. The equilibrium is the one on the stable branch through
    the nearest point already certified (plush_opt/solve/branch.py, as the
    gradient loop's line-search trials): past a limit point of that branch
    the evaluation fails in a few Newton iterations instead of following a
    snap-through (or running to the iteration limit on the way there)."""

    def __init__(self, model: Model, targets: Targets, c_full: np.ndarray, free: np.ndarray,
                 start: Equilibrium, options: EquilibriumOptions, damping: float = 0.0,
                 secant: bool = False):
        self.model, self.targets = model, targets
        self.damping = damping
        # the slack winches' damping follows the gradient loop's schedule,
        # started at and capped by ``damping``
        self.schedule = LEVENBERG_MARQUARDT.with_cap(float(damping), curvature_floor=CURVATURE_FLOOR)
        self.mu = np.full(len(free), float(damping))   # the current (adapted) damping, per winch
        self._solves_seen = 0                       # self.solves at the last accepted iterate
        self.secant = secant
        self.S = np.zeros((len(free), len(free)))   # the secant estimate of r . d2r/dc2
        self.accepted: Point | None = None
        self.c_full, self.free = c_full.copy(), free
        self.options = options
        self.B = targets.selection(model.n_dofs)
        self.sqrt_w = np.repeat(np.sqrt(targets.weight), 2)
        self.points: list[Point] = []
        self.solves = 0
        self.newton_iterations = 0
        self.failures = 0
        self.past_end = 0                           # evaluations known to fail without a solve
        self.t_evaluations = 0.0
        self.error: BaseException | None = None
        self.add(start)

    def guarded(self, fn, *args):
        """fn(*args) inside IPOPT's callbacks: the first exception is kept
        (CasADi would turn it into an invalid number, IPOPT's
        Invalid_Number_Detected) and None returned, so that the run stops
        IPOPT and re-raises it; after one, every call returns None."""
        if self.error is not None:
            return None
        try:
            return fn(*args)
        except (Exception, KeyboardInterrupt) as err:   # noqa: BLE001 - re-raised by raise_error
            self.error = err
            return None

    def raise_error(self) -> None:
        """Re-raise the exception a callback kept, if any."""
        err, self.error = self.error, None
        if err is not None:
            raise err

    def add(self, eq: Equilibrium) -> Point:
        point = Point(eq.contraction.copy(), eq, self.targets.residual(eq.x), None, None)
        self._keep(point)
        return point

    def _keep(self, point: Point) -> None:
        self.points = [p for p in self.points if not np.array_equal(p.c, point.c)]
        self.points.append(point)
        del self.points[:-CACHE_SIZE]

    def contraction(self, c_free) -> np.ndarray:
        c = self.c_full.copy()
        c[self.free] = np.asarray(c_free, dtype=np.float64).reshape(-1)
        # IPOPT may relax the bounds by its bound_relax_factor (1e-8 x the
        # bound): every point evaluated, kept and returned stays within them
        return np.clip(c, self.model.lower, self.model.upper)

    def at(self, c_free, on_branch: bool = True) -> Point | None:
        """The certified point at ``c_free`` (cached), or None where there is none.

        ``on_branch`` : follow the stable branch from the nearest point
        (IPOPT's evaluations); False for a plain Newton solve from its
        predictor, which may land on another branch (the look-further
        probes, as the gradient loop's restart probes)."""
        c = self.contraction(c_free)
        for p in reversed(self.points):
            if np.array_equal(p.c, c):
                return p
        near = min(self.points, key=lambda p: float(np.max(np.abs(p.c - c))))
        if on_branch and self._past_known_end(near, c):
            self.past_end += 1
            return None
        t0 = time.perf_counter()
        guess = self._predict(near, c)
        if on_branch:
            # Newton without regularisation from the predictor: where every
            # Hessian on the way is positive definite (no fold near) it takes
            # the plain solve's iterates exactly
            eq, failed = follow_branch(self.model, near.c, near.eq.x, c, guess, self.options)
            if failed is not None:
                u, dist = _ray(near.c, c)
                near.ends.append((u, failed * dist))
                del near.ends[:-MAX_ENDS]
        else:
            eq = solve_equilibrium(self.model, c, guess, self.options)
        self.t_evaluations += time.perf_counter() - t0
        self.solves += 1
        self.newton_iterations += eq.iterations
        if not eq.converged:
            self.failures += 1
            return None
        return self.add(eq)

    def _past_known_end(self, near: Point, c) -> bool:
        """Is ``c`` on a ray from ``near`` along which the branch has been
        seen to end, at least as far out? IPOPT cuts a step that failed by
        halves along the same ray; where the branch ends close to its
        iterate (creeping up to a fold), each halving that is still past
        the end would otherwise cost a branch-following solve that fails
        (docs/bilevel.md, "Staying on the branch")."""
        u, dist = _ray(near.c, c)
        return dist > 0.0 and any(dist >= end and np.max(np.abs(u - v)) <= SAME_RAY for v, end in near.ends)

    def _predict(self, near: Point, c) -> np.ndarray:
        """x + dx/dc (c - c_near) if admissible, else x (the loop's predictor)."""
        return predict(self.model, near.eq.x, near.dxdc, near.c, c)

    def rows(self, point: Point) -> np.ndarray:
        """The residuals IPOPT sees: r and n_free zeros (the damping rows)."""
        return np.concatenate([point.r, np.zeros(len(self.free))])

    def jacobian_rows(self, point: Point) -> np.ndarray:
        """dr/dc and the damping rows: their value is zero, so O and its
        gradient are untouched, and the Hessian IPOPT gets is J^T J + D.

        D is lambda = damping x the largest |J_j|^2 on the winches whose
        tendons are all (nearly) slack, whose column of J is (nearly) zero:
        their step is bounded instead of set by the barrier alone. Every
        other winch gets no damping: its Gauss-Newton curvature is real,
        however small (one uniform lambda I, which IPOPT cannot adapt,
        swamps a winch that moves the targets little). The factor is each
        winch's adapted ``mu`` (:meth:`_adapt_damping`), not the fixed
        start: a nearly slack winch may still move the targets (the
        smoothing zone carries a little force), and a fixed lambda makes
        its steps g / lambda, a linear crawl to its bound (docs/bilevel.md,
        "Hessian")."""
        J = self.derivatives(point).J
        curv = np.sum(J * J, axis=0)
        lam = self.schedule.scale(curv)
        d = np.where(self._near_slack(point), lam, 0.0)
        if not self.S.any():
            return np.vstack([J, np.diag(np.sqrt(self.mu * d))])
        # rows L with L^T L = D + S (both positive semidefinite)
        vals, vecs = np.linalg.eigh(np.diag(self.mu * d) + self.S)
        return np.vstack([J, np.sqrt(np.maximum(vals, 0.0))[:, None] * vecs.T])

    def new_round(self) -> None:
        """A new IPOPT round (after a look-further jump): no secant pair
        across the jump, and the damping back at its start."""
        self.accepted = None
        self.mu = np.full(len(self.free), self.schedule.initial)
        self._solves_seen = self.solves

    def accept(self, point: Point) -> None:
        """An iterate IPOPT accepted: adapt the slack winches' damping
        (:meth:`_adapt_damping`) and update the secant estimate S of the
        second-order term r . d2r/dc2 the Gauss-Newton Hessian drops
        (structured BFGS: S s = (J_new - J_old)^T r_new, kept positive
        definite by skipping a pair with no positive curvature). Where a
        winch moves the targets far less than another its Gauss-Newton
        curvature is far below the true one, and IPOPT's steps along it
        overshoot and backtrack (docs/bilevel.md, "Secant term")."""
        prev, self.accepted = self.accepted, self.derivatives(point)
        trials, self._solves_seen = self.solves - self._solves_seen, self.solves
        if prev is None:
            return
        step = point.c[self.free] - prev.c[self.free]
        self._adapt_damping(prev, point, step, trials)
        if not self.secant:
            return
        y = (point.J - prev.J).T @ point.r
        sy = float(step @ y)
        if (not sy > SECANT_CURVATURE * float(np.linalg.norm(step) * np.linalg.norm(y))
                or not np.array_equal(self._near_slack(point), self._near_slack(prev))):
            # no positive curvature along the step, or a step across the
            # tendon law's kink (a winch went slack or taut: its curvature
            # there says nothing about the other side): back to
            # Gauss-Newton until the next good pair
            self.S = np.zeros_like(self.S)
            return
        Ss = self.S @ step
        sSs = float(step @ Ss)
        S = self.S
        if sSs > 0:
            # NL2SOL's sizing: shrink S as the residual (hence the term) does,
            # so that near a zero-residual answer the Hessian is Gauss-Newton's
            tau = min(1.0, sy / sSs)
            S, Ss, sSs = tau * S, tau * Ss, tau * sSs
            S = S - np.outer(Ss, Ss) / sSs
        self.S = S + np.outer(y, y) / sy

    def _adapt_damping(self, prev: Point, point: Point, step, trials: int) -> None:
        """The loop's Levenberg-Marquardt schedule (:class:`~.policy.Damping`),
        per winch, for the damping of the slack winches. After a first
        trial that lowered O: down where the step went downhill and left the
        gradient's sign as it was (it fell short: the crawl), up where it
        flipped it (overshot), kept elsewhere. Up by the increase per trial
        IPOPT's line search cut back (the loop's rule per failed trial), and
        once for a step that kept O (IPOPT's barrier and filter accept
        those). Per winch, not one factor for every slack winch: lowered
        after any good step, a shared factor lets one winch be thrown far
        and backtrack after it (docs/bilevel.md, "Hessian")."""
        if point.objective < prev.objective and trials <= 1:
            g_old, g_new = prev.gradient(), point.gradient()
            short = (step * g_old < 0) & (g_old * g_new > 0)
            flipped = g_old * g_new < 0
            lower = self.schedule.accepted(self.mu)
            higher = self.schedule.rejected(self.mu)
            self.mu = np.where(short, lower, np.where(flipped, higher, self.mu))
        else:
            self.mu = self.schedule.rejected(self.mu, max(trials - 1, 1))

    def _near_slack(self, point: Point) -> np.ndarray:
        """Free winches (positions in ``free``) whose every tendon has its
        stretch G at or below -NEAR_SLACK x eps."""
        model = self.model
        if not model.has_tendons:
            return np.zeros(len(self.free), dtype=bool)
        G = model.tendon_state(point.eq.x, point.c)["stretch"]
        cut = -NEAR_SLACK * model.tendon_smoothing
        out = np.zeros(len(self.free), dtype=bool)
        for i, w in enumerate(self.free):
            mine = model.tendon_winch == w
            out[i] = bool(mine.any() and np.all(G[mine] <= cut))
        return out

    def derivatives(self, point: Point) -> Point:
        if point.J is None:
            t0 = time.perf_counter()
            point.dxdc = state_sensitivity(self.model, point.eq, columns=self.free)
            point.J = self.sqrt_w[:, None] * (self.B @ point.dxdc[:, self.free])
            self.t_evaluations += time.perf_counter() - t0
        return point


class _ZeroJacobian:
    """The Jacobian of dr/dc declared zero: CasADi's Hessian becomes J^T J."""

    @staticmethod
    def function(name, inames, onames, shapes_in, n_out_rows) -> ca.Function:
        ins = [ca.MX.sym(n, *s) for n, s in zip(inames, shapes_in)]
        # one block per (output, nominal input); the nominal output is not differentiated
        outs = [ca.MX(n_out_rows, int(np.prod(s))) for s in shapes_in[:len(onames)]]
        return ca.Function(name, ins, outs, inames, onames)


class _JacobianCallback(ca.Callback):
    """(c, r) -> dr/dc, dense (m, n)."""

    def __init__(self, name: str, evaluator: Evaluator, n: int, m: int):
        ca.Callback.__init__(self)
        self.ev, self.n, self.m = evaluator, n, m
        self.construct(name, {})

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.n if i == 0 else self.m, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.m, self.n)

    def eval(self, arg):
        rows = self.ev.guarded(self._rows, arg[0])
        return [ca.DM(np.full((self.m, self.n), np.nan) if rows is None else rows)]

    def _rows(self, c):
        p = self.ev.at(c)
        return None if p is None else self.ev.jacobian_rows(p)

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        return _ZeroJacobian.function(name, inames, onames,
                                      [(self.n, 1), (self.m, 1), (self.m, self.n)], self.m * self.n)


class ResidualCallback(ca.Callback):
    """c_free -> r(x(c)), with :class:`_JacobianCallback` as its Jacobian."""

    def __init__(self, name: str, evaluator: Evaluator, n: int, m: int):
        ca.Callback.__init__(self)
        self.ev, self.n, self.m = evaluator, n, m
        self.jac = None
        self.construct(name, {})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.n, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.m, 1)

    def eval(self, arg):
        rows = self.ev.guarded(self._rows, arg[0])
        return [ca.DM(np.full(self.m, np.nan) if rows is None else rows)]

    def _rows(self, c):
        p = self.ev.at(c)
        return None if p is None else self.ev.rows(p)

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self.jac = _JacobianCallback(name + "_cb", self.ev, self.n, self.m)
        c = ca.MX.sym(inames[0], self.n)
        r = ca.MX.sym(inames[1], self.m)
        return ca.Function(name, [c, r], [self.jac(c, r)], inames, onames)


class IterationRecorder(IterationCallback):
    """IPOPT's iteration callback: one dispatchable iterate per IPOPT
    iteration (each is a certified equilibrium here), and the stop rules
    IPOPT does not have (time limit, objective floor, stall)."""

    def __init__(self, name: str, n: int, rules, evaluator: "Evaluator"):
        ca.Callback.__init__(self)
        self.n, self.rules, self.ev = n, rules, evaluator
        self.sizes = {"x": n, "lam_x": n, "f": 1}
        self.construct(name, {})

    def eval(self, arg):
        stop = self.ev.guarded(self.rules, np.asarray(arg[0], dtype=np.float64).reshape(-1))
        # an error in any callback stops IPOPT at once (the run re-raises it)
        return [1 if stop or self.ev.error is not None else 0]


def build_solver(evaluator: Evaluator, n: int, m: int, ipopt: dict, rules):
    """IPOPT on c_free for this evaluator: (solver, residual callback, recorder).

    The callbacks must outlive the solver (CasADi holds them by reference)."""
    residual = ResidualCallback("reduced_residual", evaluator, n, m)
    recorder = IterationRecorder("reduced_iterations", n, rules, evaluator)
    c = ca.MX.sym("c", n)
    r = residual(c)
    nlp = {"x": c, "f": 0.5 * ca.dot(r, r)}
    opts = {"ipopt." + k: v for k, v in ipopt.items()}
    opts.update({"print_time": False, "show_eval_warnings": False,
                 "iteration_callback": recorder, "iteration_callback_step": 1,
                 "iteration_callback_ignore_errors": False})
    return ca.nlpsol("bilevel_reduced", "ipopt", nlp, opts), residual, recorder


def history_point(point: Point, evaluator: Evaluator, k: int, t: float,
                  active: tuple[str, ...]) -> ControlIterate:
    """A ControlIterate for ``point`` (a certified equilibrium)."""
    grad = np.zeros(evaluator.model.n_winches)
    if point.J is not None:
        grad[evaluator.free] = point.gradient()
    return ControlIterate(iteration=k, t_wall=t, contraction=point.c.copy(),
                          objective=point.objective, equilibrium=point.eq, gradient=grad,
                          active_bounds=active, equilibrium_solves=evaluator.solves,
                          newton_iterations=evaluator.newton_iterations)


def finite(v) -> bool:
    return v is not None and math.isfinite(v)
