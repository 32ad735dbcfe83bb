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
import weakref
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import casadi as ca
import numpy as np

from ..equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium
from ..errors import SolverError
from ..linalg import NotPositiveDefinite, smallest_eigenpair
from ..model import Model
from ..objective import Targets

log = logging.getLogger(__name__)

#: IPOPT's choices for the equality multipliers' step (its ``alpha_for_y``).
ALPHA_FOR_Y = ("primal", "bound-mult", "min", "max", "full", "min-dual-infeas",
               "safer-min-dual-infeas", "primal-and-full", "dual-and-full", "acceptor")

#: IPOPT return statuses counted as success.
SUCCESS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


@dataclass(frozen=True)
class BilevelOptions:
    """Options of the bilevel (IPOPT) control solver.

    Attributes
    ----------
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
        for name in ("tol", "constr_viol_tol", "acceptable_tol", "residual_tol"):
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


class BilevelIterate(NamedTuple):
    """One IPOPT iteration, for anytime curves. NOT a dispatchable pose: x
    does not satisfy the equilibrium constraint until IPOPT has converged.

    t_wall : seconds since IPOPT started.
    objective : O at IPOPT's iterate x (length^2).
    constraint_violation : max(|grad_x E|_inf / F_ref, max_e(delta - J_e, 0)).
    contraction : (n_winches,) IPOPT's contractions (frozen ones included).
    """

    t_wall: float
    objective: float
    constraint_violation: float
    contraction: np.ndarray


@dataclass(frozen=True)
class BilevelResult:
    """The outcome of :func:`solve_bilevel`.

    Attributes
    ----------
    converged : IPOPT succeeded, its pose is a stable equilibrium within the
        bounds, and Newton's certified pose is within ``pose_tol`` of it.
    status : short human-readable reason.
    equilibrium : the certified equilibrium at :attr:`contraction` (Newton
        from IPOPT's pose); if that fails, the starting equilibrium.
    contraction : (n_winches,) contractions of :attr:`equilibrium`.
    iterations : IPOPT iterations.
    info : JSON-able details (IPOPT status and timings, options, the check
        of IPOPT's pose, KKT residuals); see docs/bilevel.md.
    history : IPOPT's iterations (:class:`BilevelIterate`), not dispatchable.
    t_wall : seconds for the whole call (start equilibrium, build if not
        cached, IPOPT, certification).
    """

    converged: bool
    status: str
    equilibrium: Equilibrium
    contraction: np.ndarray
    iterations: int
    info: dict
    history: tuple = ()
    t_wall: float = 0.0

    @property
    def objective(self) -> float:
        """O at the certified equilibrium."""
        return float(self.info.get("objective_certified", float("nan")))

    def to_dict(self) -> dict:
        """JSON-able summary (without the pose)."""
        return {"method": "bilevel", "converged": bool(self.converged), "status": self.status,
                "contraction": [float(v) for v in self.contraction],
                "objective": _finite(self.objective), "iterations": int(self.iterations),
                "t_wall": float(self.t_wall), "info": self.info,
                "history": [[h.t_wall, _finite(h.objective), _finite(h.constraint_violation)]
                            for h in self.history]}


def _finite(v):
    v = float(v)
    return v if math.isfinite(v) else None


# --------------------------------------------------------------------------
# The NLP, built once per (model, frozen set, target triangles, options)
# --------------------------------------------------------------------------

class _Recorder(ca.Callback):
    """IPOPT iteration callback: records (t, O, violation, c) and stops
    IPOPT (by returning 1) once the time limit has passed."""

    def __init__(self, name: str, n_z: int, n_g: int, n_p: int):
        ca.Callback.__init__(self)
        self._n = {"x": n_z, "lam_x": n_z, "g": n_g, "lam_g": n_g, "p": n_p, "lam_p": n_p, "f": 1}
        self.reset(None)
        self.construct(name, {})

    def reset(self, run: dict | None):
        self.run = run
        self.points: list[BilevelIterate] = []
        self.stopped = False

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        n = self._n.get(ca.nlpsol_out(i), 0)
        return ca.Sparsity.dense(n, 1) if n else ca.Sparsity(0, 0)

    def eval(self, arg):
        run = self.run
        if run is None:
            return [0]
        t = time.perf_counter() - run["t0"]
        z = np.asarray(arg[0], dtype=np.float64).reshape(-1)
        f = float(arg[1])
        g = np.asarray(arg[2], dtype=np.float64).reshape(-1)
        n_dofs, delta = run["n_dofs"], run["delta"]
        viol = float(np.max(np.abs(g[:n_dofs]), initial=0.0))
        if delta is not None and g.size > n_dofs:
            viol = max(viol, float(np.max(delta - g[n_dofs:], initial=0.0)))
        c = run["c_fixed"].copy()
        c[run["free"]] = z[n_dofs:]
        self.points.append(BilevelIterate(t, f, viol, c))
        if run["max_time"] is not None and t >= run["max_time"]:
            self.stopped = True
            return [1]
        return [0]


@dataclass
class _Entry:
    solver: ca.Function
    recorder: _Recorder
    grad_lag: ca.Function
    free: np.ndarray
    frozen: np.ndarray
    n_g: int
    lbg: np.ndarray
    ubg: np.ndarray
    t_build: float
    ipopt_options: dict


_cache: "weakref.WeakKeyDictionary[Model, dict]" = weakref.WeakKeyDictionary()


def force_reference(model: Model) -> float:
    """F_ref: the elastic force of a unit strain across the body,
    mu * thickness * sqrt(body area) (force units). The equilibrium
    constraint is divided by it, so IPOPT's tolerances are relative."""
    return float(model.mu * model.thickness * math.sqrt(model.rest_area.sum()))


def _gradient_expression(model: Model, store: dict) -> ca.MX:
    if "grad" not in store:
        store["grad"] = ca.gradient(model.E_sym, model.x_sym)
    return store["grad"]


def _objective_expression(x: ca.MX, nodes: np.ndarray, beta: ca.MX, q: ca.MX, sqrt_w: ca.MX) -> ca.MX:
    """O(x) = 1/2 sum_k w_k |sum_j beta_kj x_{n_kj} - q_k|^2 with beta, q,
    w symbolic (the same value as Targets.value)."""
    k = nodes.shape[0]
    if k == 0:
        return ca.MX(0)
    yx = ca.MX.zeros(k, 1)
    yy = ca.MX.zeros(k, 1)
    for j in range(3):
        yx += beta[:, j] * x[(2 * nodes[:, j]).tolist()]
        yy += beta[:, j] * x[(2 * nodes[:, j] + 1).tolist()]
    rx = sqrt_w * (yx - q[:, 0])
    ry = sqrt_w * (yy - q[:, 1])
    return 0.5 * (ca.sumsqr(rx) + ca.sumsqr(ry))


def _jacobian_expression(model: Model, x: ca.MX) -> ca.MX:
    """J = det F of every element, (n_elems,), as a CasADi expression."""
    e = model._elem_dofs
    xe = [x[e[:, i].tolist()] for i in range(6)]
    det = (xe[2] - xe[0]) * (xe[5] - xe[1]) - (xe[3] - xe[1]) * (xe[4] - xe[0])
    return det / ca.DM(2 * model.rest_area)


def _build(model: Model, frozen: np.ndarray, nodes: np.ndarray, options: BilevelOptions,
           store: dict) -> _Entry:
    t0 = time.perf_counter()
    free = np.flatnonzero(~frozen)
    fixed = np.flatnonzero(frozen)
    n_free, n_fixed, k = len(free), len(fixed), nodes.shape[0]
    c_free = ca.MX.sym("c", n_free)
    c_fixed = ca.MX.sym("c_frozen", n_fixed)
    q = ca.MX.sym("q", k, 2)
    sqrt_w = ca.MX.sym("sqrt_w", k)
    beta = ca.MX.sym("beta", k, 3)
    # c_full = P_free c_free + P_fixed c_fixed
    P_free = ca.DM.zeros(model.n_winches, n_free)
    for j, w in enumerate(free):
        P_free[int(w), j] = 1
    P_fixed = ca.DM.zeros(model.n_winches, n_fixed)
    for j, w in enumerate(fixed):
        P_fixed[int(w), j] = 1
    c_full = P_free @ c_free + (P_fixed @ c_fixed if n_fixed else 0)
    x = model.x_sym
    grad = ca.substitute(_gradient_expression(model, store), model.c_sym, c_full)
    F_ref = force_reference(model)
    g = [grad / F_ref]
    lbg = [np.zeros(model.n_dofs)]
    ubg = [np.zeros(model.n_dofs)]
    if options.min_jacobian is not None:
        g.append(_jacobian_expression(model, x))
        lbg.append(np.full(model.n_elems, options.min_jacobian))
        ubg.append(np.full(model.n_elems, np.inf))
    z = ca.vertcat(x, c_free)
    p = ca.vertcat(c_fixed, ca.vec(q), sqrt_w, ca.vec(beta))
    f = _objective_expression(x, nodes, beta, q, sqrt_w)
    gz = ca.vertcat(*g)
    nlp = {"x": z, "p": p, "f": f, "g": gz}
    recorder = _Recorder("bilevel_iterations", z.shape[0], gz.shape[0], p.shape[0])
    ipopt = options.ipopt_options()
    opts = {"ipopt." + key: v for key, v in ipopt.items()}
    opts.update({"print_time": False, "show_eval_warnings": False, "expand": options.expand,
                 "iteration_callback": recorder, "iteration_callback_step": 1,
                 "iteration_callback_ignore_errors": False})
    solver = ca.nlpsol("bilevel", "ipopt", nlp, opts)
    lam_g = ca.MX.sym("lam_g", gz.shape[0])
    lam_x = ca.MX.sym("lam_x", z.shape[0])
    grad_lag = ca.Function("grad_lag", [z, p, lam_g, lam_x],
                           [ca.gradient(f, z) + ca.jtimes(gz, z, lam_g, True) + lam_x, gz],
                           ["z", "p", "lam_g", "lam_x"], ["grad_lag", "g"])
    if options.expand:
        grad_lag = grad_lag.expand()
    return _Entry(solver, recorder, grad_lag, free, fixed, gz.shape[0],
                  np.concatenate(lbg), np.concatenate(ubg), time.perf_counter() - t0, ipopt)


def _entry(model: Model, frozen: np.ndarray, targets: Targets, options: BilevelOptions):
    """The cached solver for this model, frozen set, target triangles and
    options; returns (entry, built_now)."""
    store = _cache.setdefault(model, {})
    key = (tuple(bool(f) for f in frozen), targets.nodes.tobytes(), targets.n_targets,
           repr(sorted(options.ipopt_options().items())), options.min_jacobian, options.expand)
    if key not in store:
        store[key] = _build(model, frozen, targets.nodes, options, store)
        return store[key], True
    return store[key], False


def clear_cache(model: Model | None = None) -> None:
    """Drop the cached solvers (of one model, or of all)."""
    if model is None:
        _cache.clear()
    else:
        _cache.pop(model, None)


# --------------------------------------------------------------------------
# Solve and certify
# --------------------------------------------------------------------------

def _parameters(entry: _Entry, c: np.ndarray, targets: Targets) -> np.ndarray:
    return np.concatenate([c[entry.frozen], targets.to.T.reshape(-1), np.sqrt(targets.weight),
                           targets.beta.T.reshape(-1)])


def _pose_check(model: Model, x: np.ndarray, c: np.ndarray, residual_tol: float) -> dict:
    """Is ``x`` a stable equilibrium at ``c``? Residual, Cholesky, eigenvalue."""
    out = {"admissible": bool(model.admissible(x)), "relative_residual": None,
           "positive_definite": False, "min_eigenvalue": None, "stable_equilibrium": False}
    if not out["admissible"]:
        return out
    ev = model.evaluate(x, c, order=2)
    rel = float(np.linalg.norm(ev.gradient) / ev.force_scale)
    out["relative_residual"] = rel
    try:
        model.factorizer.factor(ev.hessian)
        # positive definite: the certified pose's eigenvalue is reported instead
        out["positive_definite"] = True
    except NotPositiveDefinite:
        out["min_eigenvalue"] = float(smallest_eigenpair(ev.hessian)[0])
    out["stable_equilibrium"] = bool(out["positive_definite"] and rel <= residual_tol)
    return out


def _slack_winches(model: Model, x, c, free) -> list[int]:
    """Free winches whose tendons are all slack (G <= -eps) at (x, c)."""
    if not model.has_tendons:
        return []
    G = model.tendon_state(x, c)["stretch"]
    eps = model.tendon_smoothing
    return [int(w) for w in np.flatnonzero(free)
            if np.any(model.tendon_winch == w) and np.all(G[model.tendon_winch == w] <= -eps)]


def _take_up_slack(model: Model, eq: Equilibrium, free) -> tuple[np.ndarray, list[int]]:
    """Contractions at which every all-slack free winch has its tightest
    tendon just inside the smoothing zone (G = -0.9 eps): same pose."""
    c = eq.contraction.copy()
    winches = _slack_winches(model, eq.x, c, free)
    if not winches:
        return c, []
    G = model.tendon_state(eq.x, c)["stretch"]
    eps = model.tendon_smoothing
    for w in winches:
        mine = model.tendon_winch == w
        c[w] = min(c[w] + float(np.min(-G[mine] - eps)) + 0.1 * eps, model.upper[w])
    return c, winches


def _describe_pose(check: dict) -> str:
    if not check["admissible"]:
        return "ipopt pose is not admissible (some element has J <= 0)"
    rel = check["relative_residual"]
    if not check["positive_definite"]:
        if rel is not None and rel <= 1e-6:
            return (f"ipopt pose is a saddle of E (min Hessian eigenvalue "
                    f"{check['min_eigenvalue']:.3g}, relative residual {rel:.2g})")
        return (f"ipopt pose is not an equilibrium (relative residual {rel:.2g}) and its Hessian "
                f"is indefinite (min eigenvalue {check['min_eigenvalue']:.3g})")
    return f"ipopt pose is not an equilibrium (relative residual {rel:.2g})"


def solve_bilevel(model: Model, targets: Targets, contraction0=None, frozen=None, x0=None,
                  options: BilevelOptions | None = None) -> BilevelResult:
    """Contractions that bring the equilibrium to the targets, by IPOPT on
    the KKT formulation, certified by Newton.

    Parameters
    ----------
    model : the energy model.
    targets : where body points should go.
    contraction0 : (n_winches,) start, within bounds (default: the scene's).
        The equilibrium there (Newton) is IPOPT's starting point.
    frozen : (n_winches,) bool, winches kept at ``contraction0`` (default:
        the scene's ``frozen`` flags).
    x0 : starting pose for that first Newton solve (flat or (n_nodes, 2)).
    options : :class:`BilevelOptions`.

    Returns
    -------
    BilevelResult

    Raises
    ------
    SolverError
        Bad sizes, a start outside the bounds, or a starting equilibrium
        that cannot be certified.
    """
    options = options or BilevelOptions()
    t_start = time.perf_counter()
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

    quick = replace(options.equilibrium, eigenvalue=False)
    start = solve_equilibrium(model, c0, x0, quick)
    if not start.converged:
        raise SolverError(f"the starting equilibrium is not certified: {start.status}")
    taken = []
    if options.take_up_slack and targets.n_targets:
        c1, taken = _take_up_slack(model, start, ~frozen)
        if taken:
            moved = solve_equilibrium(model, c1, start.x, quick)
            if moved.converged:
                c0, start = c1, moved
            else:
                taken = []
    t_start_eq = time.perf_counter() - t_start
    names = model.winch_names
    info = {"solver": "ipopt", "start": {"contraction": c0.tolist(),
                                         "objective": float(targets.value(start.x)),
                                         "t_wall": t_start_eq,
                                         "slack_taken_up": [names[w] for w in taken]}}
    if targets.n_targets == 0 or frozen.all():
        reason = "no targets" if targets.n_targets == 0 else "every winch is frozen"
        info["objective_certified"] = float(targets.value(start.x))
        return BilevelResult(True, reason, start, start.contraction.copy(), 0, info, (),
                             time.perf_counter() - t_start)

    entry, built = _entry(model, frozen, targets, options)
    free = entry.free
    n = model.n_dofs
    p = _parameters(entry, c0, targets)
    z0 = np.concatenate([start.x, c0[free]])
    lbx = np.concatenate([np.full(n, -np.inf), model.lower[free]])
    ubx = np.concatenate([np.full(n, np.inf), model.upper[free]])
    entry.recorder.reset({"t0": time.perf_counter(), "n_dofs": n, "delta": options.min_jacobian,
                          "free": free, "c_fixed": c0.copy(), "max_time": options.max_time})
    t_ipopt = time.perf_counter()
    try:
        sol = entry.solver(x0=z0, p=p, lbx=lbx, ubx=ubx, lbg=entry.lbg, ubg=entry.ubg)
    finally:
        t_ipopt = time.perf_counter() - t_ipopt
        history = tuple(entry.recorder.points)
        stopped = entry.recorder.stopped
        entry.recorder.reset(None)
    stats = entry.solver.stats()
    return_status = str(stats.get("return_status", "unknown"))
    ipopt_ok = return_status in SUCCESS
    iterations = int(stats.get("iter_count", len(history)))

    z = np.asarray(sol["x"], dtype=np.float64).reshape(-1)
    x_ip = z[:n]
    c_ip = c0.copy()
    c_ip[free] = z[n:]
    bound_violation = float(np.max(np.maximum(model.lower - c_ip, c_ip - model.upper), initial=0.0))
    bound_violation = max(bound_violation, 0.0)
    c_cert = np.clip(c_ip, model.lower, model.upper)

    # the KKT triple at IPOPT's answer
    lam_g = np.asarray(sol["lam_g"], dtype=np.float64).reshape(-1)
    lam_x = np.asarray(sol["lam_x"], dtype=np.float64).reshape(-1)
    gl, gval = entry.grad_lag(z, p, lam_g, lam_x)
    gl = np.asarray(gl, dtype=np.float64).reshape(-1)
    gval = np.asarray(gval, dtype=np.float64).reshape(-1)
    feas = np.abs(gval[:n])
    if options.min_jacobian is not None:
        feas = np.concatenate([feas, np.maximum(options.min_jacobian - gval[n:], 0.0)])
    zc = z[n:]
    lx = lam_x[n:]
    comp_x = np.where(lx < 0, -lx * (zc - model.lower[free]), lx * (model.upper[free] - zc))
    comp = float(np.max(np.abs(comp_x), initial=0.0))
    if options.min_jacobian is not None:
        comp = max(comp, float(np.max(np.abs(lam_g[n:] * (gval[n:] - options.min_jacobian)),
                                      initial=0.0)))
    kkt = {"stationarity": float(np.max(np.abs(gl), initial=0.0)),
           "feasibility": float(np.max(feas, initial=0.0)),
           "complementarity": comp}

    # certification: IPOPT's own pose, then Newton from it
    t_cert = time.perf_counter()
    check = _pose_check(model, x_ip, c_cert, options.residual_tol)
    x_newton = x_ip if check["admissible"] else start.x
    cert = solve_equilibrium(model, c_cert, x_newton, options.equilibrium)
    t_cert = time.perf_counter() - t_cert
    pose_tol = options.pose_tol if options.pose_tol is not None else 1e-6 * model.mesh.diameter
    distance = float(np.max(np.linalg.norm((cert.x - x_ip).reshape(-1, 2), axis=1)))
    jmin = float(model.jacobians(cert.x).min()) if cert.converged else None
    if check["positive_definite"] and cert.converged and distance <= pose_tol:
        check["min_eigenvalue"] = cert.min_eigenvalue

    ok = bool(ipopt_ok and check["stable_equilibrium"] and cert.converged
              and distance <= pose_tol and bound_violation <= 1e-9 * float(np.max(model.upper - model.lower)))
    head = f"ipopt: {return_status}" + (f" (time limit {options.max_time:g} s)" if stopped else "")
    if ok:
        status = f"{head}; certified"
        eq = cert
    elif cert.converged:
        eq = cert
        if not check["stable_equilibrium"]:
            status = (f"{head}; {_describe_pose(check)}; Newton from it settled "
                      f"{distance:.3g} away (objective {targets.value(cert.x):.6g})")
        elif distance > pose_tol:
            status = (f"{head}; Newton moved IPOPT's pose by {distance:.3g} "
                      f"(more than pose_tol {pose_tol:.3g})")
        elif not ipopt_ok:
            status = f"{head}; certified equilibrium at IPOPT's last contractions (not a KKT point)"
        else:
            status = f"{head}; contractions outside the bounds by {bound_violation:.3g}"
    else:
        eq = start
        status = (f"{head}; certification failed at IPOPT's contractions ({cert.status}); "
                  "returned the starting equilibrium")
        if not check["stable_equilibrium"]:
            status = f"{head}; {_describe_pose(check)}; " + status[len(head) + 2:]

    slack = [names[w] for w in _slack_winches(model, eq.x, eq.contraction, ~frozen)]
    if slack:
        status += f"; winch {', '.join(slack)}: all tendons slack (zero gradient)"
    timing = {k: float(v) for k, v in stats.items() if k.startswith("t_wall_")}
    calls = {k: int(v) for k, v in stats.items() if k.startswith("n_call_")}
    t_functions = sum(v for k, v in timing.items() if k.startswith("t_wall_nlp_"))
    t_total_ipopt = timing.get("t_wall_total", t_ipopt)
    t_callback = timing.get("t_wall_callback_fun", 0.0)
    info.update({
        "return_status": return_status,
        "ipopt_success": ipopt_ok,
        "iter_count": iterations,
        "stopped_by_time_limit": stopped,
        "t_build": entry.t_build if built else 0.0,
        "cached_solver": not built,
        "t_ipopt_total": float(t_total_ipopt),
        "t_function_evaluations": float(t_functions),
        "t_inside_ipopt": float(t_total_ipopt - t_functions - t_callback),
        "t_callback": t_callback,
        "t_certification": t_cert,
        "timing": timing,
        "calls": calls,
        "options": {"ipopt": _jsonable(entry.ipopt_options), "expand": options.expand,
                    "min_jacobian": options.min_jacobian, "max_time": options.max_time,
                    "residual_tol": options.residual_tol, "pose_tol": pose_tol,
                    "force_reference": force_reference(model)},
        "frozen": [names[i] for i in np.flatnonzero(frozen)],
        "contraction_ipopt": {names[i]: float(c_ip[i]) for i in range(model.n_winches)},
        "bound_violation": bound_violation,
        "objective_ipopt": float(np.asarray(sol["f"]).reshape(-1)[0]),
        "objective_certified": float(targets.value(eq.x)),
        "kkt": kkt,
        "ipopt_pose": check,
        "certified_distance": distance,
        "certified": {"converged": bool(cert.converged), "status": cert.status,
                      "newton_iterations": int(cert.iterations),
                      "saddle_escapes": int(cert.saddle_escapes)},
        "min_jacobian_at_solution": jmin,
        "jacobian_bound_active": bool(jmin is not None and options.min_jacobian is not None
                                      and jmin <= options.min_jacobian * (1 + 1e-6)),
        "active_bounds": [names[w] for w in free
                          if min(c_cert[w] - model.lower[w], model.upper[w] - c_cert[w])
                          <= 1e-6 * (model.upper[w] - model.lower[w])],
        "slack_winches": slack,
        "equilibrium_solves": 2 + (1 if taken else 0),
        "history_points": len(history),
    })
    log.info("bilevel: %s; O = %.6g; %d iterations", status, info["objective_certified"], iterations)
    return BilevelResult(ok, status, eq, eq.contraction.copy(), iterations, info, history,
                         time.perf_counter() - t_start)


def _jsonable(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, (bool, int, str)) or v is None:
            out[k] = v
        elif isinstance(v, float):
            out[k] = v if math.isfinite(v) else str(v)
        else:
            out[k] = repr(v)
    return out
