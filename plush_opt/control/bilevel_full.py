"""The full-space bilevel NLP: one IPOPT solve on (x, c), then certification.

The control problem min_c O(x(c)) with x(c) a minimiser of E(., c) is
replaced by its first-order form (the equilibrium as a constraint):

    minimise    O(x)                          over x (n_dofs) and the free c
    subject to  grad_x E(x, c) / F_ref = 0    (n_dofs equations)
                J_e(x) >= delta               (every element, optional)
                lower <= c <= upper           (IPOPT variable bounds)

IPOPT gets the exact Hessian of the Lagrangian from CasADi, which holds
third derivatives of E (:mod:`.bilevel_nlp` builds it; the solver keeps it,
:class:`~plush_opt.control.bilevel.BilevelSolver`).

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
"""

from __future__ import annotations

import time

import numpy as np

from ..solve.equilibrium import solve_equilibrium
from ..solve.ipopt_equilibrium import call_ipopt
from .bilevel_nlp import (NlpEntry, describe_pose as _describe_pose, force_reference,
                          jsonable as _jsonable, kkt as _kkt, parameters as _parameters, pose_check as _pose_check)
from .bilevel_options import BilevelStats
from .slack import slack_winches

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
# pose_tol's default: this fraction of the body's diameter (length units).
POSE_FRACTION = 1e-6
# An element's J within this relative margin of min_jacobian counts as
# holding the J >= delta constraint active.
JACOBIAN_ACTIVE = 1e-6


class FullRun:
    """One IPOPT solve of the full-space NLP from a certified start, and its
    certification: :meth:`solve`, :meth:`certify`, then :meth:`reason`,
    :meth:`status` and :meth:`stats` (``entry``, the built NLP, and
    ``built``, whether it was built for this run, are set by the caller)."""

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
            self.sol = call_ipopt(entry.solver, stops_itself=True, x0=z0, p=self.p, lbx=lbx, ubx=ubx, lbg=entry.lbg, ubg=entry.ubg)
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
        self.pose_tol = (options.pose_tol if options.pose_tol is not None
                         else POSE_FRACTION * model.mesh.diameter)
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
                                       and self.jmin <= options.min_jacobian * (1 + JACOBIAN_ACTIVE)),
            active_bounds=[names[w] for w in free
                           if min(self.c_cert[w] - model.lower[w], model.upper[w] - self.c_cert[w])
                           <= ACTIVE_BOUND * span[w]],
            slack_winches=self.slack, equilibrium_solves=2 + (1 if self.taken else 0),
            history_points=len(self.history))
