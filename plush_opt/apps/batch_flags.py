"""The options of a command that runs many solves at once (``--jobs``,
``--dask``) and the progress it shows (plush_opt.batch)."""

from __future__ import annotations

import argparse


def jobs_arg(text: str) -> int:
    """``--jobs N``: an integer >= 1, for ``type=``."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of processes >= 1, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a number of processes >= 1, got {n}")
    return n


def add_batch_flags(p, default_one: bool = False) -> None:
    """--jobs and --dask (``default_one``: --jobs defaults to 1, not the cores)."""
    default = "1" if default_one else "the number of cores"
    p.add_argument("--jobs", "-j", type=jobs_arg, default=1 if default_one else None, metavar="N",
                   help=f"worker processes on this machine (default {default}; 1: one after the other "
                   "in this process)")
    p.add_argument("--dask", default=None, metavar="ADDRESS",
                   help="run on a Dask cluster instead: its scheduler's address (tcp://host:8786); "
                   "see docs/study.md")


def batch_kwargs(args) -> dict:
    """``jobs`` and ``scheduler`` for :func:`~plush_opt.batch.run_batch` from the flags."""
    return {"jobs": args.jobs, "scheduler": args.dask}


def progress_for(args, label: str, describe=None):
    """A :class:`~plush_opt.batch.progress.Progress` on stderr (a bar on a
    terminal, a line per item otherwise), or None with -q."""
    if getattr(args, "quiet", False):
        return None
    from ..batch.progress import Progress
    return Progress(label, describe)
