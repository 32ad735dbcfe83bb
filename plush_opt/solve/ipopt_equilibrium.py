"""The IPOPT backend of :func:`~plush_opt.solve.equilibrium.solve_equilibrium`,
for cross-checks: IPOPT minimises the CasADi expression of E; the answer
is certified by the same test as Newton's."""

from __future__ import annotations

import contextlib
import threading
import time

import casadi as ca
import numpy as np

from ..base.errors import interrupt_noted, only_note_signals, raise_if_interrupted
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


class IterationCallback(ca.Callback):
    """An IPOPT iteration callback: nlpsol's outputs in (those named in
    ``sizes``, the others empty), one flag out (1 stops IPOPT)."""

    sizes: dict = {}

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        n = self.sizes.get(ca.nlpsol_out(i), 0)
        return ca.Sparsity.dense(n, 1) if n else ca.Sparsity(0, 0)


class StopOnSignal(IterationCallback):
    """An IPOPT iteration callback that stops the solve (returns 1) once a
    signal has been noted (:func:`~plush_opt.base.errors.note_interrupt`):
    IPOPT's loop runs in C++, where the handler's exception cannot reach.
    The solver's caller then re-raises it (:func:`call_ipopt`)."""

    def __init__(self, name: str = "stop_on_signal"):
        ca.Callback.__init__(self)
        self.construct(name, {})

    def eval(self, arg):
        try:
            return [1 if interrupt_noted() else 0]
        except KeyboardInterrupt:    # the handler ran here: it noted the signal
            return [1]


#: nlpsol options that make an IPOPT solve stop at its next iteration after a signal.
STOP_ON_SIGNAL = {"iteration_callback_step": 1, "iteration_callback_ignore_errors": False}


def stop_on_signal_options(callback: StopOnSignal) -> dict:
    """nlpsol options adding ``callback`` as the iteration callback (the
    caller keeps it alive as long as the solver: CasADi holds no reference)."""
    return {"iteration_callback": callback, **STOP_ON_SIGNAL}


def call_ipopt(solver: ca.Function, stops_itself: bool = False, **kwargs) -> dict:
    """``solver(**kwargs)``, re-raising a signal noted during the solve
    (IPOPT ends such a solve with User_Requested_Stop, or with an error where
    the handler's exception reached one of its callbacks). ``stops_itself``:
    the solver has a :class:`StopOnSignal` callback, so a signal is only
    noted during the solve, which then ends cleanly at its next iteration."""
    try:
        with only_note_signals() if stops_itself else contextlib.nullcontext():
            sol = solver(**kwargs)
    except Exception:
        raise_if_interrupted()
        raise
    raise_if_interrupted()
    return sol


BUILD_POLL = 0.1     # s between the main thread's looks at a build running in a worker thread


def build_interruptibly(build, *args):
    """``build(*args)`` in a worker thread while the main thread waits, so
    that a signal ends the command during a long NLP build (CasADi releases
    the interpreter while it builds; its C++ would otherwise hold the signal
    until the build ends). The abandoned worker is a daemon thread."""
    if threading.current_thread() is not threading.main_thread():
        return build(*args)
    box: dict = {}

    def work():
        try:
            box["value"] = build(*args)
        except BaseException as exc:   # noqa: BLE001 - re-raised in the main thread
            box["error"] = exc

    worker = threading.Thread(target=work, name="nlp-build", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(BUILD_POLL)
    if "error" in box:
        raise box["error"]
    return box["value"]


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
        self._stop = StopOnSignal()

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
            opts.update(stop_on_signal_options(self._stop))

            def build():      # the model's symbolic energy too (built on first use: long on a fine mesh)
                return ca.nlpsol("equilibrium", "ipopt", {"x": m.x_sym, "p": m.c_sym, "f": m.E_sym}, opts)
            self._solvers[key] = build_interruptibly(build)
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
            return Equilibrium(x, c, False, f"initial pose not admissible ({model.violation(x)})",
                               np.inf, np.inf, np.nan, False, None, 0, 0.0, "ipopt")
        iterations, escapes, polished = 0, 0, False
        extra = {}
        while True:
            solver = self.solver(options, extra)
            sol = call_ipopt(solver, stops_itself=True, x0=x, p=c)
            stats = solver.stats()
            iterations += int(stats.get("iter_count", 0))
            xs = np.array(sol["x"], dtype=np.float64).reshape(-1)
            ev = model.evaluate(xs, c, order=2)
            if not ev.admissible:
                return Equilibrium(xs, c, False, f"ipopt: {stats['return_status']}; pose not admissible "
                                   f"({model.violation(xs)})",
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
