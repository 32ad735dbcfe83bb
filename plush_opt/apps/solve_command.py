"""``plush-opt solve``: a problem file's forward pose, or control to its
targets; the result JSON, a picture, the iterate trace.

:func:`solve_problem` is the shared path of ``solve``, ``demo`` and
``export`` (a problem file without a result)."""

from __future__ import annotations

import csv
import dataclasses
import io
import logging
import sys
import time
from pathlib import Path

import numpy as np

from ..base.errors import SceneError, SettingError, SolverError, interrupt_status, one_line
from .arguments import add_picture_flags, check_tension_max, contraction_arg, pairs
from .console import EXIT_OK, EXIT_SOLVER, say, summary_line, use_agg
from ..control.result import INTERRUPTED

log = logging.getLogger("plush_opt")

#: Steps of the forward solve's continuation in the contraction, where the
#: solve from rest fails (halved where a step fails): a few, as a user would.
CONTINUATION_STEPS = 4
#: With --accuracy, a positive definite pose whose residual stalls within its
#: round-off floor is converged (EquilibriumOptions.roundoff; docs/accuracy.md).
ACCURACY_ROUNDOFF = 1.0
#: The status of a result whose solve a solver error ended (its ``reason`` says which).
SOLVER_ERROR_STATUS = "solver_error"


def add_solve_parser(sub) -> None:
    p = sub.add_parser("solve", help="solve a problem file: forward pose, or control to its targets",
                       description="Without targets (or with --method forward): the equilibrium "
                       "at the given contractions. With targets: winch contractions that bring "
                       "the equilibrium to them.")
    p.add_argument("problem", type=Path, help="problem file (YAML, format plush-opt/1)")
    p.add_argument("--contraction", "-c", action="append", type=contraction_arg, default=[],
                   metavar="NAME=VALUE", help="contraction of a winch (forward input, or where "
                   "control starts); repeatable")
    p.add_argument("--freeze", action="append", default=[], metavar="NAME",
                   help="freeze a winch during control (keeps its contraction); repeatable")
    p.add_argument("--method", choices=("forward", "reparam", "clip", "bilevel"), default=None,
                   help="forward: equilibrium only (targets ignored); reparam (default with "
                   "targets): the gradient loop with reparametrised bounds; clip: the same loop "
                   "clipping the contractions to their bounds (the baseline); bilevel: IPOPT on "
                   "the KKT formulation")
    p.add_argument("--direction", choices=("gauss-newton", "gradient"), default="gauss-newton",
                   help="search direction of the gradient loop (reparam, clip): Gauss-Newton on "
                   "the target residuals (default) or steepest descent with Barzilai-Borwein steps")
    p.add_argument("--equilibrium", choices=("newton", "ipopt"), default="newton",
                   help="equilibrium backend (default newton; ipopt for cross-checks)")
    p.add_argument("--out", "-o", type=Path, help="write the result JSON here")
    p.add_argument("--plot", type=Path, help="write a PNG of the pose here")
    add_picture_flags(p)
    p.add_argument("--trace", type=Path, help="write the control iterate history (CSV) here")
    p.add_argument("--accuracy", type=float, default=None, metavar="TOL",
                   help="choose the element (P1, P2) and mesh whose estimated error of the "
                   "positions of the targets (or tendon stoppers) is below TOL (length units) at the "
                   "least cost of a solve (counted, the same on every run), then estimate it again at "
                   "the returned contractions and solve again on a finer mesh if TOL is not met there: "
                   "the result's accuracy.at_result says what holds for the returned pose; warns where "
                   "TOL is not met")
    p.add_argument("--max-iterations", type=int, default=None, help="control iterations at most")
    p.add_argument("--max-time", type=float, default=None, help="control seconds at most")
    p.add_argument("--ipopt-print-level", type=int, default=None, metavar="N", choices=range(13),
                   help="IPOPT's print_level, 0-12 (bilevel method, ipopt equilibrium backend); "
                   "its output goes to stdout")
    p.set_defaults(func=cmd_solve)
def write_trace(path, model, targets, history) -> None:
    """Iterate history as CSV, written atomically."""
    from ..base.files import write_text_atomic
    buf = io.StringIO()
    w = csv.writer(buf)
    names = list(model.winch_names)
    w.writerow(["iteration", "t_wall_s", "objective", "rms_target_error"]
               + [f"c_{n}" for n in names] + [f"dO_dc_{n}" for n in names]
               + ["active_bounds", "equilibrium_solves", "newton_iterations", "residual_norm"])
    for h in history:
        w.writerow([h.iteration, f"{h.t_wall:.6f}", repr(h.objective), repr(targets.rms_error(h.x)),
                    *[repr(float(c)) for c in h.contraction], *[repr(float(g)) for g in h.gradient],
                    " ".join(h.active_bounds), h.equilibrium_solves, h.newton_iterations,
                    repr(h.equilibrium.residual_norm)])
    write_text_atomic(path, buf.getvalue())


def solve_problem(problem: Path, contraction_pairs=(), freeze=(), method=None, equilibrium="newton",
                  max_iterations=None, max_time=None, accuracy=None, direction="gauss-newton",
                  ipopt_print_level=None):
    """Load and solve one problem; returns (problem, equilibrium, result document, history).

    The shared path of ``solve`` and ``demo``.
    """
    from ..problem import load

    t0 = time.perf_counter()
    if max_iterations is not None and max_iterations < 0:
        raise SceneError(f"--max-iterations: expected >= 0, got {max_iterations}")
    if max_time is not None and not max_time > 0:
        raise SceneError(f"--max-time: expected a number of seconds > 0, got {max_time}")
    log.info("%s: meshing and building the model", Path(problem).name)
    accurate = None
    if accuracy is None:
        p = load(problem)
    else:
        from .accuracy_run import AccurateSolve
        accurate = AccurateSolve(problem, accuracy, progress=lambda line: say(f"plush-opt: {line}", err=True))
        p = accurate.problem
    log.debug("%s: %d nodes, %d elements, %d tendons, winches %s", p.source, p.mesh.n_nodes, p.mesh.n_elems,
              p.model.n_tendons, ", ".join(p.winch_names))
    contraction = pairs(contraction_pairs)
    p.contraction_vector(contraction, what="--contraction")   # names and bounds checked first
    p.frozen_vector(freeze, what="--freeze")           # names checked before any solve
    if method is None:
        method = "reparam" if p.targets.n_targets else "forward"
    if method != "forward" and not p.targets.n_targets:
        raise SceneError(f"{p.source}: targets: --method {method} needs targets; the file has none")
    extra = {} if p.mesh_report is None else accuracy_record(p.mesh_report)

    def solve(p, contraction, x0=None):
        return _solve_loaded(p, contraction, freeze, method, equilibrium, max_iterations, max_time, direction,
                             ipopt_print_level, t0, {} if p.mesh_report is None else accuracy_record(p.mesh_report),
                             x0)
    try:
        solved = solve(p, contraction)
        # --accuracy: the estimate at the returned contractions (and a finer level if needed)
        return solved if accurate is None else accurate.check(solved, solve, contraction, freeze)
    except SolverError as exc:
        if isinstance(exc, SettingError):      # bad input (exit 2), not a solve that failed
            raise
        return _solver_failed(p, contraction, method, equilibrium, exc, t0, extra)


def solve_loaded(p, contraction_pairs=(), method=None):
    """``p`` (a loaded :class:`~plush_opt.problem.Problem`, e.g. on a mesh
    built apart) solved as ``solve`` solves a file without ``--accuracy``:
    control from ``contraction_pairs`` (name, value) with the default method
    if it has targets, else the forward pose there (``method`` overrides).
    Returns (equilibrium, result document)."""
    method = method or ("reparam" if p.targets.n_targets else "forward")
    contraction = pairs(contraction_pairs)
    _, eq, doc, _ = _solve_loaded(p, contraction, (), method, "newton", None, None, "gauss-newton", None,
                                  time.perf_counter(), {})
    return eq, doc


def _solve_loaded(p, contraction, freeze, method, equilibrium, max_iterations, max_time, direction,
                  ipopt_print_level, t0, extra, x0=None):
    """:func:`solve_problem` once the problem is loaded and its names checked
    (``x0``: a pose near the first equilibrium, the forward solve's or the
    control run's, or None)."""
    from ..control import BilevelOptions, ControlOptions
    from ..solve.equilibrium import EquilibriumOptions
    from ..solve.result_file import control_result_dict, result_dict
    # IPOPT's own output, when asked for: keys with the prefix for the equilibrium backend
    eq_ipopt = {} if ipopt_print_level is None else {"ipopt.print_level": ipopt_print_level}
    log.info("%s: %s", p.scene.name, "equilibrium" if method == "forward" else f"control ({method})")
    # --accuracy: a mesh level fine enough that its residual's round-off floor can exceed gtol
    # (not a file's explicit mesh: nothing was chosen, and its stall stays a stall)
    roundoff = ACCURACY_ROUNDOFF if p.mesh_report is not None and p.mesh_report.get("levels") else 0.0
    if method == "forward":
        t_solve = time.perf_counter()
        eq = p.equilibrium(contraction, x0=x0, options=EquilibriumOptions(
            backend=equilibrium, ipopt=eq_ipopt, continuation=_continuation_steps(p), roundoff=roundoff))
        t_end = time.perf_counter()
        doc = result_dict(p.model, p.targets, eq, method="forward", converged=eq.converged,
                          status=eq.status, total_s=t_end - t0, solve_s=t_end - t_solve,
                          iterations=eq.iterations,
                          extra={**extra, "continuation_steps": getattr(eq, "continuation_steps", 0)})
        return p, eq, doc, ()
    quiet = EquilibriumOptions(backend=equilibrium, eigenvalue=False, ipopt=eq_ipopt, roundoff=roundoff)
    if method == "bilevel":
        options = BilevelOptions(equilibrium=quiet,
                                 ipopt={} if ipopt_print_level is None else {"print_level": ipopt_print_level})
        if max_iterations is not None:
            options = dataclasses.replace(options, max_iter=max_iterations)
    else:
        options = ControlOptions(equilibrium=quiet, direction=direction)
        if max_iterations is not None:
            options = dataclasses.replace(options, max_iterations=max_iterations)
    if max_time is not None:
        options = dataclasses.replace(options, max_time=max_time)
    try:
        res = p.control(method, contraction, freeze, x0=x0, options=options)
    except KeyboardInterrupt as exc:
        # a signal: the run so far (the loop's last accepted iterate), for --out
        partial = getattr(exc, "partial_result", None)
        if partial is not None:
            exc.result_document = control_result_dict(partial, total_s=time.perf_counter() - t0,
                                                      extra={"signal": interrupt_status(exc)[0], **extra})
        raise
    except SolverError as exc:
        # Control cannot start (the starting equilibrium is not certified):
        # the result still says where the robot is, honestly not converged.
        return _start_failed(p, contraction, method, equilibrium, exc, t0, extra)
    # an iterate history is a trace only if every iterate is a certified
    # equilibrium (the loop's and the reduced-space bilevel's are)
    history = res.history if all(h.equilibrium is not None for h in res.history) else ()
    try:
        for it in history:
            log.info("iterate %d  O = %.6g  c = %s", it.iteration, it.objective,
                     ", ".join(f"{n}={v:.4f}" for n, v in zip(p.winch_names, it.contraction)))
        doc = control_result_dict(res, total_s=time.perf_counter() - t0, extra=extra)
    except KeyboardInterrupt as exc:
        # a signal after the run ended: its certified end, marked interrupted
        name = interrupt_status(exc)[0]
        done = dataclasses.replace(res, converged=False, reason=INTERRUPTED, status=f"{INTERRUPTED} by {name}")
        exc.result_document = control_result_dict(done, total_s=time.perf_counter() - t0,
                                                  extra={"signal": name, **extra})
        raise
    return p, res.equilibrium, doc, history


def _continuation_steps(p) -> int:
    """The forward solve's continuation in the contraction after a failure
    from rest (EquilibriumOptions.continuation): on a history-free plant
    only (with friction the path is the physics, and it is followed anyway)."""
    from ..solve.elastic_plant import ElasticPlant
    return CONTINUATION_STEPS if type(p.plant) is ElasticPlant else 0


def accuracy_record(report: dict) -> dict:
    """The result JSON's keys for a mesh chosen by ``--accuracy``: ``accuracy``
    (tolerance, estimated_error, element, nodes, whether the tolerance was
    met, whether the mesh is graded, how often it was refined uniformly,
    the summary, why the sweep stopped) and ``mesh_accuracy`` (with the
    levels solved and those left unsolved)."""
    keys = ("tolerance", "estimated_error", "element", "nodes", "reached", "status", "max_area",
            "graded", "refinements", "summary", "stopped")
    return {"accuracy": {k: report.get(k) for k in keys}, "mesh_accuracy": report}


def _start_failed(p, contraction, method, equilibrium, exc, t0, extra):
    """The result of a control run that could not start: the starting
    equilibrium, ``converged: false``, the reason as its status."""
    from ..solve.equilibrium import EquilibriumOptions
    from ..solve.result_file import result_dict
    t_solve = time.perf_counter()
    eq = p.equilibrium(contraction, options=EquilibriumOptions(backend=equilibrium))
    t_end = time.perf_counter()
    if eq.converged:
        raise exc            # the start is fine: the error is another one
    doc = result_dict(p.model, p.targets, eq, method=method, converged=False,
                      status="start_not_certified", total_s=t_end - t0, solve_s=t_end - t_solve,
                      iterations=eq.iterations, extra={"reason": str(exc), **extra})
    return p, eq, doc, ()


def _solver_failed(p, contraction, method, equilibrium, exc, t0, extra):
    """The result of a solve a :class:`SolverError` ended (no Hessian shift
    found, a factorisation that failed): ``converged: false``, status
    ``solver_error``, the error as its ``reason``, and the pose the solve
    started from (the rest pose), which is all that is known."""
    from ..solve.certificate import Equilibrium
    from ..solve.result_file import result_dict
    c = p.contraction_vector(contraction, what="--contraction")
    eq = Equilibrium(p.model.X.copy(), c, False, f"solver error: {exc}", np.nan, np.inf, np.nan, False, None,
                     0, 0.0, equilibrium)
    t_end = time.perf_counter()
    with np.errstate(all="ignore"):     # the numbers that come out non-finite are written as null
        doc = result_dict(p.model, p.targets, eq, method=method, converged=False, status=SOLVER_ERROR_STATUS,
                          total_s=t_end - t0, solve_s=t_end - t0, iterations=0,
                          extra={"reason": f"solver error: {exc}", **extra})
    return p, eq, _null_non_finite(doc), ()


def _null_non_finite(value):
    """``value`` (a JSON document) with every non-finite number as null, as the
    result file writes a missing number (the pose of a failed solve may have
    degenerate tendon segments: 0/0 rest lengths)."""
    if isinstance(value, dict):
        return {k: _null_non_finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_null_non_finite(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _check_solve_outputs(args) -> None:
    """Every output path of ``solve`` refused before the solve, not after it."""
    from ..base.files import check_output_path
    for option, path in (("--out", args.out), ("--plot", args.plot), ("--trace", args.trace)):
        if path is not None:
            check_output_path(path, option)
    if args.trace is not None and args.method == "forward":
        raise SceneError("--trace: only a control run has an iterate history (not --method forward)")


def write_interrupted(out, exc: KeyboardInterrupt) -> None:
    """``--out``, atomically, with the result of a control run a signal
    ended (``status: interrupted``), if the run left one; the signal then
    ends the command with its status."""
    doc = getattr(exc, "result_document", None)
    if out is not None and doc is not None:
        from ..base.files import write_json_atomic
        write_json_atomic(out, doc)


def say_accuracy(acc: dict) -> None:
    """The sweep's pick, then what holds at the returned pose (``at_result``),
    one line each; a tolerance not met is a warning, not a progress line.
    Where the result has its own line, that line decides: the sweep's
    estimate is then the probes', not the answer's."""
    at = acc.get("at_result")
    lines = [(acc["reached"] or at is not None, acc["summary"])]
    if at is not None:
        lines.append((at["met"], at["summary"]))
    for ok, line in lines:
        if ok:
            say(f"plush-opt: {line}", err=True)
        else:
            log.warning("%s", line)


def cmd_solve(args) -> int:
    from ..base.files import write_json_atomic
    check_tension_max(args.tension_max)
    _check_solve_outputs(args)
    try:
        p, eq, doc, history = solve_problem(
            args.problem, args.contraction, args.freeze, args.method, args.equilibrium,
            args.max_iterations, args.max_time, args.accuracy, args.direction, args.ipopt_print_level)
    except KeyboardInterrupt as exc:
        write_interrupted(args.out, exc)
        raise
    if "accuracy" in doc:
        say_accuracy(doc["accuracy"])
    if doc.get("self_crossing"):
        log.warning("the returned pose crosses itself (%s): the scene has no contact.self, so the body may pass "
                    "through itself; add `self: true` under `contact:` to forbid that", doc["self_crossing"])
    if args.trace and not history and doc["status"] != "start_not_certified":
        raise SceneError("--trace: only a control run whose iterates are certified equilibria "
                         "(the gradient loop, the reduced-space bilevel method) has an iterate history")
    if args.out:
        write_json_atomic(args.out, doc)
    if args.plot:
        from ..base.files import check_output_path
        from .plot import plot_pose
        use_agg()
        check_output_path(args.plot, "--plot")     # still writable after the solve
        plot_pose(args.plot, p.model, eq.x, eq.contraction, p.targets if p.targets.n_targets else None,
                  tension_max=args.tension_max, converged=doc["converged"], status=doc["status"])  # atomic itself
    if args.trace and history:
        write_trace(args.trace, p.model, p.targets, history)
    if args.vtk:
        from .export import write_control
        write_control(args.vtk, p.model, eq, history)
    say(summary_line(doc))
    if doc["status"] == SOLVER_ERROR_STATUS:
        print(f"plush-opt: {one_line(doc['reason'])}", file=sys.stderr)
        return EXIT_SOLVER
    if not doc["converged"]:
        print(f"plush-opt: not converged: {doc['status']}", file=sys.stderr)
        return EXIT_SOLVER
    return EXIT_OK
