"""The IPOPT backend of :func:`~plush_opt.solve.equilibrium.solve_equilibrium`,
for cross-checks: IPOPT minimises the CasADi expression of E; the answer
is certified by the same test as Newton's."""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from ..fem.model import Model
from .certificate import Equilibrium, EquilibriumOptions, certified, try_factor
from .newton import escape_saddle

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
            factor = try_factor(model, ev.hessian_form)
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
                escaped = escape_saddle(model, c, xs, ev, options)
                if escaped is not None:
                    x, escapes = escaped[0], escapes + 1
                    continue
            break
        status = _ipopt_status(stats, small, factor, escapes)
        return certified(model, c, xs, ev, factor, small and factor is not None, status, iterations, t0,
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
