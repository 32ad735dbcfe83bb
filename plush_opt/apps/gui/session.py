"""The posing session, without a window: the state the posing window shows
and everything that changes it.

It holds the pose on screen with the history it follows
(:class:`~.pose.ShownPose`: the session's fork of the problem's plant,
committed at every pose shown), the frozen set, the targets, the anytime control
loop (:meth:`PosingSession.tick` takes *one* iterate, never the whole
solve) and the board (through a :class:`BoardPacer`). The matplotlib
window (:mod:`.view`) calls into it; tests drive it directly, without
matplotlib.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from pathlib import Path

import numpy as np

from ...board.link import BoardLink
from ...solve.equilibrium import Equilibrium
from ...base.errors import SolverError
from ...fem.objective import Targets
from .options import GuiOptions
from .pacing import BoardPacer
from .pose import ShownPose

log = logging.getLogger(__name__)

# iterate durations kept for the timing table (a long session does not grow)
TIMES_KEPT = 100_000
# iterate clock times kept for the status line's rate (more than the timer
# can produce within GuiOptions.rate_window)
RATE_TIMES_KEPT = 128
class AnytimeLoop:
    """The anytime gradient loop of a session, stepped one iterate at a time.

    A :class:`~plush_opt.control.gradient.Controller` is made on the first
    step from the pose on screen; a target or frozen-set change is passed
    on to it (the loop continues from the current pose), or, once its
    history holds ``max_history`` iterates, the next step starts a fresh one.
    The controller drives the session's ``plant`` from the state on screen
    (its committed state) and commits every iterate: where the pose depends
    on the path, every iterate is a state the robot reaches when driven
    through the iterates in order.

    Attributes
    ----------
    controller : the running Controller, or None.
    finished : the loop stopped and nothing changed since.
    last_iterate : the last iterate taken, or None.
    iterate_seconds : wall time of each iterate taken (for timing tables).
    """

    def __init__(self, model, options, max_history: int, plant=None):
        self.model = model
        self.plant = plant
        self.options = options
        self.max_history = max_history
        self.controller = None
        self.finished = False
        self.last_iterate = None
        self.iterate_seconds = deque(maxlen=TIMES_KEPT)
        self._iterates = None          # the running generator of controller iterates

    def drop(self) -> None:
        """Forget the controller: the next step starts from the pose on screen."""
        self.close()
        self.controller = None
        self.last_iterate = None
        self.finished = False

    def close(self) -> None:
        if self._iterates is not None:
            self._iterates.close()
        self._iterates = None

    def set_targets(self, targets: Targets) -> None:
        self.finished = False
        if self.controller is not None:
            if len(self.controller.history) >= self.max_history:
                self.drop()
            else:
                self.controller.set_targets(targets)

    def set_frozen(self, i: int, frozen: bool) -> None:
        self.finished = False
        if self.controller is not None:
            self.controller.set_frozen(i, frozen)

    def step(self, targets: Targets, contraction, frozen, shown: Equilibrium):
        """Take one iterate (starting a controller if there is none at the
        equilibrium ``shown``, the plant's committed state). Returns it, or
        None when the loop has stopped (``finished``). Raises SolverError
        (after dropping the controller) when the loop cannot start."""
        from ...control.gradient import Controller
        try:
            if self.controller is None:
                self.controller = Controller(self.model, targets, contraction, frozen, shown.x, self.options,
                                             plant=self.plant)
            if self._iterates is None:
                self._iterates = self.controller.iterates()
            t0 = time.perf_counter()
            try:
                it = next(self._iterates)
            finally:
                self.iterate_seconds.append(time.perf_counter() - t0)
        except StopIteration:
            self._iterates = None
            self.finished = True
            return None
        except SolverError:
            self.drop()
            raise
        self.last_iterate = it
        return it


class PosingSession:
    """The state of a posing session and the operations on it.

    Parameters
    ----------
    problem : :class:`~plush_opt.problem.Problem`
        Its targets are shown at start; the loop is *held* at start when
        there are some: :meth:`toggle_pause`, or a target edit, runs it.
    board : :class:`~plush_opt.board.link.BoardLink`, optional
        The robot. The session stops it on :meth:`shutdown`; closing the
        link is the caller's business.
    options : :class:`GuiOptions`
    clock : callable returning seconds (``time.monotonic``): paces the board, counts iterates.

    Attributes
    ----------
    pose : the :class:`~.pose.ShownPose`, the pose on screen and the history
        it follows; read through to it: ``equilibrium`` (a forward solve
        may not have converged: see its ``converged`` and ``status``),
        ``contraction`` ((n_winches,), length units), ``x``,
        ``forward_solves``, ``solve_seconds``.
    targets : the current :class:`~plush_opt.fem.objective.Targets`.
    frozen : (n_winches,) bool.
    paused : the user paused the loop.
    held : the loop waits for a target edit or :meth:`toggle_pause` (after
        a contraction change, a reset, or at start with the problem's targets).
    message : what just happened, for the user.
    loop : the :class:`AnytimeLoop` (``controller``, ``finished``,
        ``last_iterate``, ``iterate_seconds`` read through to it).
    iterates_shown : count.
    iterate_clock : clock times of the last iterates shown (for the rate).
    """

    def __init__(self, problem, board: BoardLink | None = None, options: GuiOptions | None = None,
                 *, clock=time.monotonic):
        self.problem = problem
        self.model = problem.model
        self.options = options or GuiOptions()
        self.clock = clock
        self.board = board
        self.pacer = None if board is None else BoardPacer(
            board, clock, send_rate=self.options.send_rate, poll_rate=self.options.poll_rate)
        self.control_options = self.options.control_options()
        self.equilibrium_options = self.options.equilibrium_options()
        self.targets = problem.targets
        self.frozen = problem.scene.frozen.copy()
        self.paused = False
        self.held = self.targets.n_targets > 0
        self.closed = False
        self.message = ("loop held: press space or drag a target to run it"
                        if self.held else "drag the body to pose it")
        self.pose = ShownPose(problem.plant.fork(), self.equilibrium_options)
        self.loop = AnytimeLoop(self.model, self.control_options, self.options.max_history, self.pose.plant)
        self.iterates_shown = 0
        self.iterate_clock = deque(maxlen=RATE_TIMES_KEPT)
        self._t_start = time.perf_counter()
        self._show(self.pose.forward(problem.scene.contraction, None))

    # ------------------------------------------------------------ state

    # the pose on screen, as the window, the status line and the tests see it
    equilibrium = property(lambda self: self.pose.equilibrium)
    contraction = property(lambda self: self.pose.contraction)
    x = property(lambda self: self.pose.x, doc="(n_dofs,) flat pose on screen.")
    forward_solves = property(lambda self: self.pose.forward_solves)
    solve_seconds = property(lambda self: self.pose.solve_seconds)

    @property
    def winch_names(self) -> tuple[str, ...]:
        return tuple(self.model.winch_names)

    @property
    def running(self) -> bool:
        """The next tick will take an iterate."""
        return (not self.paused and not self.held and not self.finished and not self.closed
                and self.targets.n_targets > 0)

    @property
    def state(self) -> str:
        """The loop's state as the status line names it."""
        return ("paused" if self.paused else "held" if self.held
                else "no targets" if not self.targets.n_targets
                else "stopped" if self.finished else "running")

    @property
    def contraction_by_name(self) -> dict[str, float]:
        return {n: float(c) for n, c in zip(self.winch_names, self.contraction)}

    @property
    def seconds_open(self) -> float:
        """Wall time since the session opened (s)."""
        return time.perf_counter() - self._t_start

    # the loop and the board, as the window, the status line and the tests see them
    controller = property(lambda self: self.loop.controller)
    finished = property(lambda self: self.loop.finished)
    last_iterate = property(lambda self: self.loop.last_iterate)
    iterate_seconds = property(lambda self: self.loop.iterate_seconds)
    sends = property(lambda self: 0 if self.pacer is None else self.pacer.sends)
    measured = property(lambda self: None if self.pacer is None else self.pacer.measured)
    board_error = property(lambda self: None if self.pacer is None else self.pacer.error)

    def index(self, name_or_index) -> int:
        """A winch's index from its name (or index)."""
        if isinstance(name_or_index, str):
            if name_or_index not in self.winch_names:
                raise KeyError(f"no winch {name_or_index!r}; winches: {', '.join(self.winch_names)}")
            return self.winch_names.index(name_or_index)
        return int(name_or_index)

    def _show(self, eq: Equilibrium) -> None:
        """Put ``eq`` on screen and queue it for the board."""
        self.pose.show(eq)
        if self.pacer is not None:
            self.pacer.queue(self.contraction_by_name)
        self._service_board()

    def _targets_changed(self) -> None:
        """New targets: the loop continues from the pose on screen."""
        self.held = False
        self.loop.set_targets(self.targets)

    # ------------------------------------------- mode 1: contractions

    def set_contraction(self, name_or_index, value: float) -> None:
        """Set one winch's contraction: the forward pose is re-solved at
        once, warm-started from the pose on screen. Holds the loop (a
        target edit or :meth:`toggle_pause` runs it again)."""
        i = self.index(name_or_index)
        c = self.contraction.copy()
        c[i] = float(np.clip(value, self.model.lower[i], self.model.upper[i]))
        if c[i] == self.contraction[i]:
            return
        eq = self.pose.forward(c, self.x)
        self.loop.drop()
        if self.targets.n_targets and not self.paused:
            self.held = True
        name, mm = self.winch_names[i], self.model.scene.units.length
        if eq.converged:
            self.message = (f"{name} = {c[i]:.3f} {mm}: forward pose"
                            + (" (loop held: space or a target edit runs it)" if self.held else ""))
        else:
            self.message = f"{name} = {c[i]:.3f} {mm}: forward solve: {eq.status}"
        self._show(eq)

    # ------------------------------------------------- mode 3: freeze

    def set_frozen(self, name_or_index, frozen: bool = True) -> None:
        """Freeze (or release) a winch: the loop keeps a frozen winch's
        contraction bit for bit."""
        i = self.index(name_or_index)
        frozen = bool(frozen)
        if self.frozen[i] == frozen:
            return
        self.frozen[i] = frozen
        self.loop.set_frozen(i, frozen)
        self.message = f"{self.winch_names[i]} {'frozen' if frozen else 'released'}"

    # ------------------------------------------------ mode 2: targets

    def locate(self, point, tol: float = 0.0):
        """The body point under ``point`` (current coordinates), found by
        inverting the current deformation: the deformed triangle holding it
        and its barycentric weights, which are also the point's weights in
        the rest triangle. Returns (triangle, beta) or None off the body.
        Points within ``tol`` (length units) of the body snap onto its edge."""
        from ...base.geometry import locate_in_triangles
        nodes = self.x.reshape(-1, 2)
        tri, beta = locate_in_triangles(nodes[self.model.mesh.triangles],
                                        np.asarray(point, dtype=np.float64).reshape(1, 2), tol=tol)
        if tri[0] < 0:
            return None
        b = np.clip(beta[0], 0.0, None)
        return int(tri[0]), b / b.sum()

    def add_target(self, triangle: int, beta, to) -> int:
        """A target for body point (triangle, beta) going to ``to``; returns its index."""
        self.targets = with_target(self.targets, self.model.mesh, triangle, beta, to,
                                   self.options.target_weight)
        k = self.targets.n_targets - 1
        rest = ", ".join(f"{v:.1f}" for v in rest_point(self.model, triangle, beta))
        self.message = f"target {k + 1} at rest point ({rest}) \u2192 ({to[0]:.1f}, {to[1]:.1f})"
        self._targets_changed()
        return k

    def move_target(self, k: int, to) -> None:
        """Send target ``k`` somewhere else."""
        q = self.targets.to.copy()
        q[k] = np.asarray(to, dtype=np.float64)
        self.targets = self.targets.replace_to(q)
        self.message = f"target {k + 1} \u2192 ({q[k, 0]:.1f}, {q[k, 1]:.1f})"
        self._targets_changed()

    def remove_target(self, k: int) -> None:
        """Remove target ``k``."""
        self.targets = without_target(self.targets, k)
        self.message = f"target {k + 1} removed"
        self._targets_changed()

    # ---------------------------------------------------------- keys

    def toggle_pause(self) -> None:
        """Pause a running loop; run a paused or held one."""
        if self.paused or self.held:
            self.paused = self.held = False
            self.message = ("loop running" if self.targets.n_targets
                            else "no targets: drag the body to pose it")
        else:
            self.paused = True
            self.message = "paused: space runs the loop again"

    def halt(self, message: str) -> None:
        """Pause the loop after an error, saying so."""
        self.paused = True
        self.message = message

    def reset(self) -> None:
        """Back to the scene's contractions, no targets (frozen flags stay);
        driven there from the state on screen where the pose depends on the
        path (history stays)."""
        self.loop.drop()
        self.targets = Targets.empty()
        self.held = False
        self._show(self.pose.forward(self.problem.scene.contraction, None))
        self.message = "reset: scene contractions, targets cleared"

    # ---------------------------------------------------------- loop

    def tick(self):
        """One step of the session: at most one control iterate, then the
        board. Returns the iterate shown, or None."""
        shown = self._step() if self.running else None
        if shown is None:
            self._service_board()
        return shown

    def _step(self):
        t0 = time.perf_counter()
        try:
            it = self.loop.step(self.targets, self.contraction, self.frozen, self.equilibrium)
        except SolverError as exc:
            self.held = True
            self.message = f"loop cannot start: {exc}"
            return None
        finally:
            self.pose.solve_seconds += time.perf_counter() - t0
        if it is None:
            self.message = f"loop stopped: {self.controller.status}"
            return None
        self.iterates_shown += 1
        self.iterate_clock.append(self.clock())
        self._show(it.equilibrium)
        return it

    def _service_board(self) -> None:
        if self.pacer is None or self.closed:
            return
        error = self.pacer.service()
        if error is not None:
            self.message = f"board error: {error}; nothing more is sent"

    # ------------------------------------------------------ results

    def certified(self) -> Equilibrium:
        """The pose on screen with its smallest Hessian eigenvalue (:meth:`~.pose.ShownPose.certified`)."""
        return self.pose.certified()

    def result(self) -> dict:
        """The result document (results.result_dict) of the pose on screen."""
        return result_document(self)

    def save(self, path=None) -> Path:
        """Write the result JSON atomically; returns its path. Default path:
        ``options.save_path``, else ``out/gui-<timestamp>.json``."""
        from ...base.files import write_json_atomic
        path = Path(path or self.options.save_path or timestamped(Path("out"), "gui"))
        write_json_atomic(path, self.result())
        self.message = f"saved {path}"
        log.info("saved %s", path)
        return path

    def shutdown(self) -> None:
        """Stop the loop and the winches (idempotent)."""
        if self.closed:
            return
        self.closed = True
        self.loop.close()
        if self.pacer is not None:
            self.pacer.stop()


def rest_point(model, triangle: int, beta) -> np.ndarray:
    """Rest coordinates of the body point (triangle, beta), (2,)."""
    return np.asarray(beta) @ model.X.reshape(-1, 2)[model.mesh.triangles[triangle]]


def iterate_rate(session: PosingSession) -> float:
    """Iterates per second over the last ``options.rate_window`` seconds."""
    now = session.clock()
    recent = [t for t in session.iterate_clock if now - t <= session.options.rate_window]
    if len(recent) < 2 or recent[-1] <= recent[0]:
        return 0.0
    return (len(recent) - 1) / (recent[-1] - recent[0])


def with_target(targets: Targets, mesh, triangle: int, beta, to, weight: float) -> Targets:
    """``targets`` plus one for body point (triangle, beta) going to ``to``."""
    tri = np.append(targets.triangles, int(triangle))
    return Targets(tri, mesh.elements[tri], np.vstack([targets.beta, np.reshape(beta, (1, 3))]),
                   np.vstack([targets.to, np.reshape(to, (1, 2))]),
                   np.append(targets.weight, weight))


def without_target(targets: Targets, k: int) -> Targets:
    """``targets`` without target ``k``."""
    keep = np.arange(targets.n_targets) != k
    return Targets(targets.triangles[keep], targets.nodes[keep], targets.beta[keep],
                   targets.to[keep], targets.weight[keep])


def result_document(session: PosingSession) -> dict:
    """The result document of the pose on screen: ``reparam`` with targets
    (converged only if the loop stopped converged and the pose is
    certified), ``forward`` without; a ``gui`` section holds the frozen
    winches, the targets' rest points and the board's state."""
    from ...solve.result_file import result_dict
    eq = session.certified()
    ctl = session.controller
    if session.targets.n_targets:
        method = "reparam"   # the gradient loop; its bound handling is in extra["gui"]
        loop_done = ctl is not None and session.finished and ctl.converged
        converged = bool(eq.converged and loop_done)
        status = (f"interactive session, loop {session.state}"
                  + (f": {ctl.status}" if ctl is not None else ""))
        if not eq.converged:
            status += f"; pose: {eq.status}"
        iterations = len(ctl.history) - 1 if ctl is not None else 0
    else:
        method, converged, status, iterations = "forward", eq.converged, eq.status, eq.iterations
    t = session.targets
    extra = {"gui": {
        "bounds": session.control_options.bounds,
        "frozen": [n for n, f in zip(session.winch_names, session.frozen) if f],
        "targets_rest": [rest_point(session.model, e, b).tolist() for e, b in zip(t.triangles, t.beta)],
        "board": None if session.pacer is None else session.pacer.state(),
    }}
    return result_dict(session.model, t, eq, method=method, converged=converged, status=status,
                       total_s=session.seconds_open,
                       solve_s=session.solve_seconds, iterations=iterations, extra=extra)


def status_line(session: PosingSession) -> str:
    """The status line: loop state, objective, residual, rate, bounds held,
    frozen winches, board."""
    eq, t, units = session.equilibrium, session.targets, session.model.scene.units
    parts = [f"loop {session.state:<10}"]
    if t.n_targets:
        parts.append(f"O {t.value(session.x):.3e} {units.length}\u00b2 "
                     f"(rms {t.rms_error(session.x):.2f} {units.length},"
                     f" {t.n_targets} target{'s' if t.n_targets > 1 else ''})")
    else:
        parts.append("O -")
    parts.append(f"residual {eq.residual_norm:.1e} {units.force}{'' if eq.converged else ' (NOT converged)'}")
    parts.append(f"{iterate_rate(session):5.1f} it/s")
    bounds = session.last_iterate.active_bounds if session.last_iterate is not None else ()
    parts.append(f"bounds: {', '.join(bounds) if bounds else '-'}")
    frozen = [n for n, f in zip(session.winch_names, session.frozen) if f]
    parts.append(f"frozen: {', '.join(frozen) if frozen else '-'}")
    parts.append(tension_text(session))
    pacer = session.pacer
    if pacer is None:
        parts.append("board: none")
    elif pacer.error is not None:
        parts.append("board: ERROR (stopped)")
    elif session.closed:
        parts.append("board: stopped")
    else:
        lag = pacer.lag(session.contraction_by_name)
        parts.append(f"board: {pacer.sends} sent" + ("" if lag is None else f", lag {lag:.2f} {units.length}"))
    return "  |  ".join(parts)


def tension_text(session: PosingSession) -> str:
    """Tendon tensions for the status line, stopper end first: one number
    for a tendon whose segments all pull the same (no friction), its
    segments' tensions joined by '/' where friction at via points makes
    them differ."""
    segments = session.pose.plant.segment_table(session.equilibrium)
    parts = []
    for t, seg in zip(session.model.scene.tendons, segments):
        T = seg["segment_tensions"]
        parts.append(f"{t.name} " + (f"{T[0]:.3g}" if max(T) == min(T) else "/".join(f"{v:.3g}" for v in T)))
    return f"T [{session.model.scene.units.force}]: " + (", ".join(parts) if parts else "-")


def timestamped(folder: Path, stem: str) -> Path:
    """``folder/stem-<date>-<time>.json``, made unique with a counter."""
    base = folder / f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    path, k = base.with_suffix(".json"), 2
    while path.exists():
        path = folder / f"{base.name}-{k}.json"
        k += 1
    return path
