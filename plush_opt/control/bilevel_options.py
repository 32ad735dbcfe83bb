"""Options of the bilevel control method, and what it reports.

:class:`BilevelOptions` configures both formulations (the reduced search,
:mod:`.bilevel_search`, and the full-space NLP, :mod:`.bilevel_full`);
:class:`BilevelStats` is the result file's ``bilevel`` section.
docs/bilevel.md has the options that matter and why.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from ..solve.equilibrium import EquilibriumOptions
from .policy import LEVENBERG_MARQUARDT, ProbeRule, StopRules

#: IPOPT's choices for the equality multipliers' step (its ``alpha_for_y``).
ALPHA_FOR_Y = ("primal", "bound-mult", "min", "max", "full", "min-dual-infeas",
               "safer-min-dual-infeas", "primal-and-full", "dual-and-full", "acceptor")

FORMULATIONS = ("reduced", "full")

# The floor of IPOPT's acceptable_constr_viol_tol: the "acceptable" level
# is never stricter than this, however tight constr_viol_tol is.
ACCEPTABLE_CONSTR_VIOL = 1e-8


@dataclass(frozen=True)
class BilevelOptions:
    """Options of the bilevel (IPOPT) control solver.

    Attributes
    ----------
    formulation : 'reduced' (default: IPOPT on the contractions, the pose
        eliminated through the certified equilibrium, docs/bilevel.md) or
        'full' (IPOPT on pose and contractions, the equilibrium as a
        constraint).
    gtol : (reduced) stop, certified, once the projected gradient times the
        mean bound range is below gtol * max(O, objective_floor) (the
        gradient loop's rule, so both stop at the same accuracy).
    ftol, patience : (reduced) stop, certified, once O has decreased by
        less than ftol (relative) over ``patience`` consecutive IPOPT
        iterations (the gradient loop's rule and defaults).
    objective_floor : (reduced) O below this (length^2) counts as targets
        reached.
    stuck_fraction, probe_fractions, probe_gain : (reduced) the look-further
        moves where IPOPT stops with O above stuck_fraction x its start
        (the gradient loop's, docs/control.md).
    hessian_damping : (reduced) Levenberg-Marquardt damping added to the
        Gauss-Newton Hessian on the winches whose tendons are all (nearly)
        slack, relative to its largest diagonal entry, at the start (the
        loop's initial damping; it then adapts per winch by the loop's
        schedule, :class:`~plush_opt.control.policy.Damping`, never above
        this): bounds the step of a winch whose column is (nearly) zero;
        the other winches get none.
    hessian_secant : (reduced) add to the Gauss-Newton Hessian a secant
        (structured BFGS) estimate of the term it drops, r . d2r/dc2, from
        the accepted iterates: a winch that moves the targets little has a
        Gauss-Newton curvature far below its true one (docs/bilevel.md).
    mu_init, bound_push : (reduced) IPOPT's ``mu_init`` and
        ``bound_push``/``bound_frac``: the start is a certified equilibrium
        already, so a small barrier and a small push off the bounds keep
        IPOPT from first walking away from it.
    tol : IPOPT ``tol``: the overall (scaled) KKT error at which IPOPT stops.
    constr_viol_tol : IPOPT ``constr_viol_tol`` on the scaled equilibrium
        constraint |grad_x E| / F_ref (dimensionless).
    acceptable_tol : IPOPT ``acceptable_tol`` (stop after a few iterations
        at this looser level when ``tol`` cannot be reached).
    max_iter : IPOPT iterations at most.
    max_time : seconds of IPOPT at most (checked after every iteration;
        None: no limit). Does not rebuild the solver when changed.
    min_jacobian : delta in J_e >= delta for every element, keeping the
        solution away from degenerate and inverted elements; None drops
        these constraints (then only IPOPT's step cut-back on a non-finite
        energy keeps the iterates admissible).
    mu_strategy : IPOPT ``mu_strategy`` ('monotone' or 'adaptive').
    alpha_for_y : IPOPT ``alpha_for_y``, the step size of the equality
        multipliers; 'safer-min-dual-infeas' keeps IPOPT from the long
        excursions through non-equilibrium poses it otherwise takes on the
        gripper (docs/bilevel.md has the measurements).
    take_up_slack : before IPOPT, contract every free winch whose tendons
        are all slack at the start until its tightest tendon just enters
        the smoothing zone (the pose does not change). A slack winch has a
        zero column in the constraint Jacobian, so IPOPT could not tell
        whether pulling helps.
    expand : expand the CasADi graph to scalar operations (SX) before
        solving: a slower build (once per cache entry) and much faster
        evaluations of the Hessian of the Lagrangian.
    residual_tol : IPOPT's pose counts as an equilibrium when
        |grad_x E| <= residual_tol * force scale.
    pose_tol : largest distance (length units) between IPOPT's pose and the
        certified one for the result to count as converged; None: 1e-6 x
        the body diameter.
    start_continuation : where the starting equilibrium fails from its
        start pose, it is sought by continuation in the contraction in this
        many steps (``EquilibriumOptions.continuation``); 0: not.
    equilibrium : options of the Newton solves (start and certification).
    ipopt : raw IPOPT options, passed through last (keys without the
        ``ipopt.`` prefix, e.g. ``{"linear_solver": "ma27"}``).
    """

    formulation: str = "reduced"
    gtol: float = 1e-7
    ftol: float = 1e-9
    patience: int = 2
    objective_floor: float = 1e-14
    stuck_fraction: float = 0.5
    probe_fractions: tuple[float, ...] = (0.05, 0.15, 0.4)
    probe_gain: float = 1e-3
    hessian_damping: float = LEVENBERG_MARQUARDT.initial
    hessian_secant: bool = True
    mu_init: float = 1e-4
    bound_push: float = 1e-6
    tol: float = 1e-8
    constr_viol_tol: float = 1e-10
    acceptable_tol: float = 1e-6
    max_iter: int = 500
    max_time: float | None = None
    min_jacobian: float | None = 0.05
    mu_strategy: str = "monotone"
    alpha_for_y: str = "safer-min-dual-infeas"
    take_up_slack: bool = True
    expand: bool = True
    residual_tol: float = 1e-6
    pose_tol: float | None = None
    start_continuation: int = 4
    equilibrium: EquilibriumOptions = field(default_factory=EquilibriumOptions)
    ipopt: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.formulation not in FORMULATIONS:
            raise ValueError(f"formulation: expected one of {FORMULATIONS}, got {self.formulation!r}")
        if not (isinstance(self.start_continuation, int) and self.start_continuation >= 0):
            raise ValueError(f"start_continuation: expected an integer >= 0, got {self.start_continuation!r}")
        if not (isinstance(self.hessian_damping, (int, float)) and self.hessian_damping >= 0):
            raise ValueError(f"hessian_damping: expected a number >= 0, got {self.hessian_damping!r}")
        if not (isinstance(self.patience, int) and self.patience >= 1):
            raise ValueError(f"patience: expected an integer >= 1, got {self.patience!r}")
        for name in ("gtol", "ftol", "mu_init", "bound_push", "tol", "constr_viol_tol", "acceptable_tol", "residual_tol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a finite number > 0, got {v!r}")
        if not (isinstance(self.max_iter, int) and self.max_iter >= 0):
            raise ValueError(f"max_iter: expected an integer >= 0, got {self.max_iter!r}")
        if self.max_time is not None and not (self.max_time > 0):
            raise ValueError(f"max_time: expected None or a number > 0, got {self.max_time!r}")
        if self.min_jacobian is not None and not (0 <= self.min_jacobian < 1):
            raise ValueError(f"min_jacobian: expected None or 0 <= delta < 1, got {self.min_jacobian!r}")
        if self.mu_strategy not in ("monotone", "adaptive"):
            raise ValueError(f"mu_strategy: expected one of ('monotone', 'adaptive'), "
                             f"got {self.mu_strategy!r}")
        if self.alpha_for_y not in ALPHA_FOR_Y:
            raise ValueError(f"alpha_for_y: expected one of {ALPHA_FOR_Y}, got {self.alpha_for_y!r}")
        if self.pose_tol is not None and not (self.pose_tol > 0):
            raise ValueError(f"pose_tol: expected None or a number > 0, got {self.pose_tol!r}")
        if not isinstance(self.ipopt, dict) or not all(isinstance(k, str) for k in self.ipopt):
            raise ValueError(f"ipopt: expected a dict with string keys, got {self.ipopt!r}")

    @property
    def probe(self) -> ProbeRule:
        """(reduced) The look-further rule: a winch is tried again from an O
        lower by probe_gain (later IPOPT rounds may make its slack matter)."""
        return ProbeRule(self.stuck_fraction, tuple(self.probe_fractions), self.probe_gain, retry=True)

    def stop_rules(self) -> StopRules:
        """(reduced) The gradient loop's stop rules with these options
        (objective_floor absolute, max_iter IPOPT iterations)."""
        return StopRules(self.gtol, self.ftol, self.patience, self.objective_floor, self.max_iter,
                         self.max_time)

    def reduced_ipopt_options(self) -> dict:
        """The IPOPT options of the reduced-space solver (without prefix)."""
        opts = {"tol": float(self.tol), "acceptable_tol": float(self.acceptable_tol),
                "max_iter": int(self.max_iter), "mu_strategy": self.mu_strategy,
                "mu_init": float(self.mu_init), "bound_push": float(self.bound_push),
                "bound_frac": float(self.bound_push), "hessian_approximation": "exact",
                "honor_original_bounds": "yes", "print_level": 0, "sb": "yes",
                # only variable bounds, and the evaluator clips to them: a
                # relaxed bound would only let IPOPT see a point it cannot reach
                "bound_relax_factor": 0.0}
        opts.update(self.ipopt)
        return opts

    def ipopt_options(self) -> dict:
        """The IPOPT options this solver is built with (without prefix)."""
        opts = {
            "tol": float(self.tol),
            "constr_viol_tol": float(self.constr_viol_tol),
            "acceptable_tol": float(self.acceptable_tol),
            "acceptable_constr_viol_tol": float(max(self.constr_viol_tol, ACCEPTABLE_CONSTR_VIOL)),
            "max_iter": int(self.max_iter),
            "mu_strategy": self.mu_strategy,
            "alpha_for_y": self.alpha_for_y,
            "hessian_approximation": "exact",
            "honor_original_bounds": "yes",
            "print_level": 0,
            "sb": "yes",
        }
        opts.update(self.ipopt)
        return opts


@dataclass(frozen=True)
class BilevelStats:
    """What the bilevel method measured and checked (the result file's
    ``bilevel`` section). Fields that do not apply are None.

    Attributes
    ----------
    start : the starting equilibrium (contraction, objective, t_wall,
        slack_taken_up).
    formulation : 'reduced' or 'full'.
    moves, rounds : (reduced) the look-further moves taken, and each IPOPT
        round's start, status and iterations.
    return_status, ipopt_success, iter_count, stopped_by_time_limit : IPOPT's verdict.
    t_build, cached_solver : solver set-up (0 when the solver was cached).
    t_ipopt_total, t_function_evaluations, t_inside_ipopt, t_callback,
    t_certification, timing, calls : where the time went (seconds, counts).
    options : the options the solver ran with.
    frozen, contraction_ipopt, bound_violation : IPOPT's answer.
    objective_ipopt, objective_certified : O at IPOPT's and at the certified pose.
    kkt : stationarity, feasibility and complementarity at IPOPT's answer.
    ipopt_pose : the check of IPOPT's own pose (admissible, residual,
        positive definite, eigenvalue, stable_equilibrium).
    certified_distance, certified : Newton's certification from IPOPT's pose.
    min_jacobian_at_solution, jacobian_bound_active : the J >= delta constraints.
    active_bounds, slack_winches : winch names.
    equilibrium_solves, history_points : counts.
    """

    start: dict
    objective_certified: float
    solver: str = "ipopt"
    formulation: str | None = None
    moves: list | None = None
    rounds: list | None = None
    return_status: str | None = None
    ipopt_success: bool | None = None
    iter_count: int | None = None
    stopped_by_time_limit: bool | None = None
    t_build: float | None = None
    cached_solver: bool | None = None
    t_ipopt_total: float | None = None
    t_function_evaluations: float | None = None
    t_inside_ipopt: float | None = None
    t_callback: float | None = None
    t_certification: float | None = None
    timing: dict | None = None
    calls: dict | None = None
    options: dict | None = None
    frozen: list | None = None
    contraction_ipopt: dict | None = None
    bound_violation: float | None = None
    objective_ipopt: float | None = None
    kkt: dict | None = None
    ipopt_pose: dict | None = None
    certified_distance: float | None = None
    certified: dict | None = None
    min_jacobian_at_solution: float | None = None
    jacobian_bound_active: bool | None = None
    active_bounds: list | None = None
    slack_winches: list | None = None
    equilibrium_solves: int | None = None
    history_points: int | None = None

    def to_dict(self) -> dict:
        """JSON-able, without the fields that do not apply."""
        return {k: v for k, v in asdict(self).items() if v is not None or k == "min_jacobian_at_solution"}
