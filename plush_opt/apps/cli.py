"""The ``plush-opt`` command line: the parser of every command and
:func:`main`, which runs one and turns what ends it into an exit status.

Every error a user can cause ends as one line on stderr and a non-zero
exit status, never a traceback (``--debug`` shows it):

    0  success              2  bad input (file, option)
    3  solver did not converge (the result is still written, honestly)
    4  hardware error       70  internal error (a bug)      130  interrupted (Ctrl-C)
    143, 129  ended by SIGTERM, SIGHUP (handled like Ctrl-C: the board stopped, the log ended)

The commands live beside it: ``solve`` (solve_command.py), ``run``
(run_command.py), ``demo`` and ``examples`` (demo.py), ``export``
(export_command.py), ``bench``, ``sweep``, ``gui``, ``compare`` and
``calibrate`` and ``study`` in their own modules; what they print and the exit codes in
console.py, the shared options in arguments.py.
"""

from __future__ import annotations

import argparse
import signal
import sys

from ..base.errors import interrupt_status, one_line
from .arguments import CliParser, add_verbosity, contraction_arg
from .console import configure_output, describe_error
from .signals import handle_signals

#: Output folders checked before any work: command -> option of a folder.
OUTPUT_FOLDERS = {"bench": "out", "compare": "out", "study": "out"}


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    from .bench import add_bench_parser
    from .calibrate import add_calibrate_parser
    from .compare import add_compare_parser
    from .demo import add_demo_parser, add_examples_parser
    from .export_command import add_export_parser
    from .gui import add_gui_parser
    from .run_command import add_run_parser
    from .solve_command import add_solve_parser
    from .study import add_study_parser
    from .sweep import add_sweep_parser
    parser = CliParser(prog="plush-opt", description="Optimisation-centric control of plush robots.")
    parser.add_argument("--version", action="version", version=f"plush-opt {__version__}")
    add_verbosity(parser, default=True)
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=CliParser)
    sub.required = True
    add_solve_parser(sub)
    add_run_parser(sub)
    add_demo_parser(sub)
    add_examples_parser(sub)
    add_export_parser(sub)
    add_bench_parser(sub)
    add_sweep_parser(sub, contraction_arg)
    add_gui_parser(sub)
    add_compare_parser(sub)
    add_calibrate_parser(sub)
    add_study_parser(sub)
    for command in sub.choices.values():   # -q/-v also after the command: `plush-opt solve -v ...`
        add_verbosity(command, default=False)
    return parser


def overview(parser: argparse.ArgumentParser) -> str:
    """What a bare ``plush-opt`` prints: each command with its one-line
    help, and where to start reading."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    commands = [(a.dest, a.help or "") for a in sub._choices_actions]
    width = max(len(name) for name, _ in commands)
    lines = [f"plush-opt: {parser.description}", "", "usage: plush-opt COMMAND [options]   "
             "(plush-opt COMMAND --help for its options)", "", "commands:"]
    lines += [f"  {name:<{width}}  {text}" for name, text in commands]
    lines += ["", "New here? docs/quickstart.md goes from a blank problem file to a solved pose and a run "
              "on the emulator;", "`plush-opt demo` shows the shipped examples."]
    return "\n".join(lines)


def main(argv=None) -> int:
    previous = handle_signals()      # first: a signal during start-up (imports, parsing) ends quietly too
    try:
        try:
            return _command(argv)
        except KeyboardInterrupt as exc:     # one that arrived after the command's own handling
            return _interrupted(exc)
    finally:
        _restore_handlers(previous)


def _command(argv) -> int:
    args = None
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        if not argv:                 # a bare `plush-opt` asked what there is: not a usage error
            print(overview(build_parser()))
            return 0
        args = build_parser().parse_args(argv)
        configure_output(args)
        _check_output_folders(args)
        return args.func(args)
    except KeyboardInterrupt as exc:
        return _interrupted(exc)
    except Exception as exc:  # noqa: BLE001 - every error ends as one line
        interrupt = _interrupt_behind(exc)
        if interrupt is not None:    # e.g. an import cut short inside a C module's start-up
            return _interrupted(interrupt)
        if args is None or args.debug:
            raise
        message, code = describe_error(exc)
        print(f"plush-opt: {one_line(message)}", file=sys.stderr)
        return code


def _interrupted(exc: KeyboardInterrupt) -> int:
    name, code = interrupt_status(exc)
    print(f"plush-opt: interrupted ({name})", file=sys.stderr)
    return code


def _restore_handlers(previous: dict) -> None:
    """The signal handlers from before :func:`main`. A signal that arrives
    while they are put back (the command is done) changes nothing: its
    exception is dropped and the restore goes on."""
    for signum, handler in previous.items():
        while True:
            try:
                signal.signal(signum, handler)
                break
            except KeyboardInterrupt:
                continue


def _interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C (or TERM) an exception was raised from, if any: a C
    module interrupted while it starts up re-raises it as an ImportError."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _check_output_folders(args) -> None:
    from ..base.files import check_output_folder
    attr = OUTPUT_FOLDERS.get(args.command)
    if attr is not None and getattr(args, attr, None) is not None:
        check_output_folder(getattr(args, attr), f"--{attr}")


if __name__ == "__main__":
    sys.exit(main())
