"""What an equilibrium solve returns and how it is certified, whatever the
backend: :class:`EquilibriumOptions`, :class:`Equilibrium`, the residual,
and the certificate (``converged`` only if |grad_x E| is within tolerance
relative to the force scale and the Hessian is positive definite).

The solvers are :mod:`plush_opt.solve.newton` and
:mod:`plush_opt.solve.ipopt_equilibrium`; apps and control call
:func:`plush_opt.solve.equilibrium.solve_equilibrium`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..base.errors import SolverError
from ..base.eigenpair import smallest_eigenpair
from ..base.linalg import Factor, NotPositiveDefinite
from ..base.low_rank import abs_product
from ..base.reprs import compact_repr
from ..fem.model import Evaluation, Model

log = logging.getLogger("plush_opt.solve.equilibrium")   # one channel for every backend

#: The status of a pose whose residual, force scale or energy is not finite: never converged.
NOT_FINITE = "residual or energy not finite (forces overflow float64)"

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
    continuation : where Newton from the given start fails, solve again
        by continuation in the contraction from the rest contraction (0
        clipped to the bounds) in this many equal steps (halved where one
        fails), each from the last pose plus the sensitivity's predictor;
        0 (default): no retry. For a history-free model only (the forward
        solve of ``plush-opt solve`` sets it).
    roundoff : a pose whose Hessian is positive definite and whose
        residual is above ``gtol * force_scale`` but within ``roundoff``
        times its round-off floor (:func:`roundoff_floor`) is converged:
        no float64 pose is closer to the equilibrium (a fine mesh's floor
        can exceed gtol). 0 (default): gtol alone; 1: the floor as
        computed (a sum of absolute values: already a worst case), what
        the accuracy sweep's levels and ``--accuracy`` solves use.
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
    continuation: int = 0
    roundoff: float = 0.0             # opt-in (the accuracy levels, --accuracy): gtol alone by default
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
        if not (0 <= self.roundoff < 1e3):
            raise ValueError(f"roundoff: expected a number in [0, 1000), got {self.roundoff!r}")
        if self.continuation < 0:
            raise ValueError(f"continuation: expected >= 0 steps, got {self.continuation!r}")
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
    continuation_steps : contraction steps of the continuation that reached
        it after the solve from the given start failed (0: solved directly;
        ``EquilibriumOptions.continuation``).
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
    continuation_steps: int = 0
    factor: Factor | None = field(default=None, repr=False, compare=False)

    __repr__ = compact_repr      # no pose dumped: arrays by shape

    def __post_init__(self):
        # inf <= gtol * inf holds: a residual, force scale or energy that is
        # not finite (physics overflowing float64) can never certify a pose
        if self.converged and not all(np.isfinite(v) for v in (self.residual_norm, self.force_scale, self.energy)):
            object.__setattr__(self, "converged", False)
            object.__setattr__(self, "status", f"{NOT_FINITE} (the solver said: {self.status})")

    @property
    def nodes(self) -> np.ndarray:
        """(n_nodes, 2) pose."""
        return self.x.reshape(-1, 2)

    @property
    def relative_residual(self) -> float:
        return self.residual_norm / self.force_scale if self.force_scale > 0 else np.inf


def residual(model: Model, x, contraction) -> np.ndarray:
    """The equilibrium residual grad_x E(x; c), (n_dofs,) force units.

    Zero at an equilibrium; the same residual drives the solvers, their
    certificate, the implicit sensitivities and the tests."""
    ev = model.evaluate(x, contraction, order=1)
    if not ev.admissible:
        raise SolverError(f"residual: the pose is not admissible ({model.violation(x)})")
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
            lam, _ = smallest_eigenpair(ev.hessian_form)
    except SolverError as exc:
        log.warning("smallest Hessian eigenvalue not computed: %s", exc)
        return eq
    return replace(eq, min_eigenvalue=float(lam))


def certified(model, c, x, ev: Evaluation, factor, converged, status, it, t0, options,
              backend="newton", escapes=0) -> Equilibrium:
    """The :class:`Equilibrium` at pose ``x`` (evaluation ``ev``, Cholesky
    ``factor`` of its Hessian or None): ``converged`` only if the solver
    says so and the factor is of H itself (no shift); with
    ``options.eigenvalue`` the smallest Hessian eigenvalue is added."""
    pd = factor is not None and factor.shift == 0.0
    min_eig = None
    try:   # a diagnostic: its failure must not discard a certified pose
        if pd and options.eigenvalue:
            min_eig = factor.min_eigenvalue()
        elif options.eigenvalue and ev.hessian_form is not None:
            min_eig, _ = smallest_eigenpair(ev.hessian_form)
    except SolverError as exc:
        log.warning("smallest Hessian eigenvalue not computed: %s", exc)
    norm = float(np.linalg.norm(ev.gradient)) if ev.gradient is not None else np.inf
    return Equilibrium(
        x=x, contraction=c, converged=bool(converged and pd), status=status,
        energy=ev.energy, residual_norm=norm, force_scale=ev.force_scale,
        positive_definite=pd, min_eigenvalue=min_eig, iterations=it,
        t_wall=time.perf_counter() - t0, backend=backend, saddle_escapes=escapes,
        factor=factor if pd else None)


def try_factor(model: Model, H) -> Factor | None:
    """The Cholesky factor of H, or None where H is not positive definite."""
    try:
        return model.factorizer.factor(H)
    except NotPositiveDefinite:
        return None


def roundoff_floor(model: Model, x, contraction) -> float:
    """The round-off floor of the residual at the pose ``x`` (n_dofs,),
    force units (2-norm): how far from zero a float64 evaluation of grad_x E
    can be at the float64 pose nearest the equilibrium.

    Two parts, per dof i, times machine epsilon:

    * ``sum_j |H_ij| |x_j|``: each coordinate is known to eps |x_j| (the
      pose is stored in absolute coordinates), and a change of x by that
      moves the gradient by H times it; summed with absolute values (no
      cancellation assumed, and a low-rank Hessian's sparse and tendon
      parts each on their own: never assembled), so the part is an upper
      bound of that effect;
    * ``sum_terms |g_term,i|``: the terms' gradients (elastic, pins,
      tendons, gravity) are added, each to eps of its own size, and large
      opposite forces (a taut tendon against the body) cancel in the sum.

    A fine mesh has more dofs and stiffer rows relative to the force scale,
    so its floor relative to the force scale grows with refinement; this is
    the floor a stalled Newton solve sits on."""
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    ev = model.evaluate(x, c, order=2)
    if not ev.admissible or ev.hessian_form is None:
        return 0.0
    per_dof = abs_product(ev.hessian_form, np.abs(x))
    for term in model.terms:
        part = term.evaluate(x, c, 1)
        if part.gradient is not None:
            per_dof = per_dof + np.abs(part.gradient)
    return float(np.finfo(np.float64).eps * np.linalg.norm(per_dof))


def at_roundoff_floor(model: Model, eq: Equilibrium, options: EquilibriumOptions) -> Equilibrium:
    """``eq`` certified where it is not converged only because its residual
    cannot be made smaller in float64: its Hessian was factored without a
    shift (positive definite) and its residual is finite and within
    ``options.roundoff`` times :func:`roundoff_floor`. Anything else is
    returned unchanged (never converged by this)."""
    if eq.converged or options.roundoff == 0 or not eq.positive_definite \
            or not np.isfinite(eq.residual_norm) or not np.isfinite(eq.force_scale):
        return eq
    floor = options.roundoff * roundoff_floor(model, eq.x, eq.contraction)
    if not eq.residual_norm <= floor:
        return eq
    status = (f"converged to the round-off floor: residual {eq.relative_residual:.1e} of the force scale "
              f"(floor {floor / eq.force_scale:.1e}, above gtol {options.gtol:g}); the solver said: {eq.status}")
    return replace(eq, converged=True, status=status)
