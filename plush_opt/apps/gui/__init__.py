"""Interactive posing: the three interaction modes, live, with the robot attached.

A matplotlib window shows the simulated robot, always at a statically
stable pose, and offers the three interaction modes of the plush-robot
paper (section IV.A):

1. **Set a contraction**: one slider per winch; moving it re-solves the
   forward pose at once (Newton, warm-started from the pose on screen).
2. **Drag to pose**: press on the body, drag, release: the body point
   under the cursor gets a target at the release position. The control
   loop runs in the background of the event loop: a timer takes *one*
   anytime iterate per tick (never the whole solve), so the window stays
   responsive and the mesh follows iterate by iterate.
3. **Freeze a winch**: a toggle per winch; a frozen winch keeps its
   contraction bit for bit while the loop moves the others.

With a board attached, every pose shown is sent to it at a bounded rate.

The parts: :mod:`.session` (the state and its operations, no matplotlib),
:mod:`.pacing` (the board), :mod:`.view` and :mod:`.figure` (the window),
:mod:`.scripted` (synthesised sessions for the screenshot, timings and
tests). This module is the command line's ``gui``; it is imported to build
the parser, so numpy, matplotlib and the solvers are imported where they
are used: ``plush-opt --help`` stays quick. See docs/gui.md.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from .options import GuiOptions

__all__ = ["GuiOptions", "add_gui_parser", "cmd_gui", "run_gui"]


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def add_gui_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``gui`` to the command line's subparsers (``func=cmd_gui``)."""
    p = subparsers.add_parser(
        "gui", help="pose the robot interactively (sliders, drag to pose, freeze), live on the board",
        description="A window showing the robot at its stable pose: winch sliders re-solve the "
        "pose; dragging the body sets targets that the control loop reaches iterate by iterate; "
        "freeze toggles hold winches. With --port or --emulator every pose shown goes to the board.")
    p.add_argument("problem", type=Path, help="problem file (YAML, format plush-opt/1)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--port", help="serial port of the winch board: every pose shown is sent to it")
    where.add_argument("--emulator", action="store_true",
                       help="attach the board emulator (compiled on first use when `make -C hw` has not built it)")
    p.add_argument("--board", type=Path, metavar="FILE",
                   help="board calibration (default: the shipped hw/boards/<problem name>.yaml)")
    p.add_argument("--out", type=Path, metavar="FILE.json",
                   help="where `s` saves the result (the PNG goes next to it); "
                        "default out/gui-<timestamp>.json")
    p.add_argument("--send-rate", type=_positive, default=GuiOptions.send_rate, metavar="HZ",
                   help=f"board commands per second at most (default {GuiOptions.send_rate:g})")
    p.add_argument("--screenshot", type=Path, metavar="FILE.png",
                   help="no window: run a scripted drag headless, save the window as this PNG, "
                        "print the callback times")
    p.add_argument("--timing", action="store_true",
                   help="no window: run a longer scripted session headless and print the callback times")
    p.set_defaults(func=cmd_gui)
    return p


def cmd_gui(args: argparse.Namespace) -> int:
    """``plush-opt gui PROBLEM [--port PORT | --emulator]``."""
    options = GuiOptions(save_path=args.out, send_rate=args.send_rate)
    return run_gui(args.problem, port=args.port, emulator=args.emulator, board_file=args.board,
                   options=options, screenshot=args.screenshot, timing=args.timing)


def _default_board_file(scene_name: str) -> Path:
    from ...base.data_files import data_file
    return data_file("hw", "boards", f"{scene_name}.yaml")


def _open_board(problem, port, emulator: bool, board_file):
    """The board link for ``--port``/``--emulator``, or None for neither."""
    if port is None and not emulator:
        return None
    from ...board import open_board
    from ...base.errors import SceneError
    path = Path(board_file) if board_file is not None else _default_board_file(problem.scene.name)
    if not path.is_file():
        raise SceneError(f"--board: no calibration file {path}; give one with --board FILE")
    model = problem.model
    bounds = {n: (float(lo), float(hi)) for n, lo, hi in zip(model.winch_names, model.lower, model.upper)}
    board = open_board(path, port=port, simulator="emulator" if emulator else None, bounds=bounds)
    missing = [n for n in model.winch_names if n not in board.winch_names]
    if missing:
        board.close()
        raise SceneError(f"{path}: no winch {missing[0]!r} (problem winches: "
                         f"{', '.join(model.winch_names)})")
    return board


def no_window_reason(backend: str) -> str:
    """Why matplotlib's ``backend`` cannot open a window, and what to do:
    a Python without tkinter (matplotlib then falls back to Agg without a
    word) is not a missing display."""
    try:
        import tkinter  # noqa: F401 - only whether it is there
    except ImportError:
        return (f"tkinter is not installed: install python3-tk (e.g. `sudo apt install python3-tk`), "
                f"or set MPLBACKEND=QtAgg with PyQt installed; matplotlib fell back to {backend!r}, "
                "which cannot open a window (--screenshot FILE.png works without one)")
    if sys.platform in ("darwin", "win32") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        why = "no display?"
    else:
        why = "no display: DISPLAY is not set (run it in a desktop session, or over ssh -X)"
    return (f"matplotlib backend {backend!r} cannot open a window ({why}); set MPLBACKEND to an "
            "interactive one (e.g. TkAgg, QtAgg), or use --screenshot FILE.png")


def run_gui(problem, *, port=None, emulator=False, board_file=None, options: GuiOptions | None = None,
            screenshot=None, timing=False) -> int:
    """Load ``problem``, attach the board (``port`` or the emulator), run the
    window (or, headless, a scripted session for ``screenshot``/``timing``).
    The board is stopped and closed however this ends. Returns 0; errors
    are raised (:class:`~plush_opt.base.errors.SceneError` for bad options or
    no way to open a window)."""
    from ...base.errors import SceneError
    headless = screenshot is not None or timing
    if headless and port is not None:
        raise SceneError("--screenshot/--timing drive a scripted session: not on a real board "
                         "(use --emulator, or no board)")
    import matplotlib
    if headless:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .view import NON_INTERACTIVE
    if not headless and plt.get_backend().lower() in NON_INTERACTIVE:
        raise SceneError(no_window_reason(plt.get_backend()))
    from ...problem import load
    from .session import PosingSession
    from .view import PosingWindow

    problem = load(problem)
    board = _open_board(problem, port, emulator, board_file)
    try:
        window = PosingWindow(PosingSession(problem, board, options))
        if headless:
            _scripted(window, screenshot, timing)
        else:
            window.show()
    finally:
        if board is not None:
            board.close()     # stops the winches first
    return 0


def _scripted(window, screenshot, timing: bool) -> None:
    from .scripted import scripted_session, timing_table
    times = scripted_session(window, screenshot=screenshot, full=timing)
    window.close()
    session, model = window.session, window.session.model
    print(f"{model.scene.name}: {model.n_nodes} nodes, {model.n_elems} triangles, "
          f"{model.n_winches} winches; {session.iterates_shown} iterates shown")
    print(timing_table(times))
    if screenshot is not None:
        print(f"wrote {screenshot}")
