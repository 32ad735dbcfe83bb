"""``plush-opt run``: play a run script on the winch board (or its
emulator), with an optional picture and ParaView series of the run. The
run itself is :func:`plush_opt.apps.runs.run_script`."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from ..base.errors import interrupt_status
from ..io.run_script import load_run_script
from .console import EXIT_OK, say, use_agg


def add_run_parser(sub) -> None:
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
    quiet, verbose = getattr(args, "quiet", False), getattr(args, "verbose", 0)
    if not hasattr(args, "progress"):
        # A terminal gets one updating line; a log or -v gets a line per step (and arrival).
        args.progress = sys.stderr.isatty() and not quiet and not verbose
        if not args.progress and not quiet:
            logging.getLogger("plush_opt.apps.runs").setLevel(logging.INFO)
    if (args.plot or args.vtk) and args.log is None:
        from .runs import default_log_path
        args.log = default_log_path(load_run_script(args.script))
    code = cli_run(args, ControlPlanner)
    if code == EXIT_OK and args.plot:
        _run_plot(args.plot, args.log, args.script)
    if code == EXIT_OK and args.vtk:
        say(f"run: writing the poses of the run to {args.vtk}", err=True)
        from .export import export_run
        export_run(args.vtk, args.log)
    return code


def _run_plot(png: Path, log_path: Path, script: Path) -> None:
    from .plot import plot_run_log
    use_agg()
    from ..io.problem_file import file_units
    from ..io.run_script import load_run_script
    rows = [json.loads(line) for line in Path(log_path).read_text().splitlines()]
    dry = bool(rows) and rows[0].get("kind") == "start" and rows[0].get("dry_run")
    what = "planned contractions (dry run: a plan, nothing measured)" if dry else "commanded and measured contractions"
    plot_run_log(png, rows, title=f"{Path(script).stem}: {what}",
                 length=file_units(load_run_script(script).problem).length)


def add_run_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the arguments of ``plush-opt run`` to ``parser``."""
    parser.add_argument("script", type=Path, help="run script (YAML, format plush-opt-run/1)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--port", help="serial port of the winch board (default: port.device of the board file)")
    where.add_argument("--emulator", action="store_true",
                       help="run against the board emulator (compiled on first use when `make -C hw` has not built it)")
    where.add_argument("--simavr", action="store_true",
                       help="run against the firmware on a simulated AVR (simavr; see docs/hardware.md)")
    parser.add_argument("--dry-run", action="store_true",
                        help="plan and log every step, open no port (overrides the board options)")
    parser.add_argument("--log", type=Path, metavar="FILE",
                        help="JSON-lines log of the run (default: out/runs/SCRIPT-TIME.jsonl)")
    return parser


def cli_run(args: argparse.Namespace, planner_factory) -> int:
    """``plush-opt run``: ``planner_factory(problem_path) -> Planner``.

    Returns the exit status: 0 when the run completed, 130 when interrupted
    (the board has been stopped). Other errors propagate as
    :class:`~plush_opt.base.errors.PlushError`.
    """
    from ..base.files import check_output_path
    from .runs import default_log_path, run_script
    script = load_run_script(args.script)
    log_path = args.log if args.log is not None else default_log_path(script)
    check_output_path(log_path, "--log", stream_ok=True)      # before the planner's first (slow) solve
    planner = planner_factory(script.problem)
    simulator = "emulator" if args.emulator else ("simavr" if getattr(args, "simavr", False) else None)
    try:
        result = run_script(script, port=args.port, simulator=simulator, dry_run=args.dry_run, log_path=log_path,
                            planner=planner, progress=getattr(args, "progress", None))
    except KeyboardInterrupt as e:
        name, code = interrupt_status(e)
        sys.stderr.write(f"\ninterrupted ({name}): board stopped; log {log_path}\n")
        return code
    where = "dry run" if result.dry_run else (simulator or "board")
    from ..io.problem_file import file_units
    errors = (f", pose steps' RMS target error at most {max(result.pose_errors):.3g} "
              f"{file_units(script.problem).length}"
              if result.pose_errors else "")
    far = f", {len(result.far_poses)} far from their targets" if result.far_poses else ""
    if not getattr(args, "quiet", False) or result.far_poses:
        sys.stderr.write(f"run {script.path.name} completed on {where}: {result.steps} steps, "
                         f"{result.commands} commands{errors}{far}, log {result.log_path}\n")
    return 0
