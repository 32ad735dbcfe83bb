"""The bilevel method's NLP in CasADi: variables, constraints, objective,
IPOPT and its iteration recorder.

Built once per (model, frozen set, target triangles, options) by
:class:`~plush_opt.control.bilevel.BilevelSolver`, which owns the cache.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..base.errors import interrupt_noted
from ..base.eigenpair import smallest_eigenpair
from ..base.linalg import NotPositiveDefinite
from ..fem.model import Model
from ..solve.ipopt_equilibrium import IterationCallback
from .result import ControlIterate

# A pose whose relative residual is this small is an equilibrium in all but
# stability: an indefinite Hessian there is reported as a saddle.
SADDLE_RESIDUAL = 1e-6

class Recorder(IterationCallback):
    """IPOPT iteration callback: records (t, O, violation, c) and stops
    IPOPT (by returning 1) once the time limit has passed or a signal has
    been noted (:func:`~plush_opt.base.errors.interrupt_noted`; the caller
    then re-raises it, :func:`~plush_opt.solve.ipopt_equilibrium.call_ipopt`
    with ``stops_itself``)."""

    def __init__(self, name: str, n_z: int, n_g: int, n_p: int):
        ca.Callback.__init__(self)
        self.sizes = {"x": n_z, "lam_x": n_z, "g": n_g, "lam_g": n_g, "p": n_p, "lam_p": n_p, "f": 1}
        self.reset(None)
        self.construct(name, {})

    def reset(self, run: dict | None):
        self.run = run
        self.points: list[ControlIterate] = []
        self.stopped = False


    def eval(self, arg):
        try:
            return self._record(arg)
        except KeyboardInterrupt:    # the handler ran here: it noted the signal
            return [1]

    def _record(self, arg):
        run = self.run
        if interrupt_noted():
            return [1]
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
        self.points.append(ControlIterate(iteration=len(self.points), t_wall=t, contraction=c,
                                          objective=f, constraint_violation=viol))
        if run["max_time"] is not None and t >= run["max_time"]:
            self.stopped = True
            return [1]
        return [0]


@dataclass
class NlpEntry:
    """One built NLP: the IPOPT solver and what solving with it needs."""

    solver: ca.Function
    recorder: Recorder
    grad_lag: ca.Function
    free: np.ndarray
    frozen: np.ndarray
    n_g: int
    lbg: np.ndarray
    ubg: np.ndarray
    t_build: float
    ipopt_options: dict



def force_reference(model: Model) -> float:
    """F_ref: the elastic force of a unit strain across the body,
    mu * thickness * sqrt(body area) (force units). The equilibrium
    constraint is divided by it, so IPOPT's tolerances are relative."""
    return float(model.mu * model.thickness * math.sqrt(model.rest_area.sum()))


def gradient_expression(model: Model, store: dict) -> ca.MX:
    if "grad" not in store:
        store["grad"] = ca.gradient(model.E_sym, model.x_sym)
    return store["grad"]


def _objective_expression(x: ca.MX, nodes: np.ndarray, beta: ca.MX, q: ca.MX, sqrt_w: ca.MX) -> ca.MX:
    """O(x) = 1/2 sum_k w_k |sum_j beta_kj x_{n_kj} - q_k|^2 with beta, q,
    w symbolic (the same value as Targets.value). ``beta`` holds the nodes'
    interpolation weights (Targets.weights: 3 for P1, 6 for P2)."""
    k = nodes.shape[0]
    if k == 0:
        return ca.MX(0)
    yx = ca.MX.zeros(k, 1)
    yy = ca.MX.zeros(k, 1)
    for j in range(nodes.shape[1]):
        yx += beta[:, j] * x[(2 * nodes[:, j]).tolist()]
        yy += beta[:, j] * x[(2 * nodes[:, j] + 1).tolist()]
    rx = sqrt_w * (yx - q[:, 0])
    ry = sqrt_w * (yy - q[:, 1])
    return 0.5 * (ca.sumsqr(rx) + ca.sumsqr(ry))


def build_nlp(model: Model, frozen: np.ndarray, nodes: np.ndarray, options, store: dict) -> "NlpEntry":
    """IPOPT on the KKT formulation for these free winches and target
    nodes, with its recorder and the gradient of the Lagrangian (for the KKT
    check). ``store`` keeps grad_x E, shared by every entry of a model."""
    t0 = time.perf_counter()
    free = np.flatnonzero(~frozen)
    fixed = np.flatnonzero(frozen)
    n_free, n_fixed, k = len(free), len(fixed), nodes.shape[0]
    c_free = ca.MX.sym("c", n_free)
    c_fixed = ca.MX.sym("c_frozen", n_fixed)
    q = ca.MX.sym("q", k, 2)
    sqrt_w = ca.MX.sym("sqrt_w", k)
    beta = ca.MX.sym("beta", k, nodes.shape[1])
    # c_full = P_free c_free + P_fixed c_fixed
    P_free = ca.DM.zeros(model.n_winches, n_free)
    for j, w in enumerate(free):
        P_free[int(w), j] = 1
    P_fixed = ca.DM.zeros(model.n_winches, n_fixed)
    for j, w in enumerate(fixed):
        P_fixed[int(w), j] = 1
    c_full = P_free @ c_free + (P_fixed @ c_fixed if n_fixed else 0)
    x = model.x_sym
    grad = ca.substitute(gradient_expression(model, store), model.c_sym, c_full)
    F_ref = force_reference(model)
    g = [grad / F_ref]
    lbg = [np.zeros(model.n_dofs)]
    ubg = [np.zeros(model.n_dofs)]
    if options.min_jacobian is not None:
        jac = model.jacobian_expression(x)      # J per element (P2: per quadrature point)
        g.append(jac)
        lbg.append(np.full(jac.shape[0], options.min_jacobian))
        ubg.append(np.full(jac.shape[0], np.inf))
    z = ca.vertcat(x, c_free)
    p = ca.vertcat(c_fixed, ca.vec(q), sqrt_w, ca.vec(beta))
    f = _objective_expression(x, nodes, beta, q, sqrt_w)
    gz = ca.vertcat(*g)
    nlp = {"x": z, "p": p, "f": f, "g": gz}
    recorder = Recorder("bilevel_iterations", z.shape[0], gz.shape[0], p.shape[0])
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
    return NlpEntry(solver, recorder, grad_lag, free, fixed, gz.shape[0],
                  np.concatenate(lbg), np.concatenate(ubg), time.perf_counter() - t0, ipopt)


def parameters(entry: NlpEntry, c: np.ndarray, targets) -> np.ndarray:
    return np.concatenate([c[entry.frozen], targets.to.T.reshape(-1), np.sqrt(targets.weight),
                           targets.weights.T.reshape(-1)])


def pose_check(model: Model, x: np.ndarray, c: np.ndarray, residual_tol: float) -> dict:
    """Is ``x`` a stable equilibrium at ``c``? Admissible (else why not, in
    words), residual, Cholesky, eigenvalue."""
    why = model.violation(x)
    out = {"admissible": why is None, "violation": why, "relative_residual": None,
           "positive_definite": False, "min_eigenvalue": None, "stable_equilibrium": False}
    if not out["admissible"]:
        return out
    ev = model.evaluate(x, c, order=2)
    rel = float(np.linalg.norm(ev.gradient) / ev.force_scale)
    out["relative_residual"] = rel
    try:
        model.factorizer.factor(ev.hessian_form)
        # positive definite: the certified pose's eigenvalue is reported instead
        out["positive_definite"] = True
    except NotPositiveDefinite:
        out["min_eigenvalue"] = float(smallest_eigenpair(ev.hessian_form)[0])
    out["stable_equilibrium"] = bool(out["positive_definite"] and rel <= residual_tol)
    return out


def describe_pose(check: dict) -> str:
    if not check["admissible"]:
        return f"ipopt pose is not admissible ({check['violation']})"
    rel = check["relative_residual"]
    if not check["positive_definite"]:
        if rel is not None and rel <= SADDLE_RESIDUAL:
            return (f"ipopt pose is a saddle of E (min Hessian eigenvalue "
                    f"{check['min_eigenvalue']:.3g}, relative residual {rel:.2g})")
        return (f"ipopt pose is not an equilibrium (relative residual {rel:.2g}) and its Hessian "
                f"is indefinite (min eigenvalue {check['min_eigenvalue']:.3g})")
    return f"ipopt pose is not an equilibrium (relative residual {rel:.2g})"


def kkt(model: Model, entry: NlpEntry, sol, z, p, options) -> dict:
    """Stationarity, feasibility and complementarity at IPOPT's answer."""
    n = model.n_dofs
    free = entry.free
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
    return {"stationarity": float(np.max(np.abs(gl), initial=0.0)),
            "feasibility": float(np.max(feas, initial=0.0)),
            "complementarity": comp}


def jsonable(d: dict) -> dict:
    """IPOPT options as JSON values (non-finite floats and objects as text)."""
    out = {}
    for k, v in d.items():
        if isinstance(v, (bool, int, str)) or v is None:
            out[k] = v
        elif isinstance(v, float):
            out[k] = v if math.isfinite(v) else str(v)
        else:
            out[k] = repr(v)
    return out
