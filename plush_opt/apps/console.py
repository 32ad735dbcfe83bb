"""What the command line prints, and the exit status it ends with.

Summary and progress lines go through :func:`say` (silenced by ``-q``);
progress and solver steps are log records formatted by
:func:`configure_output`; an error that ends a command becomes one line and
an exit status by :func:`describe_error`.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

from ..base.errors import HardwareError, PlushError, SceneError, SettingError, SolverError
from ..io.units import units_of

EXIT_OK, EXIT_INPUT, EXIT_SOLVER, EXIT_HARDWARE, EXIT_INTERNAL, EXIT_INTERRUPT = 0, 2, 3, 4, 70, 130

_output = {"quiet": False}   # set once by configure_output: -q silences summaries and progress


def say(text: str = "", err: bool = False) -> None:
    """A summary or progress line, unless -q."""
    if not _output["quiet"]:
        print(text, file=sys.stderr if err else sys.stdout, flush=True)


def is_quiet() -> bool:
    """Whether -q was given (summaries and progress silenced)."""
    return _output["quiet"]


class _CliFormatter(logging.Formatter):
    """Progress (INFO) as plain lines, warnings and errors named, debug with its source."""

    def format(self, record):
        msg = record.getMessage()
        if record.levelno >= logging.WARNING:
            return f"plush-opt: {record.levelname.lower()}: {msg}"
        if record.levelno <= logging.DEBUG:
            return f"debug {record.name}: {msg}"
        return msg


def configure_output(args) -> None:
    """-q: errors only; default: warnings; -v: progress and solver steps; -vv: debug."""
    quiet, verbose = getattr(args, "quiet", False), getattr(args, "verbose", 0)
    _output["quiet"] = bool(quiet)
    level = logging.ERROR if quiet else [logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)]
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_CliFormatter())
    logging.basicConfig(level=level, handlers=[handler], force=True)


def describe_error(exc: Exception) -> tuple[str, int]:
    """One line and an exit status for an error that ends a command."""
    if isinstance(exc, (SceneError, SettingError, argparse.ArgumentTypeError)):
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


def _number(value, spec: str) -> str:
    """A summary number; JSON's null (a non-finite value) shows as n/a."""
    return "n/a" if value is None else format(value, spec)


def target_summary(errors, length: str = "mm") -> str:
    """The targets' RMS error in ``length`` units (the scene's
    ``units.length``), for every summary line ('no targets' without any)."""
    if not len(errors):
        return "no targets"
    rms = (sum(e * e for e in errors) / len(errors)) ** 0.5
    return f"targets RMS error {rms:.3g} {length} (worst {max(errors):.3g})"


def summary_line(doc: dict) -> str:
    """One line for a result document: verdict, contractions, how far from the
    targets, in the document's ``units`` (mm and N without them)."""
    units = units_of(doc)
    cs = ", ".join(f"{n}={v:.4f}" for n, v in doc["contractions"].items())
    parts = [f"{doc['problem']}: {doc['method']}: {doc['status']}", f"{cs} {units.length}",
             target_summary(doc["target_error"], units.length)]
    if doc["method"] != "forward":
        parts.append(f"objective {_number(doc['objective'], '.6g')}")
    elif doc["target_error"]:   # a forward solve's O is 0 by the spec; the targets' is apart
        parts.append(f"targets objective {_number(doc['targets_objective'], '.6g')}")
    parts += [f"residual {_number(doc['residual_norm'], '.3g')} {units.force}", f"{doc['timing']['total_s']:.3f} s"]
    return "; ".join(parts)


def use_agg() -> None:
    """Pictures without a display: matplotlib's file-only backend."""
    import matplotlib
    if not os.environ.get("DISPLAY") and matplotlib.get_backend().lower() != "agg":
        matplotlib.use("Agg")
