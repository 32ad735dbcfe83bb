"""Pieces of the command line's parser that several commands share: the
parser class (bad options exit with status 2), NAME=VALUE contractions,
-q/-v, the picture flags."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..base.errors import SceneError
from .console import EXIT_INPUT


class CliParser(argparse.ArgumentParser):
    """An argument parser whose usage errors exit with ``EXIT_INPUT``."""

    def error(self, message):
        self.exit(EXIT_INPUT, f"{self.prog}: error: {message}\n")


def contraction_arg(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` as (name, finite float), for ``type=`` of an option."""
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


def pairs(given, what: str = "--contraction") -> dict[str, float]:
    """NAME=VALUE pairs as a dict; a winch named twice is an error, not the last one winning."""
    out: dict[str, float] = {}
    for name, value in given:
        if name in out:
            raise SceneError(f"{what} {name}: given twice ({out[name]:g} and {value:g})")
        out[name] = value
    return out


def add_verbosity(parser, default: bool) -> None:
    """-q/-v/-vv; a subcommand's copy leaves the top level's value alone unless given."""
    keep = {} if default else {"default": argparse.SUPPRESS}
    group = parser.add_mutually_exclusive_group()
    group.add_argument("-v", "--verbose", action="count", help="say more: progress and solver steps "
                       "(-vv: debug)", **({"default": 0} if default else keep))
    group.add_argument("-q", "--quiet", action="store_true", help="print errors only",
                       **({"default": False} if default else keep))


def add_picture_flags(p, vtk_what="the pose (.vtu) and, for control, its iterates (.pvd)"):
    """--tension-max and --vtk of a command that draws poses."""
    p.add_argument("--tension-max", type=float, default=None, metavar="N",
                   help="top of the tension colour scale of the pose picture (N); fixed, pictures compare")
    p.add_argument("--vtk", type=Path, default=None, metavar="DIR",
                   help=f"write {vtk_what} for ParaView into DIR")


def check_tension_max(value) -> None:
    """--tension-max: a finite tension > 0 (N), or not given."""
    if value is not None and not (value > 0 and value != float("inf")):
        raise SceneError(f"--tension-max: expected a tension > 0 (N), got {value:g}")
