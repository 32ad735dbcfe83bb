"""The ``plush-opt`` command line.

Every error a user can cause ends as one line on stderr and a non-zero
exit status, never a traceback (``--debug`` shows it):

    0  success              2  bad input (file, option)
    3  solver did not converge (the result is still written, honestly)
    4  hardware error       70  internal error (a bug)      130  interrupted (Ctrl-C)
    143, 129  ended by SIGTERM, SIGHUP (handled like Ctrl-C: the board stopped, the log ended)
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import logging
import os
import signal
import sys
import time
from pathlib import Path

from ..base.errors import HardwareError, PlushError, SceneError, SolverError, interrupt_status, one_line
from .signals import handle_signals

log = logging.getLogger("plush_opt")

EXIT_OK, EXIT_INPUT, EXIT_SOLVER, EXIT_HARDWARE, EXIT_INTERNAL, EXIT_INTERRUPT = 0, 2, 3, 4, 70, 130
LENGTH_UNIT = "mm"     # the shipped problems' unit; summary lines carry it

_output = {"quiet": False}   # set once by _configure_output: -q silences summaries and progress


def say(text: str = "", err: bool = False) -> None:
    """A summary or progress line, unless -q."""
    if not _output["quiet"]:
        print(text, file=sys.stderr if err else sys.stdout, flush=True)


class _CliFormatter(logging.Formatter):
    """Progress (INFO) as plain lines, warnings and errors named, debug with its source."""

    def format(self, record):
        msg = record.getMessage()
        if record.levelno >= logging.WARNING:
            return f"plush-opt: {record.levelname.lower()}: {msg}"
        if record.levelno <= logging.DEBUG:
            return f"debug {record.name}: {msg}"
        return msg


def _configure_output(args) -> None:
    """-q: errors only; default: warnings; -v: progress and solver steps; -vv: debug."""
    quiet, verbose = getattr(args, "quiet", False), getattr(args, "verbose", 0)
    _output["quiet"] = bool(quiet)
    level = logging.ERROR if quiet else [logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)]
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_CliFormatter())
    logging.basicConfig(level=level, handlers=[handler], force=True)


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
    _add_picture_flags(p)
    p.add_argument("--trace", type=Path, help="write the control iterate history (CSV) here")
    p.add_argument("--accuracy", type=float, default=None, metavar="TOL",
                   help="choose the element (P1, P2) and mesh whose estimated error of the pose "
                   "at the targets is below TOL (length units) at the least solve time; says so "
                   "if no mesh level meets TOL")
    p.add_argument("--max-iterations", type=int, default=None, help="control iterations at most")
    p.add_argument("--max-time", type=float, default=None, help="control seconds at most")
    p.add_argument("--ipopt-print-level", type=int, default=None, metavar="N", choices=range(13),
                   help="IPOPT's print_level, 0-12 (bilevel method, ipopt equilibrium backend); "
                   "its output goes to stdout")
    p.set_defaults(func=cmd_solve)


def _add_picture_flags(p, vtk_what="the pose (.vtu) and, for control, its iterates (.pvd)"):
    p.add_argument("--tension-max", type=float, default=None, metavar="N",
                   help="top of the tension colour scale of the pose picture (N); fixed, pictures compare")
    p.add_argument("--vtk", type=Path, default=None, metavar="DIR",
                   help=f"write {vtk_what} for ParaView into DIR")


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
    from ..control import BilevelOptions, ControlOptions
    from ..solve.equilibrium import EquilibriumOptions
    from ..problem import load
    from ..solve.result_file import control_result_dict, result_dict

    t0 = time.perf_counter()
    if max_iterations is not None and max_iterations < 0:
        raise SceneError(f"--max-iterations: expected >= 0, got {max_iterations}")
    if max_time is not None and not max_time > 0:
        raise SceneError(f"--max-time: expected a number of seconds > 0, got {max_time}")
    log.info("%s: meshing and building the model", Path(problem).name)
    p = load(problem, accuracy=accuracy)
    log.debug("%s: %d nodes, %d elements, %d tendons, winches %s", p.source, p.mesh.n_nodes, p.mesh.n_elems,
              p.model.n_tendons, ", ".join(p.winch_names))
    contraction = _pairs(contraction_pairs)
    p.contraction_vector(contraction, what="--contraction")   # names and bounds checked first
    p.frozen_vector(freeze, what="--freeze")           # names checked before any solve
    if method is None:
        method = "reparam" if p.targets.n_targets else "forward"
    if method != "forward" and not p.targets.n_targets:
        raise SceneError(f"{p.source}: targets: --method {method} needs targets; the file has none")
    extra = {} if p.mesh_report is None else accuracy_record(p.mesh_report)
    # IPOPT's own output, when asked for: keys with the prefix for the equilibrium backend
    eq_ipopt = {} if ipopt_print_level is None else {"ipopt.print_level": ipopt_print_level}
    log.info("%s: %s", p.scene.name, "equilibrium" if method == "forward" else f"control ({method})")
    if method == "forward":
        t_solve = time.perf_counter()
        eq = p.equilibrium(contraction, options=EquilibriumOptions(backend=equilibrium, ipopt=eq_ipopt))
        t_end = time.perf_counter()
        doc = result_dict(p.model, p.targets, eq, method="forward", converged=eq.converged,
                          status=eq.status, total_s=t_end - t0, solve_s=t_end - t_solve,
                          iterations=eq.iterations, extra=extra)
        return p, eq, doc, ()
    quiet = EquilibriumOptions(backend=equilibrium, eigenvalue=False, ipopt=eq_ipopt)
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
        res = p.control(method, contraction, freeze, options=options)
    except SolverError as exc:
        # Control cannot start (the starting equilibrium is not certified):
        # the result still says where the robot is, honestly not converged.
        return _start_failed(p, contraction, method, equilibrium, exc, t0, extra)
    # an iterate history is a trace only if every iterate is a certified
    # equilibrium (the loop's and the reduced-space bilevel's are)
    history = res.history if all(h.equilibrium is not None for h in res.history) else ()
    for it in history:
        log.info("iterate %d  O = %.6g  c = %s", it.iteration, it.objective,
                 ", ".join(f"{n}={v:.4f}" for n, v in zip(p.winch_names, it.contraction)))
    doc = control_result_dict(res, total_s=time.perf_counter() - t0, extra=extra)
    return p, res.equilibrium, doc, history


def accuracy_record(report: dict) -> dict:
    """The result JSON's keys for a mesh chosen by ``--accuracy``: ``accuracy``
    (tolerance, estimated_error, element, nodes, whether the tolerance was
    met, whether the mesh is graded, how often it was refined uniformly,
    the summary) and ``mesh_accuracy``."""
    keys = ("tolerance", "estimated_error", "element", "nodes", "reached", "status", "max_area",
            "graded", "refinements", "summary")
    return {"accuracy": {k: report.get(k) for k in keys}, "mesh_accuracy": report}


def _check_tension_max(value) -> None:
    if value is not None and not (value > 0 and value != float("inf")):
        raise SceneError(f"--tension-max: expected a tension > 0 (N), got {value:g}")


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


def _check_solve_outputs(args) -> None:
    """Every output path of ``solve`` refused before the solve, not after it."""
    from ..base.files import check_output_path
    for option, path in (("--out", args.out), ("--plot", args.plot), ("--trace", args.trace)):
        if path is not None:
            check_output_path(path, option)
    if args.trace is not None and args.method == "forward":
        raise SceneError("--trace: only a control run has an iterate history (not --method forward)")


def _number(value, spec: str) -> str:
    """A summary number; JSON's null (a non-finite value) shows as n/a."""
    return "n/a" if value is None else format(value, spec)


def cmd_solve(args) -> int:
    from ..base.files import write_json_atomic
    _check_tension_max(args.tension_max)
    _check_solve_outputs(args)
    p, eq, doc, history = solve_problem(
        args.problem, args.contraction, args.freeze, args.method, args.equilibrium,
        args.max_iterations, args.max_time, args.accuracy, args.direction, args.ipopt_print_level)
    if "accuracy" in doc:
        acc = doc["accuracy"]
        if acc["reached"]:
            say(f"plush-opt: {acc['summary']}", err=True)
        else:                                   # not met: a warning, not a progress line
            log.warning("%s", acc["summary"])
    if args.trace and not history and doc["status"] != "start_not_certified":
        raise SceneError("--trace: only a control run whose iterates are certified equilibria "
                         "(the gradient loop, the reduced-space bilevel method) has an iterate history")
    if args.out:
        write_json_atomic(args.out, doc)
    if args.plot:
        from ..base.files import atomic_path, check_output_path
        from .plot import plot_pose
        _use_agg()
        check_output_path(args.plot, "--plot")     # still writable after the solve
        with atomic_path(args.plot) as tmp:
            plot_pose(tmp, p.model, eq.x, eq.contraction, p.targets if p.targets.n_targets else None,
                      tension_max=args.tension_max)
    if args.trace and history:
        write_trace(args.trace, p.model, p.targets, history)
    if args.vtk:
        from .export import write_control
        write_control(args.vtk, p.model, eq, history)
    say(summary_line(doc))
    if not doc["converged"]:
        print(f"plush-opt: not converged: {doc['status']}", file=sys.stderr)
        return EXIT_SOLVER
    return EXIT_OK


def target_summary(errors) -> str:
    """The targets' RMS error, for every summary line ('no targets' without any)."""
    if not len(errors):
        return "no targets"
    rms = (sum(e * e for e in errors) / len(errors)) ** 0.5
    return f"targets RMS error {rms:.3g} {LENGTH_UNIT} (worst {max(errors):.3g})"


def summary_line(doc: dict) -> str:
    """One line for a result document: verdict, contractions, how far from the targets."""
    cs = ", ".join(f"{n}={v:.4f}" for n, v in doc["contractions"].items())
    parts = [f"{doc['problem']}: {doc['method']}: {doc['status']}", cs, target_summary(doc["target_error"])]
    if doc["method"] != "forward":
        parts.append(f"objective {_number(doc['objective'], '.6g')}")
    elif doc["target_error"]:   # a forward solve's O is 0 by the spec; the targets' is apart
        parts.append(f"targets objective {_number(doc['targets_objective'], '.6g')}")
    parts += [f"residual {_number(doc['residual_norm'], '.3g')}", f"{doc['timing']['total_s']:.3f} s"]
    return "; ".join(parts)


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
                       "script on the board emulator. Works from any folder: the shipped files "
                       "come with the package.")
    p.add_argument("--problem", type=Path, default=None, help="default: the shipped problems/gripper.yaml")
    p.add_argument("--script", type=Path, default=None, help="default: the shipped examples/gripper_run.yaml")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--no-board", action="store_true", help="skip playing the run on the emulator")
    p.add_argument("--tension-max", type=float, default=None, metavar="N",
                   help="top of the tension colour scale of the pose picture (N)")
    p.set_defaults(func=cmd_demo)


def _add_examples(sub):
    p = sub.add_parser("examples", help="copy the shipped problems, run scripts and board files into a folder",
                       description="Copy problems/, examples/ and hw/boards/ into DIR, laid out as in the "
                       "source tree, so that the run scripts find their problem and board files.")
    p.add_argument("dir", type=Path, metavar="DIR", help="destination folder (created; must not hold them yet)")
    p.set_defaults(func=cmd_examples)


def cmd_examples(args) -> int:
    from ..base.data_files import copy_examples
    for folder in copy_examples(args.dir):
        say(f"examples: wrote {folder}")
    say(f"examples: try `plush-opt solve {args.dir / 'problems' / 'gripper.yaml'}` or "
        f"`plush-opt run {args.dir / 'examples' / 'gripper_run.yaml'} --emulator`")
    return EXIT_OK


def default_problem() -> Path:
    from ..base.data_files import data_file
    return data_file("problems", "gripper.yaml")


def cmd_demo(args) -> int:
    from .plot import plot_pose, plot_trace
    from ..base.data_files import data_file
    from ..base.files import check_output_folder, write_json_atomic
    _check_tension_max(args.tension_max)
    _use_agg()
    problem = args.problem or default_problem()
    out = check_output_folder(args.out, "--out")
    out.mkdir(parents=True, exist_ok=True)
    say(f"demo: solving {problem.name} (control to its targets)")
    p, eq, doc, history = solve_problem(problem, method="reparam")
    write_json_atomic(out / "result.json", doc)
    plot_pose(out / "pose.png", p.model, eq.x, eq.contraction, p.targets, tension_max=args.tension_max)
    plot_trace(out / "trace.png", history, title=f"{p.scene.name}: control iterates")
    write_trace(out / "trace.csv", p.model, p.targets, history)
    say(f"demo: {doc['status']}; {len(history) - 1} iterates, "
        f"{doc['control']['equilibrium_solves']} equilibrium solves, {doc['timing']['total_s']:.2f} s")
    say("demo: contractions " + ", ".join(f"{n} = {v:.3f} {LENGTH_UNIT}" for n, v in doc["contractions"].items()))
    say(f"demo: {target_summary(doc['target_error'])}; "
        f"min Hessian eigenvalue {doc['min_hessian_eigenvalue']:.3g}")
    say(f"demo: wrote {out / 'result.json'}, {out / 'pose.png'}, {out / 'trace.png'}, {out / 'trace.csv'}")
    if not args.no_board:
        _demo_run(args.script or data_file("examples", "gripper_run.yaml"), out)
    return EXIT_OK if doc["converged"] else EXIT_SOLVER


def _demo_run(script: Path, out: Path) -> None:
    """Play a run script on the board emulator; write its log and a plot."""
    import json
    from types import SimpleNamespace

    from .plot import plot_run_log
    say(f"demo: playing {script.name} on the board emulator")
    log_path = out / "run.jsonl"
    args = SimpleNamespace(script=script, port=None, emulator=True, dry_run=False, log=log_path,
                           quiet=_output["quiet"], plot=None, vtk=None, progress=False)
    code = cmd_run(args)
    if code != EXIT_OK:
        raise SolverError(f"the demo run ended with status {code}")
    rows = [json.loads(line) for line in log_path.read_text().splitlines()]
    plot_run_log(out / "run.png", rows, title=f"{script.stem}: commanded and measured contractions")
    end = rows[-1]
    say(f"demo: run {end['status']}: {end['steps_done']} steps, {end['commands']} commands; "
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
    p.add_argument("--plot", type=Path, default=None, metavar="PNG",
                   help="write a picture of the commanded and measured contractions here")
    p.add_argument("--vtk", type=Path, default=None, metavar="DIR",
                   help="write the run (the pose at every command) as a ParaView time series DIR/run.pvd")
    p.set_defaults(func=cmd_run)


def cmd_run(args) -> int:
    from .planner import ControlPlanner
    from .runs import cli_run
    quiet, verbose = getattr(args, "quiet", False), getattr(args, "verbose", 0)
    if not hasattr(args, "progress"):
        # A terminal gets one updating line; a log or -v gets a line per step (and arrival).
        args.progress = sys.stderr.isatty() and not quiet and not verbose
        if not args.progress and not quiet:
            logging.getLogger("plush_opt.apps.runs").setLevel(logging.INFO)
    if (args.plot or args.vtk) and args.log is None:
        from ..io.run_script import load_run_script
        from .runs import _default_log_path
        args.log = _default_log_path(load_run_script(args.script))
    code = cli_run(args, ControlPlanner)
    if code == EXIT_OK and args.plot:
        _run_plot(args.plot, args.log, args.script)
    if code == EXIT_OK and args.vtk:
        say(f"run: writing the poses of the run to {args.vtk}", err=True)
        from .export import export_run
        export_run(args.vtk, args.log)
    return code


def _run_plot(png: Path, log_path: Path, script: Path) -> None:
    import json

    from .plot import plot_run_log
    _use_agg()
    rows = [json.loads(line) for line in Path(log_path).read_text().splitlines()]
    plot_run_log(png, rows, title=f"{Path(script).stem}: commanded and measured contractions")


# --------------------------------------------------------------------------
# export
# --------------------------------------------------------------------------

def _add_export(sub):
    p = sub.add_parser("export", help="write a run log or a problem's pose for ParaView (meshio)",
                       description="A run log (JSON lines of plush-opt run) becomes DIR/run.pvd, the "
                       "pose at every command; a problem file becomes DIR/pose.vtu, the equilibrium at "
                       "its contractions (and -c) or the pose --result recorded. With friction at via points "
                       "a run is replayed command by command, a result keeps its segment rest lengths, "
                       "a problem alone is driven from the start state (see docs/model.md).")
    p.add_argument("source", type=Path, help="a run log (.jsonl) or a problem file (.yaml)")
    p.add_argument("--out", "-o", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--contraction", "-c", action="append", type=_contraction_arg, default=[],
                   metavar="NAME=VALUE", help="contraction of a winch (problem files); repeatable")
    p.add_argument("--result", "-r", type=Path, metavar="FILE", help="a result file of this problem: its pose")
    p.set_defaults(func=cmd_export)


def cmd_export(args) -> int:
    from .export import export_result, export_run, write_pose
    if args.source.suffix == ".json":
        raise SceneError(f"{args.source}: a result file: export PROBLEM.yaml --result {args.source} --out DIR")
    if (args.contraction or args.result) and (args.source.suffix == ".jsonl" or args.contraction and args.result):
        raise SceneError("--contraction, --result: one of them, with a problem file (a run log has its own poses)")
    if args.source.suffix == ".jsonl":
        say(str(export_run(args.out, args.source)))
        return EXIT_OK
    if args.result is not None:
        path, note, converged = export_result(args.out, args.source, args.result)
        say(f"export: {note}", err=True)
    else:
        p, eq, doc, _ = solve_problem(args.source, args.contraction, method="forward")
        if p.plant.history_note:       # the pose depends on the path: which history it assumed
            say(f"export: {p.source}: {p.plant.history_note}; --result FILE exports a state a solve recorded", err=True)
        path, converged = write_pose(args.out / "pose.vtu", p.model, eq.x, eq.contraction, eq), doc["converged"]
    say(str(path))
    return EXIT_OK if converged else EXIT_SOLVER


# --------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    parser = _Parser(prog="plush-opt", description="Optimisation-centric control of plush robots.")
    parser.add_argument("--version", action="version", version=f"plush-opt {__version__}")
    _add_verbosity(parser, default=True)
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    _add_solve(sub)
    _add_run(sub)
    _add_demo(sub)
    _add_examples(sub)
    _add_export(sub)
    from .bench import add_bench_parser
    add_bench_parser(sub)
    from .sweep import add_sweep_parser
    add_sweep_parser(sub, _contraction_arg)
    from .gui import add_gui_parser
    add_gui_parser(sub)
    from .compare import add_compare_parser
    add_compare_parser(sub)
    from .calibrate import add_calibrate_parser
    add_calibrate_parser(sub)
    for command in sub.choices.values():   # -q/-v also after the command: `plush-opt solve -v ...`
        _add_verbosity(command, default=False)
    return parser


def _add_verbosity(parser, default: bool) -> None:
    """-q/-v/-vv; a subcommand's copy leaves the top level's value alone unless given."""
    keep = {} if default else {"default": argparse.SUPPRESS}
    group = parser.add_mutually_exclusive_group()
    group.add_argument("-v", "--verbose", action="count", help="say more: progress and solver steps "
                       "(-vv: debug)", **({"default": 0} if default else keep))
    group.add_argument("-q", "--quiet", action="store_true", help="print errors only",
                       **({"default": False} if default else keep))


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _configure_output(args)
    previous = handle_signals()
    try:
        _check_output_folders(args)
        return args.func(args)
    except KeyboardInterrupt as exc:
        name, code = interrupt_status(exc)
        print(f"plush-opt: interrupted ({name})", file=sys.stderr)
        return code
    except Exception as exc:  # noqa: BLE001 - every error ends as one line
        if args.debug:
            raise
        message, code = _describe_error(exc)
        print(f"plush-opt: {one_line(message)}", file=sys.stderr)
        return code
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


#: Output folders checked before any work: command -> option of a folder.
OUTPUT_FOLDERS = {"bench": "out", "compare": "out"}


def _check_output_folders(args) -> None:
    from ..base.files import check_output_folder
    attr = OUTPUT_FOLDERS.get(args.command)
    if attr is not None and getattr(args, attr, None) is not None:
        check_output_folder(getattr(args, attr), f"--{attr}")


def _describe_error(exc: Exception) -> tuple[str, int]:
    """One line and an exit status for an error that ends a command."""
    if isinstance(exc, (SceneError, argparse.ArgumentTypeError)):
        return f"error: {exc}", EXIT_INPUT
    if isinstance(exc, HardwareError):
        return f"hardware error: {exc}", EXIT_HARDWARE
    if isinstance(exc, (SolverError, PlushError)):
        return f"solver error: {exc}", EXIT_SOLVER
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        return f"error: {where}{exc.strerror or exc}", EXIT_INPUT
    return (f"internal error: {type(exc).__name__}: {exc} (rerun with --debug for the traceback, "
            "and please report it)", EXIT_INTERNAL)


if __name__ == "__main__":
    sys.exit(main())
