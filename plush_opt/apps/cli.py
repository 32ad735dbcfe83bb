"""The ``plush-opt`` command line.

Every error a user can cause ends as one line on stderr and a non-zero
exit status, never a traceback (``--debug`` shows it):

    0  success              2  bad input (file, option)
    3  solver did not converge (the result is still written, honestly)
    4  hardware error       70  internal error (a bug)      130  interrupted
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import logging
import os
import sys
import time
from pathlib import Path

from ..errors import HardwareError, PlushError, SceneError, SolverError

log = logging.getLogger("plush_opt")

EXIT_OK, EXIT_INPUT, EXIT_SOLVER, EXIT_HARDWARE, EXIT_INTERNAL, EXIT_INTERRUPT = 0, 2, 3, 4, 70, 130


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        self.exit(EXIT_INPUT, f"{self.prog}: error: {message}\n")


def _contraction_arg(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        v = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: {value!r} is not a number") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"{name}: {value!r} is not a finite number")
    return name, v


# --------------------------------------------------------------------------
# solve
# --------------------------------------------------------------------------

def _add_solve(sub):
    p = sub.add_parser("solve", help="solve a problem file: forward pose, or control to its targets",
                       description="Without targets (or with --method forward): the equilibrium "
                       "at the given contractions. With targets: winch contractions that bring "
                       "the equilibrium to them.")
    p.add_argument("problem", type=Path, help="problem file (YAML, format plush-opt/1)")
    p.add_argument("--contraction", "-c", action="append", type=_contraction_arg, default=[],
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
    p.add_argument("--trace", type=Path, help="write the control iterate history (CSV) here")
    p.add_argument("--accuracy", type=float, default=None, metavar="TOL",
                   help="mesh no finer than needed: the coarsest mesh whose predicted pose at the "
                   "targets differs from the next finer one by less than TOL (length units)")
    p.add_argument("--max-iterations", type=int, default=None, help="control iterations at most")
    p.add_argument("--max-time", type=float, default=None, help="control seconds at most")
    p.set_defaults(func=cmd_solve)


def _pairs(pairs, what: str = "--contraction") -> dict[str, float]:
    """NAME=VALUE pairs as a dict; a winch named twice is an error, not the last one winning."""
    out: dict[str, float] = {}
    for name, value in pairs:
        if name in out:
            raise SceneError(f"{what} {name}: given twice ({out[name]:g} and {value:g})")
        out[name] = value
    return out


def write_trace(path, model, targets, history) -> None:
    """Iterate history as CSV, written atomically."""
    from ..results import write_text_atomic
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
                  max_iterations=None, max_time=None, accuracy=None, direction="gauss-newton"):
    """Load and solve one problem; returns (problem, equilibrium, result document, history).

    The shared path of ``solve`` and ``demo``.
    """
    from ..control import BilevelOptions, ControlOptions
    from ..equilibrium import EquilibriumOptions
    from ..problem import load
    from ..results import control_result_dict, result_dict

    t0 = time.perf_counter()
    if max_iterations is not None and max_iterations < 0:
        raise SceneError(f"--max-iterations: expected >= 0, got {max_iterations}")
    if max_time is not None and not max_time > 0:
        raise SceneError(f"--max-time: expected a number of seconds > 0, got {max_time}")
    p = load(problem, accuracy=accuracy)
    contraction = _pairs(contraction_pairs)
    p.contraction_vector(contraction, what="--contraction")   # names and bounds checked first
    p.frozen_vector(freeze, what="--freeze")           # names checked before any solve
    if method is None:
        method = "reparam" if p.targets.n_targets else "forward"
    if method != "forward" and not p.targets.n_targets:
        raise SceneError(f"{p.source}: targets: --method {method} needs targets; the file has none")
    extra = {} if p.mesh_report is None else {"mesh_accuracy": p.mesh_report}
    if method == "forward":
        t_solve = time.perf_counter()
        eq = p.equilibrium(contraction, options=EquilibriumOptions(backend=equilibrium))
        t_end = time.perf_counter()
        doc = result_dict(p.model, p.targets, eq, method="forward", converged=eq.converged,
                          status=eq.status, total_s=t_end - t0, solve_s=t_end - t_solve,
                          iterations=eq.iterations, extra=extra)
        return p, eq, doc, ()
    quiet = EquilibriumOptions(backend=equilibrium, eigenvalue=False)
    if method == "bilevel":
        options = BilevelOptions(equilibrium=quiet)
        if max_iterations is not None:
            options = dataclasses.replace(options, max_iter=max_iterations)
    else:
        options = ControlOptions(equilibrium=quiet, direction=direction)
        if max_iterations is not None:
            options = dataclasses.replace(options, max_iterations=max_iterations)
    if max_time is not None:
        options = dataclasses.replace(options, max_time=max_time)
    res = p.control(method, contraction, freeze, options=options)
    # an iterate history is a trace only if every iterate is a certified
    # equilibrium (the loop's and the reduced-space bilevel's are)
    history = res.history if all(h.equilibrium is not None for h in res.history) else ()
    for it in history:
        log.info("iterate %d  O = %.6g  c = %s", it.iteration, it.objective,
                 ", ".join(f"{n}={v:.4f}" for n, v in zip(p.winch_names, it.contraction)))
    doc = control_result_dict(res, total_s=time.perf_counter() - t0, extra=extra)
    return p, res.equilibrium, doc, history


def cmd_solve(args) -> int:
    from ..results import write_json_atomic
    p, eq, doc, history = solve_problem(
        args.problem, args.contraction, args.freeze, args.method, args.equilibrium,
        args.max_iterations, args.max_time, args.accuracy, args.direction)
    if "mesh_accuracy" in doc:
        print(f"plush-opt: {doc['mesh_accuracy']['summary']}", file=sys.stderr)
    if args.trace and not history:
        raise SceneError("--trace: only a control run whose iterates are certified equilibria "
                         "(the gradient loop, the reduced-space bilevel method) has an iterate history")
    if args.out:
        write_json_atomic(args.out, doc)
    if args.plot:
        from .plot import plot_pose
        _use_agg()
        plot_pose(args.plot, p.model, eq.x, eq.contraction, p.targets if p.targets.n_targets else None)
    if args.trace:
        write_trace(args.trace, p.model, p.targets, history)
    cs = ", ".join(f"{n}={v:.4f}" for n, v in doc["contractions"].items())
    summary = (f"{doc['problem']}: {doc['method']}: {doc['status']}; {cs}; "
               f"objective {doc['objective']:.6g}; residual {doc['residual_norm']:.3g}; "
               f"{doc['timing']['total_s']:.3f} s")
    print(summary)
    if not doc["converged"]:
        print(f"plush-opt: not converged: {doc['status']}", file=sys.stderr)
        return EXIT_SOLVER
    return EXIT_OK


def _use_agg():
    import matplotlib
    if not os.environ.get("DISPLAY") and matplotlib.get_backend().lower() != "agg":
        matplotlib.use("Agg")


# --------------------------------------------------------------------------
# demo
# --------------------------------------------------------------------------

def _add_demo(sub):
    p = sub.add_parser("demo", help="the main job on the default problem (what `make demo` runs)",
                       description="Solve the gripper's pose problem, then play the gripper run "
                       "script on the board emulator.")
    p.add_argument("--problem", type=Path, default=None, help="default: problems/gripper.yaml")
    p.add_argument("--script", type=Path, default=None, help="default: examples/gripper_run.yaml")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--no-board", action="store_true", help="skip playing the run on the emulator")
    p.set_defaults(func=cmd_demo)


def _repo_file(*parts) -> Path:
    return Path(__file__).resolve().parents[2].joinpath(*parts)


def default_problem() -> Path:
    return _repo_file("problems", "gripper.yaml")


def cmd_demo(args) -> int:
    from .plot import plot_pose, plot_trace
    from ..results import write_json_atomic
    _use_agg()
    problem = args.problem or default_problem()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    print(f"demo: solving {problem.name} (control to its targets)")
    p, eq, doc, history = solve_problem(problem, method="reparam")
    write_json_atomic(out / "result.json", doc)
    plot_pose(out / "pose.png", p.model, eq.x, eq.contraction, p.targets)
    plot_trace(out / "trace.png", history, title=f"{p.scene.name}: control iterates")
    write_trace(out / "trace.csv", p.model, p.targets, history)
    err = p.targets.errors(eq.x)
    print(f"demo: {doc['status']}; {len(history) - 1} iterates, "
          f"{doc['control']['equilibrium_solves']} equilibrium solves, {doc['timing']['total_s']:.2f} s")
    print("demo: contractions " + ", ".join(f"{n} = {v:.3f} mm" for n, v in doc["contractions"].items()))
    print(f"demo: target errors {', '.join(f'{e:.2f}' for e in err)} mm; "
          f"min Hessian eigenvalue {doc['min_hessian_eigenvalue']:.3g}")
    print(f"demo: wrote {out / 'result.json'}, {out / 'pose.png'}, {out / 'trace.png'}, {out / 'trace.csv'}")
    if not args.no_board:
        _demo_run(args.script or _repo_file("examples", "gripper_run.yaml"), out)
    return EXIT_OK if doc["converged"] else EXIT_SOLVER


def _demo_run(script: Path, out: Path) -> None:
    """Play a run script on the board emulator; write its log and a plot."""
    import json
    from types import SimpleNamespace

    from .plot import plot_run_log
    print(f"demo: playing {script.name} on the board emulator")
    log_path = out / "run.jsonl"
    args = SimpleNamespace(script=script, port=None, emulator=True, dry_run=False, log=log_path)
    code = cmd_run(args)
    if code != EXIT_OK:
        raise SolverError(f"the demo run ended with status {code}")
    rows = [json.loads(line) for line in log_path.read_text().splitlines()]
    plot_run_log(out / "run.png", rows, title=f"{script.stem}: commanded and measured contractions")
    end = rows[-1]
    print(f"demo: run {end['status']}: {end['steps_done']} steps, {end['commands']} commands; "
          f"wrote {log_path}, {out / 'run.png'}")


# --------------------------------------------------------------------------
# run
# --------------------------------------------------------------------------

def _add_run(sub):
    from .runs import add_run_arguments
    p = sub.add_parser("run", help="play a run script on the winch board (or its emulator)",
                       description="Solve each step of a run script and stream the contractions "
                       "to the winch board. See docs/hardware.md.")
    add_run_arguments(p)
    p.set_defaults(func=cmd_run)


def cmd_run(args) -> int:
    from .planner import ControlPlanner
    from .runs import cli_run
    return cli_run(args, ControlPlanner)


# --------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    parser = _Parser(prog="plush-opt", description="Optimisation-centric control of plush robots.")
    parser.add_argument("--version", action="version", version=f"plush-opt {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="log more (-vv: debug)")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    _add_solve(sub)
    _add_run(sub)
    _add_demo(sub)
    from .bench import add_bench_parser
    add_bench_parser(sub)
    from .gui import add_gui_parser
    add_gui_parser(sub)
    from .compare import add_compare_parser
    add_compare_parser(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=[logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)],
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("plush-opt: interrupted", file=sys.stderr)
        return EXIT_INTERRUPT
    except Exception as exc:  # noqa: BLE001 - every error ends as one line
        if args.debug:
            raise
        message, code = _describe_error(exc)
        print(f"plush-opt: {message}", file=sys.stderr)
        return code


def _describe_error(exc: Exception) -> tuple[str, int]:
    """One line and an exit status for an error that ends a command."""
    if isinstance(exc, (SceneError, argparse.ArgumentTypeError)):
        return f"error: {exc}", EXIT_INPUT
    if isinstance(exc, HardwareError):
        return f"hardware error: {exc}", EXIT_HARDWARE
    if isinstance(exc, (SolverError, PlushError)):
        return f"solver error: {exc}", EXIT_SOLVER
    if isinstance(exc, OSError):
        return f"error: {exc.filename or ''}: {exc.strerror or exc}", EXIT_INPUT
    return (f"internal error: {type(exc).__name__}: {exc} (rerun with --debug for the traceback, "
            "and please report it)", EXIT_INTERNAL)


if __name__ == "__main__":
    sys.exit(main())
