"""Interactive posing: the three interaction modes, live, with the robot attached.

A matplotlib window shows the simulated robot, always at a statically
stable pose, and offers the three interaction modes of the plush-robot
paper (section IV.A):

1. **Set a contraction**: one slider per winch; moving it re-solves the
   forward pose at once (Newton, warm-started from the pose on screen).
2. **Drag to pose**: press on the body, drag, release: the body point
   under the cursor gets a target at the release position. The control
   loop (:class:`~plush_opt.control.gradient.Controller`) runs in the
   background of the event loop: a timer calls :meth:`PosingSession.tick`,
   which takes *one* anytime iterate (never the whole solve), so the window
   stays responsive and the mesh follows iterate by iterate. Targets can be
   dragged again or removed (right click) while the loop runs.
3. **Freeze a winch**: a toggle per winch; a frozen winch keeps its
   contraction bit for bit while the loop moves the others.

With a board attached, every pose shown is sent to it at a bounded rate
(the latest pose wins, the last one is always sent), its positions are read
back (which also keeps the board's watchdog fed), and closing the window
stops the winches.

This module is imported by the command line to build its parser, so
numpy, matplotlib and the solvers are imported where they are used, not at
the top: ``plush-opt --help`` stays quick.

See docs/gui.md.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

log = logging.getLogger(__name__)

# exit statuses of plush_opt.cli
EXIT_OK, EXIT_INPUT, EXIT_SOLVER, EXIT_HARDWARE, EXIT_INTERRUPT = 0, 2, 3, 4, 130

KEY_HELP = (
    "mouse\n"
    "  drag the body     add a target\n"
    "  drag a \u2715          move that target\n"
    "  right-click a \u2715   remove it\n"
    "keys\n"
    "  space   pause / run the loop\n"
    "  r       reset: scene contractions,\n"
    "          no targets\n"
    "  s       save result JSON + PNG\n"
    "  q       quit (stops the winches)"
)

# colours of the interactive parts (the pose itself uses plush_opt.plot's)
PREVIEW_COLOR = "#ff7f0e"
STATUS_FACE = "#f2f2f2"
NON_INTERACTIVE = ("agg", "pdf", "ps", "svg", "pgf", "cairo", "template")


class BoardLink(Protocol):
    """What the window needs from a winch board.

    Contractions are ``{winch name: length}`` in the problem's length unit.
    :class:`DriverBoard` adapts :class:`plush_opt.board.Driver` to it.
    """

    def send(self, contraction: dict[str, float]) -> None:
        """Command these contractions."""

    def positions(self) -> dict[str, float] | None:
        """Measured contractions, or None if unknown."""

    def stop(self) -> None:
        """Stop every winch where it is."""

    def close(self) -> None:
        """Stop and release the board."""


class DriverBoard:
    """:class:`BoardLink` over an open :class:`plush_opt.board.Driver`."""

    def __init__(self, driver):
        self.driver = driver

    def send(self, contraction: dict[str, float]) -> None:
        self.driver.set_contractions(contraction)

    def positions(self) -> dict[str, float] | None:
        return self.driver.read_positions()

    def stop(self) -> None:
        self.driver.stop()

    def close(self) -> None:
        self.driver.close()


@dataclass(frozen=True)
class GuiOptions:
    """Options of the posing window.

    Attributes
    ----------
    interval_ms : period of the timer that steps the control loop, ms
        (each tick takes at most one iterate).
    send_rate : board commands per second at most (the latest pose wins;
        the last one is always sent).
    poll_rate : board position reads per second (they also keep the
        board's watchdog fed while nothing moves).
    pick_radius : how close (pixels) a press must be to a target marker to
        grab it, or to the body to start a new target.
    target_weight : weight w_k of targets made by dragging.
    save_path : where ``s`` writes the result JSON (the PNG goes next to
        it, same name, ``.png``); default ``out/gui-<timestamp>.json``.
    control : :class:`~plush_opt.control.gradient.ControlOptions` of the
        loop; default: the loop's defaults with no iteration or time limit.
    equilibrium : :class:`~plush_opt.equilibrium.EquilibriumOptions` of the
        forward solves (sliders, reset); default: without the eigenvalue.
    max_history : iterates a controller keeps before the window starts a
        fresh one from the current pose (bounds the memory of long sessions).
    figsize : window size, inches.
    """

    interval_ms: int = 30
    send_rate: float = 20.0
    poll_rate: float = 5.0
    pick_radius: float = 10.0
    target_weight: float = 1.0
    save_path: str | os.PathLike | None = None
    control: object | None = None
    equilibrium: object | None = None
    max_history: int = 2000
    figsize: tuple[float, float] = (13.0, 7.6)

    def __post_init__(self):
        if not (isinstance(self.interval_ms, int) and self.interval_ms >= 1):
            raise ValueError(f"interval_ms: expected an integer >= 1, got {self.interval_ms!r}")
        for name in ("send_rate", "poll_rate", "pick_radius", "target_weight"):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"{name}: expected > 0, got {value!r}")
        if self.max_history < 2:
            raise ValueError(f"max_history: expected >= 2, got {self.max_history!r}")


def _default_control():
    from .control.gradient import ControlOptions
    return ControlOptions(max_iterations=10**9)


def _default_equilibrium():
    from .equilibrium import EquilibriumOptions
    return EquilibriumOptions(eigenvalue=False)


def _boundary_edges(triangles):
    """Edges used by one triangle only: the outline (and holes) of the mesh."""
    import numpy as np
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return edges[counts[inverse.reshape(-1)] == 1]


class PosingSession:
    """The posing window: its state, its artists and its event handlers.

    Parameters
    ----------
    model : :class:`~plush_opt.model.Model`
    targets : :class:`~plush_opt.objective.Targets`, optional
        Targets shown at start (the problem file's). The loop is *held* at
        start when there are some: space, or dragging a target, runs it.
    board : :class:`BoardLink`, optional
        The robot. The session stops it when the window closes; closing the
        link is the caller's business (see :func:`run_gui`).
    options : :class:`GuiOptions`
    figure : matplotlib Figure, optional (default: a new pyplot figure).
    clock : callable returning seconds, optional (``time.monotonic``): paces
        board commands and measures the iterate rate.

    Everything a user does goes through the figure's event handlers, which
    call the public methods below; tests drive both. :meth:`tick` is what
    the timer calls.

    Attributes
    ----------
    contraction : (n_winches,) contractions on screen (length units).
    equilibrium : the equilibrium on screen (a forward solve may not have
        converged: see its ``converged`` and ``status``, shown in the status line).
    targets : the current targets.
    frozen : (n_winches,) bool.
    paused : the user paused the loop (space).
    held : the loop waits for a target edit or space (after a slider move,
        a reset, or at start with the problem's targets).
    callback_times : {'tick', 'press', 'motion', 'release', 'key', 'slider',
        'freeze'} -> deque of seconds spent in each handler call; 'iterate':
        the part of a tick spent in the control loop; 'full_redraw': redraws
        of the whole window asked for by a handler (synchronous on Agg,
        deferred to the event loop on a screen); 'tick_blit': the ticks
        without a full redraw.
    """

    def __init__(self, model, targets=None, board: BoardLink | None = None,
                 options: GuiOptions | None = None, *, figure=None, clock=time.monotonic):
        import numpy as np
        from .equilibrium import solve_equilibrium
        from .objective import Targets

        self.model = model
        self.options = options or GuiOptions()
        self.board = board
        self.clock = clock
        self._control_options = self.options.control or _default_control()
        self._eq_options = self.options.equilibrium or _default_equilibrium()
        self.targets = targets if targets is not None else Targets.empty()
        self.frozen = model.scene.frozen.copy()
        self.paused = False
        self.held = self.targets.n_targets > 0
        self.message = ("loop held: press space or drag a target to run it"
                        if self.held else "drag the body to pose it")
        self.callback_times = {k: deque(maxlen=100_000) for k in
                               ("tick", "tick_blit", "iterate", "full_redraw", "press",
                                "motion", "release", "key", "slider", "freeze")}
        self.forward_solves = 0
        self.iterates_shown = 0
        self.controller = None
        self._iterates = None         # the running generator of controller iterates
        self._finished = False        # the loop stopped and nothing changed since
        self._last_iterate = None
        self._iterate_times = deque(maxlen=64)
        self._t_start = time.perf_counter()
        self._solve_s = 0.0
        self._syncing = False         # widgets being set from the state: not user input
        self._drag = None             # {'kind': 'new'|'move', ...} during a mouse drag
        self._closed = False
        self._tension_max = self._tension_scale()
        # board
        self._pending = None          # latest contraction not yet sent
        self._last_send = -np.inf
        self._last_poll = -np.inf
        self.sent = []                # (clock time, contraction dict) of every command sent, last 1000
        self.sends = 0
        self.measured = None
        self.board_error = None

        t0 = time.perf_counter()
        eq = solve_equilibrium(model, model.scene.contraction, None, self._eq_options)
        self._solve_s += time.perf_counter() - t0
        self.forward_solves += 1
        self._set_state(eq)
        self._build_figure(figure)
        self._queue_board()
        self._service_board()
        self._redraw()

    # ------------------------------------------------------------------ state

    def _tension_scale(self) -> float:
        """Top of the tension colour scale: the largest tension with every
        winch at its upper bound (one solve at start), so that colours
        compare across the session; it still grows if a pose goes beyond
        (each growth costs a full redraw)."""
        from .equilibrium import solve_equilibrium
        model = self.model
        if not model.n_tendons:
            return 1.0
        floor = 2.0 * model.tendon_stiffness * model.tendon_smoothing
        t0 = time.perf_counter()
        eq = solve_equilibrium(model, model.upper, None, self._eq_options)
        self._solve_s += time.perf_counter() - t0
        top = float(model.tendon_state(eq.x, model.upper)["tension"].max()) if eq.converged else 0.0
        return _nice_ceil(max(top, floor, 1e-9))

    @property
    def x(self):
        """(n_dofs,) flat pose on screen."""
        return self.equilibrium.x

    @property
    def winch_names(self) -> tuple[str, ...]:
        return tuple(self.model.winch_names)

    @property
    def running(self) -> bool:
        """The next tick will take an iterate."""
        return (not self.paused and not self.held and not self._finished and not self._closed
                and self.targets.n_targets > 0)

    def _index(self, name_or_index) -> int:
        if isinstance(name_or_index, str):
            if name_or_index not in self.winch_names:
                raise KeyError(f"no winch {name_or_index!r}; winches: {', '.join(self.winch_names)}")
            return self.winch_names.index(name_or_index)
        return int(name_or_index)

    def _set_state(self, eq):
        self.equilibrium = eq
        self.contraction = eq.contraction.copy()

    def _objective(self) -> float:
        return self.targets.value(self.x) if self.targets.n_targets else 0.0

    def _drop_controller(self):
        if self._iterates is not None:
            self._iterates.close()
        self._iterates = None
        self.controller = None
        self._last_iterate = None
        self._finished = False

    def _targets_changed(self):
        """New targets: the loop continues from the pose on screen."""
        self.held = False
        self._finished = False
        if self.controller is not None:
            if len(self.controller.history) >= self.options.max_history:
                self._drop_controller()
            else:
                self.controller.set_targets(self.targets)
        self._redraw()

    # ------------------------------------------------ mode 1: contractions

    def set_contraction(self, name_or_index, value: float) -> None:
        """Set one winch's contraction (what its slider does): the forward
        pose is re-solved at once, warm-started from the pose on screen.
        Holds the loop (a target edit or space runs it again)."""
        import numpy as np
        from .equilibrium import solve_equilibrium
        i = self._index(name_or_index)
        c = self.contraction.copy()
        c[i] = float(np.clip(value, self.model.lower[i], self.model.upper[i]))
        if c[i] == self.contraction[i]:
            return
        t0 = time.perf_counter()
        eq = solve_equilibrium(self.model, c, self.x, self._eq_options)
        self._solve_s += time.perf_counter() - t0
        self.forward_solves += 1
        self._drop_controller()
        if self.targets.n_targets and not self.paused:
            self.held = True
        if eq.converged:
            self.message = (f"{self.winch_names[i]} = {c[i]:.3f} mm: forward pose"
                            + (" (loop held: space or a target edit runs it)" if self.held else ""))
        else:
            self.message = f"{self.winch_names[i]} = {c[i]:.3f} mm: forward solve: {eq.status}"
        self._set_state(eq)
        self._sync_sliders()
        self._queue_board()
        self._service_board()
        self._redraw()

    # ------------------------------------------------------ mode 3: freeze

    def set_frozen(self, name_or_index, frozen: bool = True) -> None:
        """Freeze (or release) a winch: the loop keeps a frozen winch's
        contraction bit for bit."""
        i = self._index(name_or_index)
        frozen = bool(frozen)
        if self.frozen[i] == frozen:
            return
        self.frozen[i] = frozen
        if self.controller is not None:
            self.controller.set_frozen(i, frozen)
        self._finished = False
        box = self.freeze_buttons[self.winch_names[i]]
        if box.get_status()[0] != frozen:
            self._syncing = True
            try:
                box.set_active(0)
            finally:
                self._syncing = False
        self.message = f"{self.winch_names[i]} {'frozen' if frozen else 'released'}"
        self._redraw()

    # -------------------------------------------------- mode 2: targets

    def locate(self, point):
        """The body point under ``point`` (current coordinates), found by
        inverting the current deformation: the deformed triangle holding it
        and its barycentric weights, which are also the point's weights in
        the rest triangle. Returns (triangle, beta) or None off the body.
        Points within the pick radius of the body snap onto its edge."""
        import numpy as np
        from .scene import locate_in_triangles
        nodes = self.x.reshape(-1, 2)
        tri, beta = locate_in_triangles(nodes[self.model.mesh.triangles],
                                        np.asarray(point, dtype=np.float64).reshape(1, 2),
                                        tol=self.options.pick_radius * self._data_per_pixel())
        if tri[0] < 0:
            return None
        b = np.clip(beta[0], 0.0, None)
        return int(tri[0]), b / b.sum()

    def rest_point(self, triangle: int, beta):
        """Rest coordinates of the body point (triangle, beta), (2,)."""
        import numpy as np
        X = self.model.X.reshape(-1, 2)
        return np.asarray(beta) @ X[self.model.mesh.triangles[triangle]]

    def add_target(self, triangle: int, beta, to) -> int:
        """A target for body point (triangle, beta) going to ``to``; returns its index."""
        import numpy as np
        from .objective import Targets
        t = self.targets
        tri = np.append(t.triangles, int(triangle))
        self.targets = Targets(tri, self.model.mesh.triangles[tri],
                               np.vstack([t.beta, np.reshape(beta, (1, 3))]),
                               np.vstack([t.to, np.reshape(to, (1, 2))]),
                               np.append(t.weight, self.options.target_weight))
        k = self.targets.n_targets - 1
        self.message = (f"target {k + 1} at rest point ({', '.join(f'{v:.1f}' for v in self.rest_point(triangle, beta))})"
                        f" \u2192 ({to[0]:.1f}, {to[1]:.1f})")
        self._targets_changed()
        return k

    def move_target(self, k: int, to) -> None:
        """Send target ``k`` somewhere else."""
        import numpy as np
        q = self.targets.to.copy()
        q[k] = np.asarray(to, dtype=np.float64)
        self.targets = self.targets.replace_to(q)
        self.message = f"target {k + 1} \u2192 ({q[k, 0]:.1f}, {q[k, 1]:.1f})"
        self._targets_changed()

    def remove_target(self, k: int) -> None:
        """Remove target ``k``."""
        import numpy as np
        from .objective import Targets
        t = self.targets
        keep = np.arange(t.n_targets) != k
        self.targets = Targets(t.triangles[keep], t.nodes[keep], t.beta[keep], t.to[keep],
                               t.weight[keep])
        self.message = f"target {k + 1} removed"
        self._targets_changed()

    # --------------------------------------------------------------- keys

    def toggle_pause(self) -> None:
        """Pause a running loop; run a paused or held one."""
        if self.paused or self.held:
            self.paused = self.held = False
            self.message = "loop running" if self.targets.n_targets else "no targets: drag the body to pose it"
        else:
            self.paused = True
            self.message = "paused: space runs the loop again"
        self._redraw()

    def reset(self) -> None:
        """Back to rest: the scene's contractions, no targets (frozen flags stay)."""
        from .equilibrium import solve_equilibrium
        from .objective import Targets
        self._drop_controller()
        self._drag = None
        self.targets = Targets.empty()
        self.held = False
        t0 = time.perf_counter()
        eq = solve_equilibrium(self.model, self.model.scene.contraction, None, self._eq_options)
        self._solve_s += time.perf_counter() - t0
        self.forward_solves += 1
        self._set_state(eq)
        self._sync_sliders()
        self._queue_board()
        self._service_board()
        self.message = "reset: scene contractions, targets cleared"
        self._redraw()

    def result(self) -> dict:
        """The result document (results.result_dict) of the pose on screen,
        re-certified with the smallest Hessian eigenvalue."""
        from .equilibrium import EquilibriumOptions, solve_equilibrium
        from .results import result_dict
        eq = solve_equilibrium(self.model, self.contraction, self.x,
                               EquilibriumOptions(backend=self._eq_options.backend))
        names = self.winch_names
        ctl = self.controller
        if self.targets.n_targets:
            method = "reparam"   # the gradient loop; its bound handling is in extra["gui"]
            loop_done = ctl is not None and self._finished and ctl.converged
            converged = bool(eq.converged and loop_done)
            state = ("paused" if self.paused else "held" if self.held
                     else "stopped" if self._finished else "running")
            status = (f"interactive session, loop {state}"
                      + (f": {ctl.status}" if ctl is not None else ""))
            if not eq.converged:
                status += f"; pose: {eq.status}"
            iterations = len(ctl.history) - 1 if ctl is not None else 0
        else:
            method, converged, status, iterations = "forward", eq.converged, eq.status, eq.iterations
        extra = {"gui": {
            "bounds": self._control_options.bounds,
            "frozen": [n for n, f in zip(names, self.frozen) if f],
            "targets_rest": [self.rest_point(e, b).tolist()
                             for e, b in zip(self.targets.triangles, self.targets.beta)],
            "board": None if self.board is None else {
                "commands": self.sends, "error": self.board_error,
                "measured": None if self.measured is None else dict(self.measured)},
        }}
        return result_dict(self.model, self.targets, eq, method=method, converged=converged,
                           status=status, total_s=time.perf_counter() - self._t_start,
                           solve_s=self._solve_s, iterations=iterations, extra=extra)

    def save(self, path=None) -> tuple[Path, Path]:
        """Write the result JSON (atomically) and a PNG of the window next
        to it; returns both paths. Default path: ``options.save_path``, else
        ``out/gui-<timestamp>.json``."""
        from .results import write_json_atomic
        path = Path(path or self.options.save_path or _timestamped(Path("out"), "gui"))
        png = path.with_suffix(".png")
        write_json_atomic(path, self.result())
        self.message = f"saved {path} and {png.name}"
        self._redraw()
        png.parent.mkdir(parents=True, exist_ok=True)
        self.fig.savefig(png, dpi=100)
        self._backgrounds = None      # redraw everything after saving
        self.fig.canvas.draw_idle()
        log.info("saved %s and %s", path, png)
        return path, png

    def close(self) -> None:
        """Stop the loop and the board, close the window (``q``)."""
        self.shutdown()
        import matplotlib.pyplot as plt
        plt.close(self.fig)

    def shutdown(self) -> None:
        """Stop the timer, the loop and the winches (idempotent; the
        window's close event calls it)."""
        if self._closed:
            return
        self._closed = True
        if self.timer is not None:
            self.timer.stop()
        if self._iterates is not None:
            self._iterates.close()
            self._iterates = None
        if self.board is not None:
            try:
                self.board.stop()
                log.info("board stopped")
            except Exception as exc:  # noqa: BLE001 - the window must close whatever the board does
                log.error("could not stop the board: %s", exc)

    # --------------------------------------------------------------- loop

    def tick(self):
        """One timer callback: at most one control iterate, then the board
        and the status line. Returns the iterate shown, or None."""
        t0 = time.perf_counter()
        full_redraws = len(self.callback_times["full_redraw"])
        shown = None
        try:
            if self.running:
                shown = self._step()
            self._service_board()
            if shown is not None:
                self._redraw()
            else:
                self._update_status()
                self._refresh()
        finally:
            dt = time.perf_counter() - t0
            self.callback_times["tick"].append(dt)
            if len(self.callback_times["full_redraw"]) == full_redraws:
                self.callback_times["tick_blit"].append(dt)
        return shown

    def _on_timer(self):
        try:
            self.tick()
        except Exception:  # noqa: BLE001 - a failing tick must not kill the timer silently
            log.exception("tick failed")
            self.paused = True
            self.message = "error in the control loop (see the log); paused"

    def _step(self):
        from .control.gradient import Controller
        from .errors import SolverError
        try:
            if self.controller is None:
                self.controller = Controller(self.model, self.targets, self.contraction, self.frozen,
                                             x0=self.x, options=self._control_options)
            if self._iterates is None:
                self._iterates = self.controller.iterates()
            t0 = time.perf_counter()
            try:
                it = next(self._iterates)
            finally:
                dt = time.perf_counter() - t0
                self._solve_s += dt
                self.callback_times["iterate"].append(dt)
        except StopIteration:
            self._iterates = None
            self._finished = True
            self.message = f"loop stopped: {self.controller.status}"
            return None
        except SolverError as exc:
            self._drop_controller()
            self.held = True
            self.message = f"loop cannot start: {exc}"
            return None
        self._set_state(it.equilibrium)
        self._last_iterate = it
        self.iterates_shown += 1
        self._iterate_times.append(self.clock())
        self._sync_sliders()
        self._queue_board()
        return it

    # -------------------------------------------------------------- board

    def _queue_board(self):
        if self.board is not None:
            self._pending = {n: float(c) for n, c in zip(self.winch_names, self.contraction)}

    def _service_board(self):
        """Send the latest pose if the rate allows; read positions now and then."""
        if self.board is None or self.board_error is not None or self._closed:
            return
        now = self.clock()
        try:
            if self._pending is not None and now - self._last_send >= 1.0 / self.options.send_rate:
                self.board.send(self._pending)
                self.sends += 1
                self.sent.append((now, self._pending))
                del self.sent[:-1000]
                self._pending = None
                self._last_send = now
            if now - self._last_poll >= 1.0 / self.options.poll_rate:
                self._last_poll = now
                self.measured = self.board.positions()
        except Exception as exc:  # noqa: BLE001 - show it, stop the board, keep the window
            self.board_error = str(exc)
            self.message = f"board error: {exc}; nothing more is sent"
            log.error("board error: %s", exc)
            try:
                self.board.stop()
            except Exception as stop_exc:  # noqa: BLE001
                log.error("could not stop the board: %s", stop_exc)

    # ------------------------------------------------------------- figure

    def _build_figure(self, figure):
        import matplotlib.pyplot as plt
        from matplotlib.collections import LineCollection
        from matplotlib.lines import Line2D
        from matplotlib.patches import Rectangle

        from .apps.plot import REST_COLOR, TARGET_COLOR, draw_pose

        model = self.model
        n_w = model.n_winches
        fig = figure if figure is not None else plt.figure(figsize=self.options.figsize)
        self.fig = fig
        try:
            fig.canvas.manager.set_window_title(f"plush-opt: {model.scene.name}")
        except AttributeError:
            pass

        # --- pose axes, big, on the left
        ax = fig.add_axes([0.055, 0.125, 0.58, 0.83])
        self.ax = ax
        X = model.X.reshape(-1, 2)
        self.artists = draw_pose(ax, model, self.x, self.contraction, None, show_rest=False,
                                 colorbar=False)
        self.artists["tendons"].set_clim(0.0, self._tension_max)
        outline = X[_boundary_edges(model.mesh.triangles)]
        ax.add_collection(LineCollection(outline, colors=REST_COLOR, linewidths=1.0,
                                         linestyles=(0, (4, 3)), zorder=1.5))
        self.artists["target_lines"] = ax.add_collection(LineCollection(
            [], colors=TARGET_COLOR, linestyles="dotted", linewidths=1.2, zorder=7))
        self.artists["targets"], = ax.plot([], [], "x", color=TARGET_COLOR, ms=11, mew=2.5, zorder=9)
        self.artists["points"], = ax.plot([], [], "o", mfc="white", mec=TARGET_COLOR, mew=1.5,
                                          ms=6, zorder=8)
        self.artists["preview_line"], = ax.plot([], [], "--", color=PREVIEW_COLOR, lw=1.5, zorder=10)
        self.artists["preview"], = ax.plot([], [], "x", color=PREVIEW_COLOR, ms=12, mew=2.5,
                                           alpha=0.8, zorder=10)
        self.artists["grab"], = ax.plot([], [], "o", color=PREVIEW_COLOR, ms=7, zorder=10)
        self._set_limits(X)
        ax.set_title(f"{model.scene.name}: drag the body to pose it", fontsize=11, loc="left")
        ax.grid(True, alpha=0.15)
        legend = [Line2D([], [], color=REST_COLOR, ls=(0, (4, 3)), label="rest outline"),
                  Line2D([], [], marker="^", ls="", color="#222222", label="pin"),
                  Line2D([], [], marker="x", ls="", color=TARGET_COLOR, mew=2, label="target"),
                  Line2D([], [], marker="o", ls="", mfc="white", mec=TARGET_COLOR,
                         label="its body point")]
        pins = [self.artists["pins"]]

        # --- tension colour bar
        cax = fig.add_axes([0.645, 0.125, 0.01, 0.83])
        cb = fig.colorbar(self.artists["tendons"], cax=cax)
        cb.set_label("tendon tension [N]", fontsize=9)
        cb.ax.tick_params(labelsize=8)

        # --- right-hand panel: one slider and one freeze toggle per winch
        left, width = 0.745, 0.15
        fig.text(0.705, 0.935, "Winch contractions [mm]", fontsize=11, weight="bold")
        row = min(0.075, 0.52 / max(n_w, 1))
        self.sliders, self.freeze_buttons = {}, {}
        with _no_redraws(fig.canvas):
            self._build_winch_rows(left, width, row)

        help_top = 0.875 - n_w * row - 0.02
        fig.text(0.705, help_top, KEY_HELP, fontsize=8.5, family="monospace", va="top",
                 linespacing=1.35, color="#333333")
        # the legend lives in the panel: the body never covers it
        fig.legend(handles=legend, loc="lower left", bbox_to_anchor=(0.7, 0.075), fontsize=8.5,
                   frameon=False, ncols=2)

        # --- status strip at the bottom
        sax = fig.add_axes([0.0, 0.0, 1.0, 0.055])
        self._status_ax = sax
        sax.set_axis_off()
        sax.add_patch(Rectangle((0, 0), 1, 1, transform=sax.transAxes, facecolor=STATUS_FACE,
                                edgecolor="#cccccc"))
        self.status_text = sax.text(0.008, 0.68, "", family="monospace", fontsize=9, va="center")
        self.message_text = sax.text(0.008, 0.25, "", family="monospace", fontsize=9, va="center",
                                     color="#555555")

        # --- blitting: what changes is drawn over saved backgrounds of three
        # kinds of region (the pose axes, each slider, the status strip), and
        # only where something changed: an iterate costs the mesh and a few
        # texts, not the whole window
        a = self.artists
        pose = [a[k] for k in ("body", "tendons", "stoppers", "target_lines", "points",
                               "targets", "preview_line", "grab", "preview")] + pins
        pose.sort(key=lambda artist: artist.get_zorder())
        self._region_artists = {"pose": pose, "status": [self.status_text],
                                "message": [self.message_text]}
        for name, s in self.sliders.items():
            s.drawon = False          # drawn by _refresh
            self._region_artists[f"slider:{name}"] = \
                [s.poly, s.valtext] + ([s._handle] if hasattr(s, "_handle") else [])
        for artists in self._region_artists.values():
            for artist in artists:
                artist.set_animated(True)
        self._backgrounds = None      # region -> (bbox, saved pixels), after a full draw
        self._drawn = {}              # region -> what it shows (for changes)
        self._drawn_at = {}           # region -> when it was last blitted
        self._pose_changed = True
        self._clim_drawn = self._tension_max

        # --- events
        canvas = fig.canvas
        self._cids = [
            canvas.mpl_connect("draw_event", self._on_draw),
            canvas.mpl_connect("button_press_event", self._on_press),
            canvas.mpl_connect("motion_notify_event", self._on_motion),
            canvas.mpl_connect("button_release_event", self._on_release),
            canvas.mpl_connect("key_press_event", self._on_key),
            canvas.mpl_connect("close_event", self._on_close),
        ]
        # our keys (space, r, s, q) replace matplotlib's defaults for them
        # ('r' home, 's' save, 'q' quit); the toolbar's other keys still work
        manager = getattr(canvas, "manager", None)
        if manager is not None and getattr(manager, "key_press_handler_id", None) is not None:
            canvas.mpl_disconnect(manager.key_press_handler_id)
            manager.key_press_handler_id = None
        self.timer = canvas.new_timer(interval=self.options.interval_ms)
        self.timer.add_callback(self._on_timer)

    def _build_winch_rows(self, left, width, row):
        """One slider and one freeze toggle per winch."""
        from matplotlib.widgets import CheckButtons, Slider
        fig, model = self.fig, self.model
        for i, name in enumerate(model.winch_names):
            y = 0.875 - i * row
            sax = fig.add_axes([left, y, width, 0.03])
            s = Slider(sax, name, float(model.lower[i]), float(model.upper[i]),
                       valinit=float(self.contraction[i]), valfmt="%.2f")
            s.label.set_fontsize(10)
            s.valtext.set_fontsize(9)
            s.valtext.set_x(1.06)     # clear of the handle at either bound
            s.label.set_x(-0.07)
            s.on_changed(lambda value, i=i: self._on_slider(i, value))
            self.sliders[name] = s
            bax = fig.add_axes([left + width + 0.045, y - 0.008, 0.07, 0.046])
            bax.set_frame_on(False)
            b = CheckButtons(bax, ["freeze"], [bool(self.frozen[i])], useblit=False)
            for text in b.labels:
                text.set_fontsize(9)
            b.on_clicked(lambda label, i=i: self._on_freeze(i))
            self.freeze_buttons[name] = b

    def _set_limits(self, X):
        """Rest body and targets with a margin, stretched to the axes' shape
        (equal scales without matplotlib moving the limits later)."""
        import numpy as np
        lo, hi = X.min(axis=0), X.max(axis=0)
        if self.targets.n_targets:
            lo = np.minimum(lo, self.targets.to.min(axis=0))
            hi = np.maximum(hi, self.targets.to.max(axis=0))
        centre, half = (lo + hi) / 2, (hi - lo) / 2 + 0.3 * float((hi - lo).max())
        box = self.ax.get_position(original=True)
        w_in, h_in = self.fig.get_size_inches()
        ratio = (box.height * h_in) / (box.width * w_in)       # height / width of the box
        if half[1] / half[0] < ratio:
            half[1] = half[0] * ratio
        else:
            half[0] = half[1] / ratio
        self.ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
        self.ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
        self.ax.set_aspect("equal", adjustable="box")

    def _region_bboxes(self) -> dict:
        """Pixel boxes of the blitted regions (after a draw: they follow resizes)."""
        from matplotlib.transforms import Bbox
        strip = self._status_ax.bbox
        middle = strip.y0 + 0.45 * strip.height        # between the two lines of text
        boxes = {"pose": self.ax.bbox.frozen(),
                 "status": Bbox.from_extents(strip.x0, middle, strip.x1, strip.y1),
                 "message": Bbox.from_extents(strip.x0, strip.y0, strip.x1, middle)}
        for name, s in self.sliders.items():
            b, right = s.ax.bbox, self.freeze_buttons[name].ax.bbox.x0
            # the handle sticks out of the slider's axes a little
            boxes[f"slider:{name}"] = Bbox.from_extents(b.x0 - 12, b.y0 - 8, right, b.y1 + 8)
        return boxes

    def _region_state(self, region: str):
        if region == "status":
            return self.status_text.get_text()
        if region == "message":
            return self.message_text.get_text()
        if region.startswith("slider:"):
            return self.sliders[region[7:]].valtext.get_text()
        return None

    def _on_draw(self, event):
        """After a full draw (first show, resize, a widget click): keep the
        backgrounds of the regions, then draw their artists on them."""
        canvas = self.fig.canvas
        if canvas.is_saving() or not canvas.supports_blit:
            return
        self._backgrounds = {k: (b, canvas.copy_from_bbox(b)) for k, b in self._region_bboxes().items()}
        for region, artists in self._region_artists.items():
            for artist in artists:
                self.fig.draw_artist(artist)
            self._drawn[region] = self._region_state(region)
        self._pose_changed = False

    def _refresh(self):
        """Show the new state: blit the regions that changed over their
        backgrounds, or ask for a full redraw when there are none yet or the
        colour scale changed. Text costs as much to draw as the mesh, so the
        status numbers are redrawn at most 5 times a second and the slider
        values 10 times (the pose and the message at once); a region left
        behind is drawn by a later call (the timer's ticks)."""
        canvas = self.fig.canvas
        if self._backgrounds is None or self._clim_drawn != self._tension_max:
            self._clim_drawn = self._tension_max
            self._backgrounds = None
            t0 = time.perf_counter()
            canvas.draw_idle()
            self.callback_times["full_redraw"].append(time.perf_counter() - t0)
            return
        now = time.perf_counter()
        for region, artists in self._region_artists.items():
            if region == "pose":
                if not self._pose_changed:
                    continue
                self._pose_changed = False
            else:
                state = self._region_state(region)
                if state == self._drawn.get(region):
                    continue
                period = 0.2 if region == "status" else 0.1 if region.startswith("slider:") else 0.0
                if now - self._drawn_at.get(region, -1e9) < period:
                    continue
                self._drawn[region] = state
                self._drawn_at[region] = now
            bbox, background = self._backgrounds[region]
            canvas.restore_region(background)
            for artist in artists:
                self.fig.draw_artist(artist)
            canvas.blit(bbox)

    def _data_per_pixel(self) -> float:
        inv = self.ax.transData.inverted()
        (x0, _), (x1, _) = inv.transform([(0.0, 0.0), (1.0, 0.0)])
        return abs(x1 - x0)

    def _sync_sliders(self):
        """Sliders follow the state without calling back (no forward solve)."""
        self._syncing = True
        try:
            for i, s in enumerate(self.sliders.values()):
                if s.val != self.contraction[i]:
                    s.set_val(float(self.contraction[i]))
        finally:
            self._syncing = False

    def _redraw(self):
        """Move the artists to the state and ask for a redraw."""
        import numpy as np
        model = self.model
        xn = self.x.reshape(-1, 2)
        a = self.artists
        a["body"].set_verts(xn[model.mesh.triangles])
        if model.n_tendons:
            tension = model.tendon_state(self.x, self.contraction)["tension"]
            if tension.max() > self._tension_max:
                # grow the scale in steps (each change costs a full redraw)
                self._tension_max = _nice_ceil(1.25 * float(tension.max()))
            a["tendons"].set_segments([xn[p] for p in model.tendon_paths])
            a["tendons"].set_array(tension)
            a["tendons"].set_clim(0.0, self._tension_max)
            ends = np.array([xn[p[0]] for p in model.tendon_paths])
            a["stoppers"].set_data(ends[:, 0], ends[:, 1])
        t = self.targets
        if t.n_targets:
            y = t.y(self.x)
            a["targets"].set_data(t.to[:, 0], t.to[:, 1])
            a["points"].set_data(y[:, 0], y[:, 1])
            a["target_lines"].set_segments(np.stack([y, t.to], axis=1))
        else:
            for k in ("targets", "points"):
                a[k].set_data([], [])
            a["target_lines"].set_segments([])
        self._draw_preview()
        self._update_status()
        self._refresh()

    def _draw_preview(self):
        a = self.artists
        self._pose_changed = True
        d = self._drag
        if d is None or d.get("to") is None:
            for k in ("preview", "preview_line", "grab"):
                a[k].set_data([], [])
            return
        if d["kind"] == "new":
            nodes = self.x.reshape(-1, 2)[self.model.mesh.triangles[d["triangle"]]]
            start = d["beta"] @ nodes
        else:
            start = self.targets.y(self.x)[d["k"]]
        to = d["to"]
        a["grab"].set_data([start[0]], [start[1]])
        a["preview_line"].set_data([start[0], to[0]], [start[1], to[1]])
        a["preview"].set_data([to[0]], [to[1]])

    def _update_status(self):
        eq = self.equilibrium
        state = ("paused" if self.paused else "held" if self.held
                 else "no targets" if not self.targets.n_targets
                 else "stopped" if self._finished else "running")
        now = self.clock()
        recent = [t for t in self._iterate_times if now - t <= 2.0]
        rate = (len(recent) - 1) / (recent[-1] - recent[0]) if len(recent) >= 2 and recent[-1] > recent[0] else 0.0
        parts = [f"loop {state:<10}"]
        if self.targets.n_targets:
            parts.append(f"O {self._objective():.3e} mm\u00b2 (rms {self.targets.rms_error(self.x):.2f} mm,"
                         f" {self.targets.n_targets} target{'s' if self.targets.n_targets > 1 else ''})")
        else:
            parts.append("O -")
        parts.append(f"residual {eq.residual_norm:.1e} N{'' if eq.converged else ' (NOT converged)'}")
        parts.append(f"{rate:5.1f} it/s")
        bounds = self._last_iterate.active_bounds if self._last_iterate is not None else ()
        parts.append(f"bounds: {', '.join(bounds) if bounds else '-'}")
        frozen = [n for n, f in zip(self.winch_names, self.frozen) if f]
        parts.append(f"frozen: {', '.join(frozen) if frozen else '-'}")
        if self.board is None:
            parts.append("board: none")
        elif self.board_error is not None:
            parts.append("board: ERROR (stopped)")
        elif self._closed:
            parts.append("board: stopped")
        else:
            lag = ""
            if self.measured:
                diffs = [abs(self.measured[n] - c) for n, c in zip(self.winch_names, self.contraction)
                         if n in self.measured]
                if diffs:
                    lag = f", lag {max(diffs):.2f} mm"
            parts.append(f"board: {self.sends} sent{lag}")
        self.status_text.set_text("  |  ".join(parts))
        self.message_text.set_text(self.message)

    # ------------------------------------------------------------- events

    def _timed(self, kind, t0):
        self.callback_times[kind].append(time.perf_counter() - t0)

    def _toolbar_busy(self) -> bool:
        toolbar = getattr(self.fig.canvas, "toolbar", None)
        mode = getattr(toolbar, "mode", "")
        return mode not in ("", None)

    def _target_near(self, event, include_points: bool):
        """Index of the target marker (or body point) within the pick radius, or None."""
        import numpy as np
        t = self.targets
        if not t.n_targets:
            return None
        spots = [t.to] + ([t.y(self.x)] if include_points else [])
        best, best_d = None, self.options.pick_radius
        for pts in spots:
            pix = self.ax.transData.transform(pts)
            d = np.hypot(pix[:, 0] - event.x, pix[:, 1] - event.y)
            k = int(np.argmin(d))
            if d[k] <= best_d:
                best, best_d = k, d[k]
        return best

    def _on_press(self, event):
        t0 = time.perf_counter()
        try:
            if event.inaxes is not self.ax or self._toolbar_busy() or event.xdata is None:
                return
            if event.button == 3:
                k = self._target_near(event, include_points=True)
                if k is not None:
                    self.remove_target(k)
                return
            if event.button != 1:
                return
            k = self._target_near(event, include_points=False)
            if k is not None:
                self._drag = {"kind": "move", "k": k, "to": None}
                self.message = f"moving target {k + 1}"
                return
            found = self.locate((event.xdata, event.ydata))
            if found is None:
                self.message = "press on the body to grab a point of it"
                self._update_status()
                self._refresh()
                return
            tri, beta = found
            self._drag = {"kind": "new", "triangle": tri, "beta": beta,
                          "to": (float(event.xdata), float(event.ydata))}
            self.message = "drag to where this point should go, release to set the target"
            self._redraw()
        finally:
            self._timed("press", t0)

    def _on_motion(self, event):
        if self._drag is None or event.inaxes is not self.ax or event.xdata is None:
            return
        t0 = time.perf_counter()
        self._drag["to"] = (float(event.xdata), float(event.ydata))
        self._draw_preview()
        self._refresh()
        self._timed("motion", t0)

    def _on_release(self, event):
        d = self._drag
        if d is None or event.button != 1:
            return
        t0 = time.perf_counter()
        try:
            self._drag = None
            if event.inaxes is self.ax and event.xdata is not None:
                to = (float(event.xdata), float(event.ydata))
            else:
                to = d["to"]   # released outside the axes: the last position seen
            if to is None:
                self._redraw()
                return
            if d["kind"] == "new":
                self.add_target(d["triangle"], d["beta"], to)
            else:
                self.move_target(d["k"], to)
        finally:
            self._timed("release", t0)

    def _on_key(self, event):
        t0 = time.perf_counter()
        try:
            key = event.key
            if key == " ":
                self.toggle_pause()
            elif key == "r":
                self.reset()
            elif key == "s":
                self.save()
            elif key == "q":
                self.close()
            else:
                from matplotlib.backend_bases import key_press_handler
                key_press_handler(event, self.fig.canvas, getattr(self.fig.canvas, "toolbar", None))
        finally:
            self._timed("key", t0)

    def _on_slider(self, i, value):
        if self._syncing:
            return
        t0 = time.perf_counter()
        try:
            self.set_contraction(i, value)
        finally:
            self._timed("slider", t0)

    def _on_freeze(self, i):
        if self._syncing:
            return
        t0 = time.perf_counter()
        try:
            status = self.freeze_buttons[self.winch_names[i]].get_status()[0]
            self.set_frozen(i, status)
        finally:
            self._timed("freeze", t0)

    def _on_close(self, event):
        self.shutdown()

    # ---------------------------------------------------------------- run

    def show(self) -> None:
        """Start the timer and run the window until it is closed."""
        import matplotlib.pyplot as plt
        self.timer.start()
        try:
            plt.show()
        finally:
            self.shutdown()


@contextlib.contextmanager
def _no_redraws(canvas):
    """Hold back the full redraws widgets ask for while they are built (on
    Agg each is done at once)."""
    canvas.draw_idle = lambda *args, **kwargs: None
    try:
        yield
    finally:
        del canvas.draw_idle


def _nice_ceil(value: float) -> float:
    """The smallest of 1, 1.5, 2, 2.5, 3, 4, 5, 6, 8 times a power of ten
    that is >= value."""
    import math
    exp = math.floor(math.log10(value))
    for m in (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if m * 10.0**exp >= value:
            return m * 10.0**exp
    return 10.0 ** (exp + 1)


def _timestamped(folder: Path, stem: str) -> Path:
    base = folder / f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    path, k = base.with_suffix(".json"), 2
    while path.exists():
        path = folder / f"{base.name}-{k}.json"
        k += 1
    return path


# ----------------------------------------------------------------------------
# Scripted sessions: the screenshot in docs/ and the callback timings
# ----------------------------------------------------------------------------

def mouse(session: PosingSession, kind: str, xy, button: int = 1) -> None:
    """Feed one synthesised mouse event (``press``, ``motion``, ``release``)
    at data point ``xy`` of the pose axes through the figure's callbacks."""
    from matplotlib.backend_bases import MouseEvent
    name = {"press": "button_press_event", "motion": "motion_notify_event",
            "release": "button_release_event"}[kind]
    px, py = session.ax.transData.transform(xy)
    event = MouseEvent(name, session.fig.canvas, px, py, button=None if kind == "motion" else button)
    session.fig.canvas.callbacks.process(name, event)


def key(session: PosingSession, name: str) -> None:
    """Feed one synthesised key press through the figure's callbacks."""
    from matplotlib.backend_bases import KeyEvent
    session.fig.canvas.callbacks.process("key_press_event",
                                         KeyEvent("key_press_event", session.fig.canvas, name))


def drag(session: PosingSession, start, end, steps: int = 8, button: int = 1) -> None:
    """Press at ``start``, move in ``steps`` steps and release at ``end``
    (data coordinates)."""
    import numpy as np
    start, end = np.asarray(start, float), np.asarray(end, float)
    mouse(session, "press", start, button)
    for s in np.linspace(0.0, 1.0, steps + 1)[1:]:
        mouse(session, "motion", start + s * (end - start))
    mouse(session, "release", end, button)


def run_ticks(session: PosingSession, max_ticks: int) -> int:
    """Tick until the loop stops (or ``max_ticks``); returns the ticks done."""
    for n in range(1, max_ticks + 1):
        session.tick()
        if not session.running:
            return n
    return max_ticks


def demo_drags(model):
    """Three drags for a scripted session, as (body point, destination) in
    rest coordinates.

    The points: the triangle centroid farthest from the pins; among those
    at least 70 % as far, the one farthest from the first; the centroid
    nearest the middle of those two. The destinations are where the points
    are at reachable poses: the first two at contractions of 60, 15, 30,
    45, 60, ... % of each winch's range, the third at 0, 80, 0, 50, 0, ... %.
    """
    import numpy as np
    from .equilibrium import EquilibriumOptions, solve_equilibrium
    X = model.X.reshape(-1, 2)
    pivot = X[model.pin_nodes].mean(axis=0)
    C = X[model.mesh.triangles].mean(axis=1)
    reach = np.linalg.norm(C - pivot, axis=1)
    k0 = int(np.argmax(reach))
    k1 = int(np.argmax(np.where(reach >= 0.7 * reach.max(), np.linalg.norm(C - C[k0], axis=1), -1.0)))
    k2 = int(np.argmin(np.linalg.norm(C - (C[k0] + C[k1]) / 2, axis=1)))
    moved = []
    for fractions in ([0.6, 0.15, 0.3, 0.45], [0.0, 0.8, 0.0, 0.5]):
        c = model.lower + np.resize(fractions, model.n_winches) * (model.upper - model.lower)
        x = solve_equilibrium(model, c, None, EquilibriumOptions(eigenvalue=False)).x.reshape(-1, 2)
        moved.append(x[model.mesh.triangles].mean(axis=1))
    return [(C[k0], moved[0][k0]), (C[k1], moved[0][k1]), (C[k2], moved[1][k2])]


def current_position(session: PosingSession, rest_point):
    """Where the body point at ``rest_point`` (rest coordinates) is now."""
    import numpy as np
    tri, beta = session.model.mesh.locate(np.reshape(rest_point, (1, 2)))
    nodes = session.x.reshape(-1, 2)[session.model.mesh.triangles[tri[0]]]
    return beta[0] @ nodes


def scripted_session(session: PosingSession, *, ticks: int = 80, screenshot=None,
                     full: bool = True) -> dict:
    """A scripted drag session, as a user would run it.

    ``r`` (no targets), two drags (see :func:`demo_drags`), each followed
    by ticks until the loop stops, and a third drag, caught half-way for
    the screenshot, then released and followed by ticks. With ``full``,
    then: the first target dragged again, a slider move, space, a freeze,
    a right-click removal, each followed by ticks.
    Returns the handler times (seconds) by kind (a tick includes blitting
    the new pose) plus ``draw``: five full redraws of the window (what a
    resize or a widget click costs).
    """
    import numpy as np
    key(session, "r")
    first, second, (point, to) = demo_drags(session.model)
    for p, q in (first, second):
        drag(session, current_position(session, p), q)
        run_ticks(session, ticks)
    start = current_position(session, point)
    mouse(session, "press", start)
    for f in (0.2, 0.4, 0.6):
        mouse(session, "motion", start + f * (np.asarray(to) - start))
    if screenshot is not None:
        Path(screenshot).parent.mkdir(parents=True, exist_ok=True)
        session.fig.canvas.draw()
        session.fig.savefig(screenshot, dpi=100)
    mouse(session, "release", start + 0.6 * (np.asarray(to) - start))
    run_ticks(session, ticks)
    if full:
        to = session.targets.to[0]
        drag(session, to, to + 0.3 * (session.targets.y(session.x)[0] - to))
        run_ticks(session, ticks)
        name = session.winch_names[0]
        mid = 0.5 * (session.model.lower[0] + session.model.upper[0])
        session.sliders[name].set_val(mid)
        key(session, " ")
        run_ticks(session, ticks)
        session.freeze_buttons[name].set_active(0)
        run_ticks(session, ticks)
        mouse(session, "press", session.targets.to[0], button=3)
        run_ticks(session, ticks)
    times = {k: list(v) for k, v in session.callback_times.items()}
    times["draw"] = []
    for _ in range(5):
        t0 = time.perf_counter()
        session.fig.canvas.draw()
        times["draw"].append(time.perf_counter() - t0)
    return times


def timing_table(times: dict) -> str:
    """Count, median and worst (ms) of each handler kind."""
    import numpy as np
    lines = [f"{'callback':<12} {'count':>6} {'median ms':>10} {'worst ms':>9}"]
    for k, v in times.items():
        if v:
            lines.append(f"{k:<12} {len(v):>6} {1e3 * np.median(v):>10.1f} {1e3 * max(v):>9.1f}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------
# Command line: `plush-opt gui` and `python -m plush_opt.gui`
# ----------------------------------------------------------------------------

def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def _add_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.add_argument("problem", type=Path, help="problem file (YAML, format plush-opt/1)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--port", help="serial port of the winch board: every pose shown is sent to it")
    where.add_argument("--emulator", action="store_true",
                       help="attach the board emulator (build it with `make -C hw`)")
    p.add_argument("--board", type=Path, metavar="FILE",
                   help="board calibration (default: hw/boards/<problem name>.yaml of the source tree)")
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
    return p


def add_gui_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``gui`` to the command line's subparsers (``func=cmd_gui``)."""
    p = subparsers.add_parser(
        "gui", help="pose the robot interactively (sliders, drag to pose, freeze), live on the board",
        description="A window showing the robot at its stable pose: winch sliders re-solve the "
        "pose; dragging the body sets targets that the control loop reaches iterate by iterate; "
        "freeze toggles hold winches. With --port or --emulator every pose shown goes to the board.")
    _add_arguments(p)
    p.set_defaults(func=cmd_gui)
    return p


def _default_board_file(scene_name: str) -> Path:
    return Path(__file__).resolve().parent.parent / "hw" / "boards" / f"{scene_name}.yaml"


def run_gui(problem, *, port=None, emulator=False, board_file=None, options: GuiOptions | None = None,
            screenshot=None, timing=False) -> int:
    """Load ``problem``, attach the board (``port`` or the emulator), run the
    window (or, headless, a scripted session for ``screenshot``/``timing``).
    The board is stopped and closed however this ends."""
    from .errors import SceneError
    from .mesh import build_mesh
    from .model import build_model
    from .objective import Targets
    from .scene import load_scene

    headless = screenshot is not None or timing
    if headless and port is not None:
        raise SceneError("--screenshot/--timing drive a scripted session: not on a real board "
                         "(use --emulator, or no board)")
    import matplotlib
    if headless:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    if not headless and plt.get_backend().lower() in NON_INTERACTIVE:
        print(f"plush-opt: error: matplotlib backend {plt.get_backend()!r} cannot open a window "
              "(no display?); set MPLBACKEND to an interactive one (e.g. TkAgg, QtAgg), or use "
              "--screenshot FILE.png", file=sys.stderr)
        return EXIT_INPUT

    scene = load_scene(problem)
    mesh = build_mesh(scene)
    model = build_model(scene, mesh)
    targets = Targets.from_mesh(mesh, scene)
    options = options or GuiOptions()

    driver = emu = None
    try:
        if port is not None or emulator:
            from .board import Driver, Emulator, load_calibration
            path = Path(board_file) if board_file is not None else _default_board_file(scene.name)
            if not path.is_file():
                raise SceneError(f"--board: no calibration file {path}; give one with --board FILE")
            calibration = load_calibration(path)
            missing = [n for n in model.winch_names if n not in calibration.winch_names]
            if missing:
                raise SceneError(f"{path}: no winch {missing[0]!r} (problem winches: "
                                 f"{', '.join(model.winch_names)})")
            if emulator:
                top = 2 * max(w.speed_ticks for w in calibration.winches)
                emu = Emulator(winches=calibration.n_axes_required, speed=top)
                port = emu.start()
            bounds = {n: (float(lo), float(hi))
                      for n, lo, hi in zip(model.winch_names, model.lower, model.upper)}
            driver = Driver(port, calibration, bounds=bounds)
            driver.open()
        board = DriverBoard(driver) if driver is not None else None
        session = PosingSession(model, targets, board, options)
        if headless:
            times = scripted_session(session, screenshot=screenshot, full=timing)
            session.close()
            print(f"{scene.name}: {model.n_nodes} nodes, {model.n_elems} triangles, "
                  f"{model.n_winches} winches; {session.iterates_shown} iterates shown")
            print(timing_table(times))
            if screenshot is not None:
                print(f"wrote {screenshot}")
        else:
            session.show()
    finally:
        if driver is not None:
            driver.close()     # stops the winches first
        if emu is not None:
            emu.close()
    return EXIT_OK


def cmd_gui(args: argparse.Namespace) -> int:
    """``plush-opt gui PROBLEM [--port PORT | --emulator]``."""
    options = GuiOptions(save_path=args.out, send_rate=args.send_rate)
    return run_gui(args.problem, port=args.port, emulator=args.emulator, board_file=args.board,
                   options=options, screenshot=args.screenshot, timing=args.timing)


def main(argv=None) -> int:
    """``python -m plush_opt.gui``: the same as ``plush-opt gui``."""
    from .errors import HardwareError, PlushError, SceneError
    parser = _add_arguments(argparse.ArgumentParser(prog="python -m plush_opt.gui",
                                                    description="Interactive posing window."))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        return cmd_gui(args)
    except SceneError as exc:
        print(f"plush-opt gui: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except HardwareError as exc:
        print(f"plush-opt gui: hardware error: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    except PlushError as exc:
        print(f"plush-opt gui: solver error: {exc}", file=sys.stderr)
        return EXIT_SOLVER
    except KeyboardInterrupt:
        print("plush-opt gui: interrupted", file=sys.stderr)
        return EXIT_INTERRUPT


if __name__ == "__main__":
    sys.exit(main())
