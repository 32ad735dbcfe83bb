"""Method 2: the bilevel problem as one NLP on (x, c), solved by IPOPT.

The control problem min_c O(x(c)) with x(c) a minimiser of E(., c) is
replaced by its first-order form (the equilibrium as a constraint):

    minimise    O(x)                          over x (n_dofs) and the free c
    subject to  grad_x E(x, c) / F_ref = 0    (n_dofs equations)
                J_e(x) >= delta               (every element, optional)
                lower <= c <= upper           (IPOPT variable bounds)

IPOPT gets the exact Hessian of the Lagrangian from CasADi, which holds
third derivatives of E. Frozen winches are parameters, not variables; so
are the targets' positions, weights and barycentric weights, so moving a
target does not rebuild the solver (only a target in a different triangle
does). The solver is built once per (model, frozen set, target triangles,
options) and cached next to the model (weak reference: it goes with it).

A KKT point of this NLP need not be a *stable* equilibrium: the constraint
grad_x E = 0 also holds at saddles and maxima of E. So the answer is
certified afterwards: the pose IPOPT returns is tested (residual, Cholesky
of the Hessian) and Newton re-solves the equilibrium at IPOPT's
contractions from IPOPT's pose. The result is ``converged`` only if IPOPT
succeeded, its pose was a stable equilibrium, and the certified pose is
within ``pose_tol`` of it. The returned equilibrium is always the
certified one (a saddle is never returned as a pose).

IPOPT's iterates satisfy the equilibrium constraint only at the end: the
history recorded here (objective and constraint violation per iteration,
for anytime curves) is not a list of poses a robot could be sent to.
docs/bilevel.md has the formulation and the options that matter.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from ..solve.equilibrium import EquilibriumOptions, certify, solve_equilibrium
from ..base.errors import SolverError
from ..fem.model import Model
from ..fem.objective import Targets
from .bilevel_nlp import (NlpEntry, build_nlp, describe_pose as _describe_pose, force_reference,
                          jsonable as _jsonable, kkt as _kkt, parameters as _parameters, pose_check as _pose_check)
from .bilevel_search import ReducedRun
from .result import ControlResult, ControlStats
from .slack import slack_winches, take_up

log = logging.getLogger(__name__)

#: IPOPT's choices for the equality multipliers' step (its ``alpha_for_y``).
ALPHA_FOR_Y = ("primal", "bound-mult", "min", "max", "full", "min-dual-infeas",
               "safer-min-dual-infeas", "primal-and-full", "dual-and-full", "acceptor")

FORMULATIONS = ("reduced", "full")

#: IPOPT return statuses counted as success.
SUCCESS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")

#: IPOPT statuses that end a run on a budget rather than by failing.
BUDGET = {"Maximum_Iterations_Exceeded": "max_iterations",
          "Maximum_CpuTime_Exceeded": "max_time", "Maximum_WallTime_Exceeded": "max_time"}

# Contractions outside the bounds by more than this fraction of the largest
# range are not a success (IPOPT's bound_push keeps them inside otherwise).
BOUND_SLACK = 1e-9
# A free winch within this fraction of its range from a bound is "active".
ACTIVE_BOUND = 1e-6


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
        loop's initial damping; it then adapts per winch as the loop's
        does, never above this): bounds the step of a winch whose column
        is (nearly) zero; the other winches get none.
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
    probe_fractions: tuple = (0.05, 0.15, 0.4)
    probe_gain: float = 1e-3
    hessian_damping: float = 1e-3
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
    equilibrium: EquilibriumOptions = field(default_factory=EquilibriumOptions)
    ipopt: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.formulation not in FORMULATIONS:
            raise ValueError(f"formulation: expected one of {FORMULATIONS}, got {self.formulation!r}")
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
            "acceptable_constr_viol_tol": float(max(self.constr_viol_tol, 1e-8)),
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


class BilevelSolver:
    """The bilevel method for one model, keeping its built NLPs.

    Building IPOPT's NLP (and its exact Lagrangian Hessian) is the
    expensive part; a solver keeps one per (frozen set, target triangles,
    options), so moving a target or re-running is cheap.
    """

    def __init__(self, model: Model):
        self.model = model
        self._entries: dict = {}
        self._store: dict = {}     # grad_x E, shared by every entry

    def clear(self) -> None:
        """Drop the built NLPs."""
        self._entries.clear()

    def _entry(self, frozen: np.ndarray, targets: Targets, options: BilevelOptions):
        """The NLP for this frozen set, target triangles and options; (entry, built_now)."""
        key = (tuple(bool(f) for f in frozen), targets.nodes.tobytes(), targets.n_targets,
               repr(sorted(options.ipopt_options().items())), options.min_jacobian, options.expand)
        if key not in self._entries:
            self._entries[key] = build_nlp(self.model, frozen, targets.nodes, options, self._store)
            return self._entries[key], True
        return self._entries[key], False

    def solve(self, targets: Targets, contraction0=None, frozen=None, x0=None,
              options: BilevelOptions | None = None) -> ControlResult:
        """Contractions that bring the equilibrium to the targets, by IPOPT on
        the KKT formulation, certified by Newton.

        Parameters
        ----------
        targets : where body points should go.
        contraction0 : (n_winches,) start, within bounds (default: the scene's).
            The equilibrium there (Newton) is IPOPT's starting point.
        frozen : (n_winches,) bool, winches kept at ``contraction0`` (default:
            the scene's ``frozen`` flags).
        x0 : starting pose for that first Newton solve (flat or (n_nodes, 2)).
        options : :class:`BilevelOptions`.

        Raises
        ------
        SolverError
            Bad sizes, a start outside the bounds, or a starting equilibrium
            that cannot be certified.
        SceneError
            A scene whose pose depends on the path (friction at via
            points): the method has no history.
        """
        from ..solve.plant import make_plant     # a pose that depends on the path: refuse, never solve without it
        make_plant(self.model).require_history_free("the bilevel method",
                                                    "use --method reparam or clip (they follow the path)")
        options = options or BilevelOptions()
        t_start = time.perf_counter()
        c0, frozen = _checked_start(self.model, contraction0, frozen)
        start, taken = _start(self.model, targets, c0, frozen, x0, options)
        start_info = {"contraction": start.contraction.tolist(),
                      "objective": float(targets.value(start.x)),
                      "t_wall": time.perf_counter() - t_start,
                      "slack_taken_up": [self.model.winch_names[w] for w in taken]}
        if targets.n_targets == 0 or frozen.all():
            status = "no targets" if targets.n_targets == 0 else "every winch is frozen"
            stats = BilevelStats(start=start_info, objective_certified=float(targets.value(start.x)))
            return self._result(targets, frozen, start, True,
                                "targets_reached" if targets.n_targets == 0 else "stationary",
                                status, (), 0, 0.0, stats, t_start)
        if options.formulation == "reduced":
            return self._solve_reduced(targets, frozen, start, start_info, options, t_start)
        run = _IpoptRun(self.model, targets, options, frozen, start, taken, start_info)
        run.entry, run.built = self._entry(frozen, targets, options)
        run.solve()
        run.certify()
        return self._result(targets, frozen, run.eq, run.ok, run.reason(), run.status(),
                            run.history, run.iterations, run.entry.t_build if run.built else 0.0,
                            run.stats(), t_start)

    def _solve_reduced(self, targets, frozen, start, start_info, options, t_start) -> ControlResult:
        model = self.model
        run = ReducedRun(model, targets, options, frozen, start, t_start)
        run.solve()
        ok, reason, status = run.verdict()
        end, names = run.end, model.winch_names
        g = run.gradient(end)
        t_eval = run.ev.t_evaluations
        stats = BilevelStats(
            start=start_info, objective_certified=end.objective, formulation="reduced",
            moves=run.moves, rounds=run.rounds, return_status=run.return_status,
            ipopt_success=run.return_status in SUCCESS, iter_count=run.iterations,
            stopped_by_time_limit=run.stop == "max_time", t_build=run.t_build, cached_solver=False,
            t_ipopt_total=run.t_ipopt, t_function_evaluations=t_eval,
            t_inside_ipopt=max(run.t_ipopt - t_eval, 0.0),
            calls={**run.calls, "equilibrium_solves": run.ev.solves, "failed_equilibrium_solves":
                   run.ev.failures, "known_past_branch_end": run.ev.past_end},
            options={"ipopt": _jsonable(options.reduced_ipopt_options()), "gtol": options.gtol,
                     "ftol": options.ftol, "patience": options.patience,
                     "objective_floor": options.objective_floor, "max_time": options.max_time},
            frozen=[names[i] for i in np.flatnonzero(frozen)],
            contraction_ipopt={names[i]: float(end.c[i]) for i in range(model.n_winches)},
            bound_violation=0.0, objective_ipopt=end.objective,
            kkt={"gradient": {names[i]: float(g[i]) for i in run.free}},
            active_bounds=[names[w] for w in run._held_mask(end.c, g)],
            slack_winches=[names[w] for w in slack_winches(model, end.eq.x, end.c, ~frozen, g)],
            equilibrium_solves=run.ev.solves + 1, history_points=len(run.history))
        return self._result(targets, frozen, end.eq, ok, reason, status, run.history,
                            run.iterations, run.t_build, stats, t_start)

    def _result(self, targets, frozen, eq, ok, reason, status, history, iterations, t_setup,
                stats: BilevelStats, t_start) -> ControlResult:
        model = self.model
        names = model.winch_names
        eq = certify(model, eq)
        common = ControlStats(solver="ipopt", iterations=int(iterations),
                              equilibrium_solves=int(stats.equilibrium_solves or 1),
                              newton_iterations=int(eq.iterations),
                              t_wall=time.perf_counter() - t_start, t_setup=float(t_setup),
                              details=stats)
        log.info("bilevel: %s; O = %.6g; %d iterations", status, stats.objective_certified, iterations)
        return ControlResult(
            method="bilevel", converged=bool(ok), reason=reason, status=status, equilibrium=eq,
            objective=float(stats.objective_certified), active_bounds=tuple(stats.active_bounds or ()),
            frozen=tuple(names[i] for i in np.flatnonzero(frozen)), history=tuple(history),
            stats=common, model=model, targets=targets)


def solve_bilevel(model: Model, targets: Targets, contraction0=None, frozen=None, x0=None,
                  options: BilevelOptions | None = None, solver: BilevelSolver | None = None
                  ) -> ControlResult:
    """:meth:`BilevelSolver.solve` with ``solver`` (a new one if None: no NLP reuse)."""
    return (solver or BilevelSolver(model)).solve(targets, contraction0, frozen, x0, options)


def _checked_start(model: Model, contraction0, frozen) -> tuple[np.ndarray, np.ndarray]:
    c0 = model.scene.contraction.copy() if contraction0 is None \
        else np.array(contraction0, dtype=np.float64).reshape(-1)
    if c0.shape != (model.n_winches,):
        raise SolverError(f"contraction: expected {model.n_winches} values, got {c0.size}")
    if np.any(c0 < model.lower) or np.any(c0 > model.upper):
        raise SolverError("contraction: outside the winch bounds "
                          f"{list(zip(model.lower.tolist(), model.upper.tolist()))}: {c0.tolist()}")
    frozen = model.scene.frozen.copy() if frozen is None else np.array(frozen, dtype=bool).reshape(-1)
    if frozen.shape != (model.n_winches,):
        raise SolverError(f"frozen: expected {model.n_winches} flags, got {frozen.size}")
    return c0, frozen


def _start(model: Model, targets: Targets, c0, frozen, x0, options: BilevelOptions):
    """The certified starting equilibrium, with the slack taken up; (eq, winches taken up)."""
    quick = replace(options.equilibrium, eigenvalue=False)
    start = solve_equilibrium(model, c0, x0, quick)
    if not start.converged:
        raise SolverError(f"the starting equilibrium is not certified: {start.status}")
    if not (options.take_up_slack and targets.n_targets):
        return start, []
    free = ~frozen
    taken = slack_winches(model, start.x, c0, free)
    if not taken:
        return start, []
    c1 = c0.copy()
    for w in taken:
        c1[w] = min(take_up(model, start.x, c0, w), model.upper[w])
    moved = solve_equilibrium(model, c1, start.x, quick)
    return (moved, taken) if moved.converged else (start, [])


class _IpoptRun:
    """One IPOPT solve from a certified start, and its certification."""

    def __init__(self, model, targets, options, frozen, start, taken, start_info):
        self.model, self.targets, self.options = model, targets, options
        self.frozen, self.start, self.taken, self.start_info = frozen, start, taken, start_info
        self.entry: NlpEntry | None = None
        self.built = False

    def solve(self) -> None:
        model, entry, options = self.model, self.entry, self.options
        c0, n, free = self.start.contraction, model.n_dofs, self.entry.free
        self.p = _parameters(entry, c0, self.targets)
        z0 = np.concatenate([self.start.x, c0[free]])
        lbx = np.concatenate([np.full(n, -np.inf), model.lower[free]])
        ubx = np.concatenate([np.full(n, np.inf), model.upper[free]])
        entry.recorder.reset({"t0": time.perf_counter(), "n_dofs": n, "delta": options.min_jacobian,
                              "free": free, "c_fixed": c0.copy(), "max_time": options.max_time})
        t_ipopt = time.perf_counter()
        try:
            self.sol = entry.solver(x0=z0, p=self.p, lbx=lbx, ubx=ubx, lbg=entry.lbg, ubg=entry.ubg)
        finally:
            self.t_ipopt = time.perf_counter() - t_ipopt
            self.history = tuple(entry.recorder.points)
            self.stopped = entry.recorder.stopped
            entry.recorder.reset(None)
        self.ipopt_stats = entry.solver.stats()
        self.return_status = str(self.ipopt_stats.get("return_status", "unknown"))
        self.ipopt_ok = self.return_status in SUCCESS
        self.iterations = int(self.ipopt_stats.get("iter_count", len(self.history)))
        self.z = np.asarray(self.sol["x"], dtype=np.float64).reshape(-1)
        self.c_ip = c0.copy()
        self.c_ip[free] = self.z[n:]
        violation = float(np.max(np.maximum(model.lower - self.c_ip, self.c_ip - model.upper), initial=0.0))
        self.bound_violation = max(violation, 0.0)
        self.kkt = _kkt(model, entry, self.sol, self.z, self.p, options)

    def certify(self) -> None:
        """IPOPT's own pose checked, then Newton from it at IPOPT's (clipped) contractions."""
        model, options = self.model, self.options
        x_ip = self.z[:model.n_dofs]
        self.c_cert = np.clip(self.c_ip, model.lower, model.upper)
        t_cert = time.perf_counter()
        self.check = _pose_check(model, x_ip, self.c_cert, options.residual_tol)
        x_newton = x_ip if self.check["admissible"] else self.start.x
        self.cert = solve_equilibrium(model, self.c_cert, x_newton, options.equilibrium)
        self.t_cert = time.perf_counter() - t_cert
        self.pose_tol = options.pose_tol if options.pose_tol is not None else 1e-6 * model.mesh.diameter
        self.distance = float(np.max(np.linalg.norm((self.cert.x - x_ip).reshape(-1, 2), axis=1)))
        self.jmin = float(model.jacobians(self.cert.x).min()) if self.cert.converged else None
        if self.check["positive_definite"] and self.cert.converged and self.distance <= self.pose_tol:
            self.check["min_eigenvalue"] = self.cert.min_eigenvalue
        span = float(np.max(model.upper - model.lower))
        self.ok = bool(self.ipopt_ok and self.check["stable_equilibrium"] and self.cert.converged
                       and self.distance <= self.pose_tol and self.bound_violation <= BOUND_SLACK * span)
        self.eq = self.cert if self.cert.converged else self.start
        self.slack = [model.winch_names[w]
                      for w in slack_winches(model, self.eq.x, self.eq.contraction, ~self.frozen)]

    def reason(self) -> str:
        if self.ok:
            return "stationary"
        if not self.cert.converged or not self.check["stable_equilibrium"]:
            return "not_certified"
        if self.stopped:
            return "max_time"
        if self.return_status in BUDGET:
            return BUDGET[self.return_status]
        if not self.ipopt_ok:
            return "solver_failed"
        return "not_certified"

    def status(self) -> str:
        check, cert = self.check, self.cert
        head = f"ipopt: {self.return_status}" + (
            f" (time limit {self.options.max_time:g} s)" if self.stopped else "")
        if self.ok:
            status = f"{head}; certified"
        elif cert.converged:
            if not check["stable_equilibrium"]:
                status = (f"{head}; {_describe_pose(check)}; Newton from it settled "
                          f"{self.distance:.3g} away (objective {self.targets.value(cert.x):.6g})")
            elif self.distance > self.pose_tol:
                status = (f"{head}; Newton moved IPOPT's pose by {self.distance:.3g} "
                          f"(more than pose_tol {self.pose_tol:.3g})")
            elif not self.ipopt_ok:
                status = f"{head}; certified equilibrium at IPOPT's last contractions (not a KKT point)"
            else:
                status = f"{head}; contractions outside the bounds by {self.bound_violation:.3g}"
        else:
            status = (f"{head}; certification failed at IPOPT's contractions ({cert.status}); "
                      "returned the starting equilibrium")
            if not check["stable_equilibrium"]:
                status = f"{head}; {_describe_pose(check)}; " + status[len(head) + 2:]
        if self.slack:
            status += f"; winch {', '.join(self.slack)}: all tendons slack (zero gradient)"
        return status

    def stats(self) -> BilevelStats:
        model, options, entry = self.model, self.options, self.entry
        names = model.winch_names
        raw = self.ipopt_stats
        timing = {k: float(v) for k, v in raw.items() if k.startswith("t_wall_")}
        calls = {k: int(v) for k, v in raw.items() if k.startswith("n_call_")}
        t_functions = sum(v for k, v in timing.items() if k.startswith("t_wall_nlp_"))
        t_total = timing.get("t_wall_total", self.t_ipopt)
        t_callback = timing.get("t_wall_callback_fun", 0.0)
        free = entry.free
        span = model.upper - model.lower
        return BilevelStats(
            start=self.start_info, objective_certified=float(self.targets.value(self.eq.x)),
            return_status=self.return_status, ipopt_success=self.ipopt_ok,
            iter_count=self.iterations, stopped_by_time_limit=self.stopped,
            t_build=entry.t_build if self.built else 0.0, cached_solver=not self.built,
            t_ipopt_total=float(t_total), t_function_evaluations=float(t_functions),
            t_inside_ipopt=float(t_total - t_functions - t_callback), t_callback=t_callback,
            t_certification=self.t_cert, timing=timing, calls=calls,
            options={"ipopt": _jsonable(entry.ipopt_options), "expand": options.expand,
                     "min_jacobian": options.min_jacobian, "max_time": options.max_time,
                     "residual_tol": options.residual_tol, "pose_tol": self.pose_tol,
                     "force_reference": force_reference(model)},
            frozen=[names[i] for i in np.flatnonzero(self.frozen)],
            contraction_ipopt={names[i]: float(self.c_ip[i]) for i in range(model.n_winches)},
            bound_violation=self.bound_violation,
            objective_ipopt=float(np.asarray(self.sol["f"]).reshape(-1)[0]),
            kkt=self.kkt, ipopt_pose=self.check, certified_distance=self.distance,
            certified={"converged": bool(self.cert.converged), "status": self.cert.status,
                       "newton_iterations": int(self.cert.iterations),
                       "saddle_escapes": int(self.cert.saddle_escapes)},
            min_jacobian_at_solution=self.jmin,
            jacobian_bound_active=bool(self.jmin is not None and options.min_jacobian is not None
                                       and self.jmin <= options.min_jacobian * (1 + 1e-6)),
            active_bounds=[names[w] for w in free
                           if min(self.c_cert[w] - model.lower[w], model.upper[w] - self.c_cert[w])
                           <= ACTIVE_BOUND * span[w]],
            slack_winches=self.slack, equilibrium_solves=2 + (1 if self.taken else 0),
            history_points=len(self.history))

