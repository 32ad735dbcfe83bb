"""Quasi-static equilibria: local minimisers of E(x; c).

Two backends on the same energy:

* ``newton`` (default): Newton on the exact sparse Hessian, CHOLMOD
  factorisation (symbolic analysis once per model), backtracking line
  search that never accepts a non-admissible pose (some J <= 0) or a
  non-finite energy, a multiple of the identity added when the Hessian is
  not positive definite, and an escape along the most negative curvature
  direction when the gradient vanishes at a saddle.
* ``ipopt``: IPOPT minimising the CasADi expression of E, for cross-checks
  (:class:`IpoptEquilibrium`, which keeps the NLPs it builds for its model;
  the module holds no state).

Both return an :class:`Equilibrium` that is *certified* by the same test:
``converged`` only if the residual |grad_x E| is within tolerance relative
to the force scale and the Hessian is positive definite (Cholesky succeeds).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from ..base.errors import SolverError
from ..base.linalg import Factor, NotPositiveDefinite, smallest_eigenpair
from ..fem.model import Evaluation, Model

log = logging.getLogger(__name__)

BACKENDS = ("newton", "ipopt")

# the status of a solve that met an indefinite Hessian with ``regularise=False``
LEFT_BRANCH = "left the stable branch"


@dataclass(frozen=True)
class EquilibriumOptions:
    """Options of the equilibrium solvers.

    Attributes
    ----------
    backend : 'newton' (default) or 'ipopt'.
    gtol : relative residual tolerance: converged when
        |grad_x E| <= gtol * force_scale.
    max_iterations : Newton iterations (IPOPT: its max_iter). Generous:
        with tendons far stiffer than the body, Newton's full steps
        zig-zag between the tendons' smoothing zones for hundreds of
        iterations.
    armijo : sufficient-decrease constant of the line search.
    max_backtracks : cuts of the step before the line search gives up.
    backtrack : factor a rejected step is cut by (0 < backtrack < 1).
    escape_saddles : at a saddle (gradient zero, Hessian indefinite), step
        along the most negative curvature direction and continue.
    max_escapes : how many saddles may be escaped in one solve.
    escape_halvings : step sizes tried along the negative curvature
        direction, from the mesh size (sqrt of the mean element area)
        halving down: the first that lowers the energy is taken.
    symmetric_gradient : an indefinite Hessian whose most negative
        curvature direction v has |g . v| <= symmetric_gradient * |g| is
        on a symmetric branch (the gradient is blind to the unstable
        direction) and is left along v like a saddle.
    eigenvalue : compute the smallest Hessian eigenvalue at the end (a few
        extra solves with the final factor).
    regularise : take a regularised step where the Hessian is not positive
        definite (default). False: stop there instead, with a status that
        starts with ``LEFT_BRANCH`` (the solve cannot stay on the stable
        branch it started on; plush_opt/solve/branch.py then continues in c).
        With ``escape_saddles`` it first checks for a symmetric branch (a
        gradient blind to the negative curvature: a regularised factor and
        a Lanczos run) and escapes from it as usual; after such an escape (a
        pitchfork: the path goes on, buckled) the steps down to the buckled
        branch are regularised as usual. A saddle where the gradient
        vanishes is reported, not escaped (on a branch, that is the fold at
        its end).
    shift_floor : the smallest regularisation shift, relative to the mean
        |diagonal| of H: a shift below it does not change a factorisation.
    shift_growth : factor the shift grows by until H + shift I factors; the
        next indefinite step of the same solve starts one such factor below
        the last shift (consecutive Hessians are alike).
    max_shifts : shifts tried before the regularisation gives up.
    stall_residual, stall_window, stall_gain : Newton stops as stalled when
        the relative residual is below ``stall_residual`` (near the
        tolerance, where round-off of sliver elements or an
        ill-conditioned H can set a floor above gtol), more than
        2 * stall_window iterations ran, and the best residual of the last
        ``stall_window`` is not below ``stall_gain`` times the best before.
    ipopt : raw IPOPT options (backend 'ipopt'), passed through.
    """

    backend: str = "newton"
    gtol: float = 1e-10
    max_iterations: int = 500
    armijo: float = 1e-4
    max_backtracks: int = 60
    backtrack: float = 0.5            # halving: the classic backtracking cut
    escape_saddles: bool = True
    max_escapes: int = 5
    escape_halvings: int = 30         # down to 2^-29 (~2e-9) of the mesh size: a smaller step escapes nothing
    symmetric_gradient: float = 1e-6  # far above round-off of g . v, far below a real component
    eigenvalue: bool = True
    regularise: bool = True
    shift_floor: float = 1e-8         # lifts round-off pivots, leaves the step close to Newton's
    shift_growth: float = 10.0        # a decade per try: few factorisations, shift within 10x of needed
    max_shifts: int = 40              # a bound on the loop: 40 decades above the floor, never needed
    stall_residual: float = 1e-6      # a stall only counts near the tolerance, not in the global phase
    stall_window: int = 20            # long enough that a slow linear phase is not taken for a stall
    stall_gain: float = 0.5           # progress means halving the best residual over a window
    ipopt: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {BACKENDS}, got {self.backend!r}")
        if not (0 < self.gtol < 1):
            raise ValueError(f"gtol: expected 0 < gtol < 1, got {self.gtol!r}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations: expected >= 1, got {self.max_iterations!r}")
        if not (0 < self.armijo < 0.5):
            raise ValueError(f"armijo: expected 0 < armijo < 0.5, got {self.armijo!r}")
        for name in ("backtrack", "stall_gain", "stall_residual", "symmetric_gradient", "shift_floor"):
            if not (0 < getattr(self, name) < 1):
                raise ValueError(f"{name}: expected a number in (0, 1), got {getattr(self, name)!r}")
        if not self.shift_growth > 1:
            raise ValueError(f"shift_growth: expected > 1, got {self.shift_growth!r}")
        for name in ("max_backtracks", "escape_halvings", "max_shifts", "stall_window"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected >= 1, got {getattr(self, name)!r}")
        if self.max_escapes < 0:
            raise ValueError(f"max_escapes: expected >= 0, got {self.max_escapes!r}")


@dataclass(frozen=True)
class Equilibrium:
    """The result of an equilibrium solve.

    Attributes
    ----------
    x : (n_dofs,) flat pose, interleaved [x0, y0, x1, y1, ...].
    contraction : (n_winches,) the contractions it was solved at.
    converged : residual within tolerance and Hessian positive definite.
    status : short human-readable reason.
    energy : E(x; c).
    residual_norm : |grad_x E(x; c)|, 2-norm.
    force_scale : the force size the residual is judged against.
    positive_definite : the Hessian at x has a Cholesky factor.
    min_eigenvalue : smallest Hessian eigenvalue (None if not computed).
    iterations, t_wall : Newton (or IPOPT) iterations and seconds.
    backend : 'newton' or 'ipopt'.
    saddle_escapes : saddles escaped on the way.
    factor : Cholesky factor of the Hessian at x (for sensitivities), or None.
    """

    x: np.ndarray
    contraction: np.ndarray
    converged: bool
    status: str
    energy: float
    residual_norm: float
    force_scale: float
    positive_definite: bool
    min_eigenvalue: float | None
    iterations: int
    t_wall: float
    backend: str
    saddle_escapes: int = 0
    factor: Factor | None = field(default=None, repr=False, compare=False)

    @property
    def nodes(self) -> np.ndarray:
        """(n_nodes, 2) pose."""
        return self.x.reshape(-1, 2)

    @property
    def relative_residual(self) -> float:
        return self.residual_norm / self.force_scale if self.force_scale > 0 else np.inf


def solve_equilibrium(model: Model, contraction, x0=None, options: EquilibriumOptions | None = None,
                      ipopt: IpoptEquilibrium | None = None) -> Equilibrium:
    """Equilibrium of ``model`` at ``contraction`` (n_winches,), from ``x0``
    (flat or (n_nodes, 2); default the rest pose). ``x0`` must be admissible.

    ``ipopt`` : the IPOPT backend's solver of this model, which keeps the
    NLPs it built (default: a new one, built for this solve alone)."""
    options = options or EquilibriumOptions()
    c = np.array(contraction, dtype=np.float64).reshape(-1)
    if c.shape != (model.n_winches,):
        raise SolverError(f"contraction: expected {model.n_winches} values, got {c.size}")
    x = model.X.copy() if x0 is None else np.array(x0, dtype=np.float64).reshape(-1)
    if x.shape != (model.n_dofs,):
        raise SolverError(f"x0: expected {model.n_dofs} coordinates, got {x.size}")
    if options.backend == "ipopt":
        if ipopt is None:
            ipopt = IpoptEquilibrium(model)
        elif ipopt.model is not model:
            raise ValueError("ipopt: an IpoptEquilibrium of another model")
        return ipopt.solve(c, x, options)
    return _solve_newton(model, c, x, options)


def residual(model: Model, x, contraction) -> np.ndarray:
    """The equilibrium residual grad_x E(x; c), (n_dofs,) force units.

    Zero at an equilibrium; the same residual drives the solvers, their
    certificate, the implicit sensitivities and the tests."""
    ev = model.evaluate(x, contraction, order=1)
    if not ev.admissible:
        raise SolverError("residual: the pose is not admissible (some element has J <= 0)")
    return ev.gradient


def certify(model: Model, eq: Equilibrium) -> Equilibrium:
    """``eq`` with its smallest Hessian eigenvalue, for a result file.

    Uses the factor the solver kept (shift-invert Lanczos, no new
    factorisation) when there is one; a failure of this diagnostic never
    discards the pose."""
    if eq.min_eigenvalue is not None:
        return eq
    try:
        if eq.factor is not None and eq.factor.shift == 0.0:
            lam = eq.factor.min_eigenvalue()
        else:
            ev = model.evaluate(eq.x, eq.contraction, order=2)
            if ev.hessian_form is None:
                return eq
            lam, _ = smallest_eigenpair(ev.hessian)
    except SolverError as exc:
        log.warning("smallest Hessian eigenvalue not computed: %s", exc)
        return eq
    return replace(eq, min_eigenvalue=float(lam))


# --------------------------------------------------------------------------
# Newton
# --------------------------------------------------------------------------

# Round-off of E relative to its size (|E|, the elastic scale, the work of
# gravity): a few hundred machine epsilons, the error of summing O(mu)
# element terms whose difference is E.
ENERGY_ROUNDOFF = 1e-13
# Energy changes within this many round-off allowances are noise: the full
# Newton step is then judged by the residual it leaves instead.
ROUNDOFF_BAND = 100.0
# ... and is taken if it cuts the residual by at least this factor.
ROUNDOFF_RESIDUAL_CUT = 0.5
# A mode whose net displacement is below this fraction of its 1-norm has
# none (an antisymmetric mode): its sign is fixed by its largest component.
NO_NET_DISPLACEMENT = 1e-8


def _energy_slack(model: Model, ev_energy: float, x: np.ndarray) -> float:
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


def _finish(model, c, x, ev: Evaluation, factor, converged, status, it, t0, options,
            backend="newton", escapes=0) -> Equilibrium:
    pd = factor is not None and factor.shift == 0.0
    min_eig = None
    try:   # a diagnostic: its failure must not discard a certified pose
        if pd and options.eigenvalue:
            min_eig = factor.min_eigenvalue()
        elif options.eigenvalue and ev.hessian_form is not None:
            min_eig, _ = smallest_eigenpair(ev.hessian)
    except SolverError as exc:
        log.warning("smallest Hessian eigenvalue not computed: %s", exc)
    residual = float(np.linalg.norm(ev.gradient)) if ev.gradient is not None else np.inf
    return Equilibrium(
        x=x, contraction=c, converged=bool(converged and pd), status=status,
        energy=ev.energy, residual_norm=residual, force_scale=ev.force_scale,
        positive_definite=pd, min_eigenvalue=min_eig, iterations=it,
        t_wall=time.perf_counter() - t0, backend=backend, saddle_escapes=escapes,
        factor=factor if pd else None)


def _try_factor(model: Model, H) -> Factor | None:
    try:
        return model.factorizer.factor(H)
    except NotPositiveDefinite:
        return None


def _escape_saddle(model: Model, c, x, ev: Evaluation, options: EquilibriumOptions,
                   pair=None) -> tuple[np.ndarray, Evaluation] | None:
    """Step from a saddle along its most negative curvature direction.

    The sign is fixed (net displacement of the mode positive) so the outcome
    is deterministic; both signs are tried, the lower energy wins (the first
    sign on a tie: a symmetric scene always buckles the same way).
    """
    lam, v = pair if pair is not None else smallest_eigenpair(ev.hessian)
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
            if et.admissible and np.isfinite(et.energy) and et.energy < ev.energy - _energy_slack(model, ev.energy, x):
                if best is None or et.energy < best[0] - _energy_slack(model, et.energy, xt):
                    best = (et.energy, xt)
        if best is not None:
            break
    if best is None:
        return None
    log.info("escaped a saddle (lambda_min = %.3g) by a step of %.3g", lam, s)
    return best[1], model.evaluate(best[1], c, order=2)


def _left_branch(it: int) -> str:
    return f"{LEFT_BRANCH}: Hessian not positive definite after {it} iteration(s)"


def _stalled(history: list[float], options: EquilibriumOptions) -> bool:
    """No progress over the last ``stall_window`` relative residuals of
    ``history`` near the tolerance (see :class:`EquilibriumOptions`)."""
    w = options.stall_window
    return (history[-1] < options.stall_residual and len(history) > 2 * w
            and min(history[-w:]) > options.stall_gain * min(history[:-w]))


def _line_search(model: Model, c, x, ev: Evaluation, dx, options: EquilibriumOptions):
    """Backtracking from the full step ``dx``: the accepted (x, evaluation
    with its Hessian) and the step length, or (None, 0.0). A step is never
    accepted at a non-admissible pose or a non-finite energy."""
    g = ev.gradient
    slope = float(g @ dx)
    slack = _energy_slack(model, ev.energy, x)
    alpha = 1.0
    for k in range(options.max_backtracks):
        xt = x + alpha * dx
        et = model.evaluate(xt, c, order=2 if k == 0 else 0)
        if not (et.admissible and np.isfinite(et.energy)):
            alpha *= options.backtrack
            continue
        if et.energy <= ev.energy + options.armijo * alpha * slope + slack:
            return (xt, et if k == 0 else model.evaluate(xt, c, order=2)), alpha
        if k == 0 and et.energy <= ev.energy + ROUNDOFF_BAND * slack and \
                np.linalg.norm(et.gradient) < ROUNDOFF_RESIDUAL_CUT * np.linalg.norm(g):
            # energy differences at round-off level: judge the full
            # Newton step by the residual it leaves instead
            return (xt, et), alpha
        alpha *= options.backtrack
    return None, 0.0


def _solve_newton(model: Model, c, x, options: EquilibriumOptions) -> Equilibrium:
    t0 = time.perf_counter()
    ev = model.evaluate(x, c, order=2)
    if not ev.admissible:
        return Equilibrium(x, c, False, "initial pose not admissible (some element has J <= 0)",
                           np.inf, np.inf, np.nan, False, None, 0, time.perf_counter() - t0,
                           "newton")
    escapes = 0
    status = f"iteration limit ({options.max_iterations}) reached"
    best: list[float] = []        # relative residual per iteration (stall detection)
    watch_symmetry = True         # look for a gradient blind to negative curvature
    last_shift = None             # regularisation of the previous indefinite step
    converged = False
    factor = None
    it = 0
    while True:
        g, H = ev.gradient, ev.hessian_form
        factor = _try_factor(model, H)
        small = np.linalg.norm(g) <= options.gtol * ev.force_scale
        if small and factor is not None:
            converged = True
            status = "converged" if escapes == 0 else f"converged (escaped {escapes} saddle(s))"
            break
        if small:
            # (not when staying on a branch: a converged point with an
            # indefinite Hessian there is the fold at its end, past which
            # the escape would snap through)
            if options.escape_saddles and options.regularise and escapes < options.max_escapes:
                escaped = _escape_saddle(model, c, x, ev, options)
                if escaped is not None:
                    x, ev = escaped
                    escapes += 1
                    continue
            status = "saddle: the gradient vanishes but the Hessian is not positive definite"
            break
        if it >= options.max_iterations:
            break
        rel = np.linalg.norm(g) / ev.force_scale
        best.append(rel)
        if factor is not None and _stalled(best, options):
            # round-off (a sliver element, an ill-conditioned H) sets a floor above gtol
            status = (f"residual stalled at {min(best):.1e} of the force scale, above gtol "
                      f"{options.gtol:g} (a round-off floor: badly shaped elements or an "
                      "ill-conditioned Hessian)")
            break
        if factor is None and not options.regularise and not options.escape_saddles:
            status = _left_branch(it)      # (no symmetric-branch check to make first)
            break
        if factor is None:
            step_factor = _regularised_factor(model, H, options, last_shift)
            last_shift = step_factor.shift
        else:
            step_factor = factor
        if factor is None and watch_symmetry and options.escape_saddles and escapes < options.max_escapes:
            # Indefinite Hessian with a gradient blind to the unstable
            # direction (a symmetric scene on its symmetric branch): a
            # regularised step would pick a side by round-off. Leave along
            # the negative curvature by the same rule as at a saddle. (Once
            # the gradient is seen to have a component along it, the scene
            # is not on a symmetric branch: no more checks this solve.)
            pair = step_factor.most_negative_eigenpair()
            if pair is not None and abs(g @ pair[1]) <= options.symmetric_gradient * np.linalg.norm(g):
                escaped = _escape_saddle(model, c, x, ev, options, pair)
                if escaped is not None:
                    x, ev = escaped
                    escapes += 1
                    it += 1
                    continue
            watch_symmetry = pair is None
        if factor is None and not options.regularise and escapes == 0:
            status = _left_branch(it)
            break
        it += 1
        accepted, alpha = _line_search(model, c, x, ev, -step_factor.solve(g), options)
        log.debug("newton %d: residual %.3e, shift %.3e, step %.3e", it, rel, step_factor.shift, alpha)
        if accepted is None:
            status = "line search failed: no admissible step decreases the energy"
            break
        x, ev = accepted
    return _finish(model, c, x, ev, factor, converged, status, it, t0, options, "newton", escapes)


# --------------------------------------------------------------------------
# IPOPT
# --------------------------------------------------------------------------

# IPOPT silent, with the exact Hessian, and its own tolerances tighter than
# the certificate's (relative 1e-10 of the force scale), which decides.
_IPOPT_DEFAULTS = {
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "print_time": False,
    "show_eval_warnings": False,
    "ipopt.tol": 1e-12,
    "ipopt.acceptable_tol": 1e-10,
    "ipopt.hessian_approximation": "exact",
}
# The polishing run's absolute tolerance per coordinate: this fraction of
# the certificate's residual spread over the sqrt(n_dofs) coordinates, so
# that IPOPT's max-norm test implies the certificate's 2-norm test.
POLISH_MARGIN = 0.5


class IpoptEquilibrium:
    """IPOPT minimising one model's energy E(x; c) over x (c a parameter),
    certified afterwards by the Newton backend's test.

    Building IPOPT's NLP (CasADi's exact Hessian of E) takes far longer
    than a solve, so the solvers built here, one per IPOPT option set, are
    kept on this object: hold one per model and pass it to every solve
    (:func:`solve_equilibrium`'s ``ipopt``) to build each once.
    """

    def __init__(self, model: Model):
        self.model = model
        self._solvers: dict[str, ca.Function] = {}

    def solver(self, options: EquilibriumOptions, extra: dict | None = None) -> ca.Function:
        """The NLP solver for these options (``extra``: IPOPT options of a
        polishing run), built on first use."""
        opts = dict(_IPOPT_DEFAULTS)
        opts["ipopt.max_iter"] = options.max_iterations
        opts.update(extra or {})
        opts.update(options.ipopt)
        key = repr(sorted(opts.items()))
        if key not in self._solvers:
            m = self.model
            self._solvers[key] = ca.nlpsol("equilibrium", "ipopt", {"x": m.x_sym, "p": m.c_sym, "f": m.E_sym}, opts)
        return self._solvers[key]

    def solve(self, c: np.ndarray, x: np.ndarray, options: EquilibriumOptions) -> Equilibrium:
        """Minimise E at ``c`` (n_winches,) from the admissible ``x`` (n_dofs,).

        IPOPT treats a non-finite energy (log J of an inverted element) as an
        evaluation error and cuts its step back, so it stays admissible.
        ``converged`` is the certificate's verdict, whatever IPOPT's return
        status (which the status string reports when it differs).
        IPOPT's own stopping test works on a scaled problem; when its answer
        misses the certificate's residual only, it is run again from there with
        no scaling and an absolute tolerance taken from the force scale. Where
        it stops on a saddle it is restarted past it along the most negative
        curvature (the Newton backend's rule), up to ``max_escapes`` times.
        """
        model = self.model
        t0 = time.perf_counter()
        if not model.admissible(x):
            return Equilibrium(x, c, False, "initial pose not admissible (some element has J <= 0)",
                               np.inf, np.inf, np.nan, False, None, 0, 0.0, "ipopt")
        iterations, escapes, polished = 0, 0, False
        extra = {}
        while True:
            solver = self.solver(options, extra)
            sol = solver(x0=x, p=c)
            stats = solver.stats()
            iterations += int(stats.get("iter_count", 0))
            xs = np.array(sol["x"], dtype=np.float64).reshape(-1)
            ev = model.evaluate(xs, c, order=2)
            if not ev.admissible:
                return Equilibrium(xs, c, False, f"ipopt: {stats['return_status']}; pose not admissible",
                                   np.inf, np.inf, np.nan, False, None, iterations,
                                   time.perf_counter() - t0, "ipopt")
            factor = _try_factor(model, ev.hessian_form)
            small = np.linalg.norm(ev.gradient) <= options.gtol * ev.force_scale
            if factor is not None and not small and not polished:
                # the residual alone misses the certificate: once more, unscaled
                tol = POLISH_MARGIN * options.gtol * ev.force_scale / np.sqrt(model.n_dofs)
                # a power of ten below: solvers are kept per option set, and
                # a pose-dependent tolerance would build a new one every time
                tol = float(10.0 ** np.floor(np.log10(tol)))
                extra = {"ipopt.nlp_scaling_method": "none", "ipopt.tol": tol,
                         "ipopt.acceptable_iter": 0}
                x, polished = xs, True
                continue
            if factor is None and small and options.escape_saddles and escapes < options.max_escapes:
                escaped = _escape_saddle(model, c, xs, ev, options)
                if escaped is not None:
                    x, escapes = escaped[0], escapes + 1
                    continue
            break
        status = _ipopt_status(stats, small, factor, escapes)
        return _finish(model, c, xs, ev, factor, small and factor is not None, status, iterations, t0,
                       options, "ipopt", escapes)


def _ipopt_status(stats: dict, small: bool, factor, escapes: int) -> str:
    """The status of an IPOPT solve: the certificate decides, not IPOPT's
    own flag (IPOPT may end with "search direction too small" on a pose
    that passes it), which is reported where it differs."""
    note = f" (escaped {escapes} saddle(s))" if escapes else ""
    if small and factor is not None:
        status = "converged" + note
        if not stats["success"]:
            status += f" (ipopt ended with {stats['return_status']}; the pose passes the certificate)"
        return status
    if factor is None:
        return f"ipopt: {stats['return_status']}; Hessian not positive definite (saddle or maximum)"
    if not small:
        return f"ipopt: {stats['return_status']}; residual above tolerance"
    return f"ipopt: {stats['return_status']}"
