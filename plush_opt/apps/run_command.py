"""``plush-opt run``: play a run script on the winch board (or its
emulator), with an optional picture and ParaView series of the run. The
run itself is :func:`plush_opt.apps.runs.cli_run`."""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

from .console import EXIT_OK, say, use_agg


def add_run_parser(sub) -> None:
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
    from .plot import plot_run_log
    use_agg()
    from ..io.problem_file import file_units
    from ..io.run_script import load_run_script
    rows = [json.loads(line) for line in Path(log_path).read_text().splitlines()]
    plot_run_log(png, rows, title=f"{Path(script).stem}: commanded and measured contractions",
                 length=file_units(load_run_script(script).problem).length)
