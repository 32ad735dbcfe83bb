"""Where the shipped files are: problems, run scripts, board files and the
board emulator's source.

In a source checkout they are the tree's own ``problems/``, ``examples/``
and ``hw/``; an installed wheel carries copies of them in
``plush_opt/data/`` (setup.py maps them in), laid out the same way, so
that the run scripts' relative paths (``../problems/gripper.yaml``) hold
in both and in a folder that ``plush-opt examples`` copied them to.
"""

from __future__ import annotations

import errno
import shutil
from pathlib import Path

from plush_opt.base.errors import PlushError

_PACKAGE = Path(__file__).resolve().parents[1]     # plush_opt/

EXAMPLE_FOLDERS = ("problems", "examples", "hw/boards")
"""What ``plush-opt examples`` copies out, relative to :func:`data_root`."""

EMULATOR_SOURCES = ("hw/emulator/main.cpp", "hw/firmware/plush_winch/protocol_core.cpp",
                    "hw/firmware/plush_winch/protocol_core.h")
"""The board emulator's sources, relative to :func:`data_root` (hw/Makefile builds the same)."""


def data_root() -> Path:
    """The folder holding ``problems/``, ``examples/`` and ``hw/``.

    The installed package's ``plush_opt/data`` when it is there, else the
    source tree around the package. Raises :class:`PlushError` when neither is.
    """
    for root in (_PACKAGE / "data", _PACKAGE.parent):
        if (root / "problems").is_dir() and (root / "hw" / "boards").is_dir():
            return root
    raise PlushError(f"the shipped problems and board files are missing: neither {_PACKAGE / 'data'} "
                     f"nor the source tree {_PACKAGE.parent} has them; reinstall plush_opt")


def data_file(*parts: str) -> Path:
    """A shipped file, e.g. ``data_file("problems", "gripper.yaml")``."""
    return data_root().joinpath(*parts)


def copy_examples(dest) -> list[Path]:
    """Copy the shipped problems, run scripts and board files into ``dest``
    (which must not hold them yet: FileExistsError); returns the folders written.

    The layout is the source tree's, so the copies refer to each other as
    the originals do.
    """
    root, dest = data_root(), Path(dest)
    clashes = [dest / f for f in EXAMPLE_FOLDERS if (dest / f).exists()]
    if clashes:
        raise FileExistsError(errno.EEXIST, "exists already; give an empty or new folder", str(clashes[0]))
    written = []
    for folder in EXAMPLE_FOLDERS:
        target = dest / folder
        target.parent.mkdir(parents=True, exist_ok=True)
        # No build products (hw/emulator/build) and no caches travel.
        shutil.copytree(root / folder, target, ignore=shutil.ignore_patterns("build", "__pycache__", "*.pyc"))
        written.append(target)
    return written
