"""Scripted runs: a run script drives the robot through a list of steps.

A run script (``plush-opt-run/1``, read by :mod:`plush_opt.io.run_script`;
the format is in docs/hardware.md) names a problem file, a board
calibration, a streaming rate and a list of steps (set, pose, hold, release).

The control problems are solved by a :class:`Planner` passed in (the
runner never imports a solver). Only certified poses go to the board: a
pose step sends its final pose, or with ``stream`` every certified iterate
that moves a winch, in order, at most ``rate`` per second
(:class:`~plush_opt.apps.run_schedule.PoseDispatch`): the same script sends
the same commands however fast the planner computes them. A dry run's log
is a plan: its times are planned times (moves at top speed, holds, the
stream's period; :class:`~plush_opt.apps.run_schedule.PlannedClock`).
The board is a :class:`~plush_opt.board.BoardLink` (a serial board, a
simulator or a dry run, made by :func:`~plush_opt.board.open_board`).
Every run writes a JSON-lines log, one object per line, flushed and
fsync'ed line by line; a command's line is written before the command is
sent, so a board that never answers still leaves it in the log. The
board is stopped however the run ends.
"""

from __future__ import annotations

import logging
import math
import queue
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from plush_opt.apps.run_log import ProgressLine, RunLog
from plush_opt.apps.run_schedule import PlannedClock, PoseDispatch
from plush_opt.board import BoardCalibration, BoardLink, DryRunLink, load_calibration, open_board
from plush_opt.board.limits import allowed_ranges, check_contractions
from plush_opt.base.errors import HardwareError, SceneError, SolverError, interrupt_status, one_line
from plush_opt.io.problem_file import file_units
from plush_opt.io.run_script import RunScript, Step, load_run_script

log = logging.getLogger(__name__)

PLANNER_GRACE = 10.0       # s beyond 2 * max_time before a silent planner is an error
SETTLE_MARGIN = 2.0        # s added to twice the slowest move when waiting for arrival
TOLERANCE_SLACK = 1e-9     # mm: float rounding of mm -> ticks -> mm, so a winch exactly at its tolerance passes


class Planner(Protocol):
    """What a run needs from the control side (implemented elsewhere).

    ``lower``/``upper`` are the scene's winch bounds, in ``winch_names``
    order. Result dicts have the keys ``contraction`` (``{name: value}``),
    ``objective`` (float), ``converged`` (bool), ``status`` (str) and
    ``certified`` (bool: a certified stable equilibrium within bounds, that
    may go to the robot; a result without it is never sent). The last
    result of :meth:`pose` is the step's pose; ``"time_limited": true`` on
    it says the planner stopped at ``max_time`` rather than by its own rules.
    """

    winch_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray

    def forward(self, contraction: dict[str, float]) -> dict:
        """Equilibrium at these contractions; also the start of the next :meth:`pose`."""

    def pose(self, targets: list[dict], freeze: list[str], max_time: float) -> Iterator[dict]:
        """Control iterates towards ``targets`` (``{"at", "to", "weight"}`` dicts),
        starting from the last contraction solved for, keeping ``freeze`` winches;
        the last one the step's pose."""

    # Optional: ``check_targets(targets)`` raises SceneError (``targets[k].at: ...``)
    # for a target the pose step could never reach (off the body); a run calls
    # it for every pose step before the first command.


@dataclass(frozen=True)
class RunResult:
    """How a run that finished went (an interrupted or failed run raises)."""

    script: str
    log_path: str
    dry_run: bool
    steps: int                          # steps executed
    commands: int                       # contraction commands sent (or, dry, that would be)
    contraction: dict                   # last commanded {name: mm}
    status: str = "completed"
    pose_errors: tuple = ()             # RMS target error at the end of each pose step, mm
    far_poses: tuple = ()               # indices of the pose steps that ended far from their targets

    def to_dict(self) -> dict:
        return {"script": self.script, "log": self.log_path, "dry_run": self.dry_run, "steps": self.steps,
                "pose_errors": list(self.pose_errors), "far_poses": list(self.far_poses),
                "commands": self.commands, "contraction": dict(self.contraction), "status": self.status}


SETTLE_FACTOR = 2.0        # a move may take this many times its time at top speed (ramps, the last ticks)
PLANNER_TIME_FACTOR = 2.0  # a pose step's planner may run this many times its max_time (plus the grace)
WATCHDOG_POLLS = 3         # polls per board watchdog period: one late poll does not trip it


def _script_error(script: RunScript, key: str, message: str):
    raise SceneError(f"{script.path}: {key}: {message}")


def scene_bounds(planner: Planner) -> dict[str, tuple[float, float]]:
    """The scene's winch bounds ``{name: (lower, upper)}`` as the planner reports them."""
    return {n: (float(lo), float(hi)) for n, lo, hi in zip(planner.winch_names, planner.lower, planner.upper)}


def check_run_script(script: RunScript, planner: Planner,
                     calibration: BoardCalibration) -> dict[str, tuple[float, float]]:
    """Check every name and value of the script against the scene (planner)
    and the calibration, before any port is opened. Raises :class:`SceneError`.

    Returns the allowed contraction of every calibrated winch: calibration
    limits within the scene's bounds (see :func:`~plush_opt.board.limits.allowed_ranges`).
    """
    names = tuple(planner.winch_names)
    missing = [n for n in names if n not in calibration.winch_names]
    if missing:
        _script_error(script, "board", f"calibration {calibration.source} has no winch "
                                       f"{', '.join(map(repr, missing))} of problem {script.problem} "
                                       f"(calibrated: {', '.join(calibration.winch_names)})")
    try:
        allowed = allowed_ranges(calibration, scene_bounds(planner))
    except HardwareError as e:
        _script_error(script, "board", str(e))
    for i, step in enumerate(script.steps):
        key = f"steps[{i}].{step.kind}"
        unknown = [n for n in (*step.contraction, *step.freeze) if n not in names]
        if unknown:
            _script_error(script, key, f"unknown winch {unknown[0]!r}; winches of {script.problem.name}: "
                                       f"{', '.join(names)}")
        for name, value in step.contraction.items():
            try:
                check_contractions({name: value}, allowed, calibration)
            except HardwareError as e:
                _script_error(script, f"{key}.{name}", str(e))
        check_targets = getattr(planner, "check_targets", None)
        if step.kind == "pose" and check_targets is not None:
            try:
                check_targets([dict(t) for t in step.targets])
            except SceneError as e:
                _script_error(script, key, str(e))
    return allowed


# ----------------------------------------------------------------- runner --

class _Runner:
    """Executes the steps of one script on an open board link."""

    def __init__(self, script: RunScript, planner: Planner, calibration: BoardCalibration,
                 allowed: dict[str, tuple[float, float]], link: BoardLink, runlog: RunLog,
                 progress: ProgressLine, t0: float):
        self.script = script
        self.planner = planner
        self.calibration = calibration
        self.allowed = allowed
        self.link = link
        self.dry = isinstance(link, DryRunLink)   # nothing moves: no polls, no waiting
        self.log = runlog
        self.progress = progress
        self.names = tuple(planner.winch_names)
        self.lower = {n: float(v) for n, v in zip(self.names, planner.lower)}
        self.upper = {n: float(v) for n, v in zip(self.names, planner.upper)}
        self.period = 1.0 / script.rate
        self.unit = file_units(script.problem).length   # the problem's length unit (board lengths too)
        # Polls also feed the board's watchdog.
        self.poll_period = min(self.period, calibration.port.watchdog_ms / 1000.0 / WATCHDOG_POLLS)
        self.t0 = t0
        self.clock: PlannedClock | None = None   # a dry run's planned time, from start()
        self.commanded: dict[str, float] = {}
        self.planner_at: dict[str, float] | None = None   # contraction the planner last solved for
        self.commands = 0
        self.steps_done = 0
        self.measured: dict[str, float] | None = None
        self._step = None   # (index, kind) for the progress line
        self.pose_errors: list[float] = []
        self.far_poses: list[int] = []

    # -- log lines ---------------------------------------------------------
    def now(self) -> float:
        """s since the run started: planned time in a dry run (0 before its start)."""
        if self.dry:
            return self.clock.t if self.clock is not None else 0.0
        return time.monotonic() - self.t0

    def _line(self, step, kind, event, *, commanded=None, ticks=None, acknowledged=None, info=None, **extra):
        commanded = dict(commanded if commanded is not None else self.commanded)
        info = info or {}
        self.log.write({
            "t": round(self.now(), 4), "step": step, "kind": kind, "event": event,
            "commanded": commanded, "ticks": ticks if ticks is not None else self.calibration.to_ticks(commanded),
            "acknowledged": acknowledged, "measured": self.measured,
            "objective": info.get("objective"), "status": info.get("status"), **extra})
        self._show(event, info)

    def _show(self, event, info):
        i, kind = self._step or (None, "start")
        head = f"[{i + 1}/{len(self.script.steps)}]" if i is not None else "[-]"
        obj = info.get("objective")
        parts = [f"{head} {kind:<7} {event:<8}"]
        if isinstance(obj, (int, float)) and math.isfinite(obj):
            parts.append(f"obj {obj:.3g}")
        for n in self.names:
            c = self.commanded.get(n)
            m = (self.measured or {}).get(n)
            parts.append(f"{n} {c:.1f}" + (f">{m:.1f}" if m is not None else "") if c is not None else n)
        self.progress.update("  ".join(parts) + f" {self.unit}")

    # -- board I/O ---------------------------------------------------------
    def _read(self):
        positions = self.link.positions()
        self.measured = None if positions is None else {n: positions[n] for n in self.names}

    def _send(self, i, kind, contraction, info, **extra):
        full = {**self.commanded, **contraction}
        ticks = check_contractions(full, self.allowed, self.calibration)   # refused before it is logged or sent
        full = {n: float(v) for n, v in full.items()}
        # The line goes out before the command: if the board never answers,
        # the log still shows what was sent.
        self._line(i, kind, "command", commanded=full, ticks=ticks, info=info, **extra)
        self.link.send(full)
        self.commanded = full
        self.commands += 1
        if self.dry:
            self.clock.command(full)
        else:
            self._line(i, kind, "acknowledged", acknowledged=True, info=info)

    def _poll(self, i, kind, info=None):
        self._read()
        self._line(i, kind, "measure", info=info)

    def _settle(self, i, kind, info):
        """Wait, polling, until every winch has arrived: the board says none is
        moving (each within its deadband and at rest) and every measured
        contraction is within its calibrated ``tolerance`` of the command."""
        if self.dry:
            self.clock.settle()
            return
        # the board's own clock: on a loaded machine a simulator runs slower than the wall's
        clock = self.link.clock
        measured = self.measured or {}
        slowest = max((abs(self.commanded[n] - measured.get(n, self.commanded[n])) / self.calibration.winch(n).max_speed
                       for n in self.names), default=0.0)
        timeout = SETTLE_FACTOR * slowest + SETTLE_MARGIN
        deadline = clock() + timeout
        tolerance = {n: self.calibration.winch(n).tolerance for n in self.names}
        while True:
            moving = self.link.moving()
            self._poll(i, kind, info)
            error = {n: self.measured[n] - self.commanded[n] for n in self.names} if self.measured else {}
            off = [n for n, e in error.items() if abs(e) > tolerance[n] + TOLERANCE_SLACK]
            if not moving and not off:
                self._line(i, kind, "arrived", info=info, error=error, tolerance=tolerance)
                log.info("step %d/%d %s: arrived", i + 1, len(self.script.steps), kind)
                return
            if clock() >= deadline:
                at = self.measured or {}
                late = max(off or self.names, key=lambda n: abs(self.commanded[n] - at.get(n, self.commanded[n])))
                where = (f" (at {at[late]:.3f} {self.unit}, tolerance {tolerance[late]:.3f} {self.unit})"
                         if late in at else "")
                why = ("the board holds it there: tolerance below the board's deadband?" if not moving
                       else "tendon jammed or motor stalled?")
                raise HardwareError(f"{self.script.path}: steps[{i}].{kind}: winch {late!r} did not reach "
                                    f"{self.commanded[late]:.3f} {self.unit} within {timeout:.1f} s{where}: {why}")
            time.sleep(self.poll_period)

    def _forward(self, contraction):
        result = self.planner.forward(dict(contraction))
        self.planner_at = dict(contraction)
        return result

    # -- steps -------------------------------------------------------------
    def start(self):
        if not self.dry:
            self._read()
        # Start from where the winches are (0 when unknown), as far as the scene allows.
        at = self.measured or {}
        start = {n: min(max(at.get(n, 0.0), self.lower[n]), self.upper[n]) for n in self.names}
        self.commanded = start
        if self.dry:
            self.clock = PlannedClock({n: self.calibration.winch(n).max_speed for n in self.names}, start)
        info = self._forward(start)
        self._line(None, "start", "start", info=info, script=str(self.script.path), problem=str(self.script.problem),
                   board=str(self.script.board), dry_run=self.dry, rate=self.script.rate,
                   winches=list(self.names), clock="planned" if self.dry else "measured")

    def run_step(self, i: int, step: Step):
        self._step = (i, step.kind)
        log.info("step %d/%d %s: %s", i + 1, len(self.script.steps), step.kind, _describe_step(step, self.unit))
        getattr(self, f"_step_{step.kind}")(i, step)
        self.steps_done += 1

    def _step_set(self, i, step):
        target = {**self.commanded, **step.contraction}
        info = self._forward(target)
        self._send(i, "set", target, info)
        self._settle(i, "set", info)

    def _step_release(self, i, step):
        target = dict(self.lower)
        info = self._forward(target)
        self._send(i, "release", target, info)
        self._settle(i, "release", info)

    def _step_hold(self, i, step):
        if self.dry:
            self._line(i, "hold", "hold", seconds=step.seconds)
            self.clock.wait(step.seconds)
            return
        end = time.monotonic() + step.seconds
        while True:
            self._poll(i, "hold")
            remaining = end - time.monotonic()
            if remaining <= 0:
                return
            time.sleep(min(self.poll_period, remaining))

    def _step_pose(self, i, step):
        if self.planner_at != self.commanded:
            self._forward(self.commanded)   # the planner starts where the robot is
        iterates: queue.SimpleQueue = queue.SimpleQueue()
        cancel = threading.Event()
        targets, freeze = [dict(t) for t in step.targets], list(step.freeze)

        def work():
            # The planner runs beside the I/O loop, so that a slow iterate
            # never starves the board's watchdog.
            try:
                for it in self.planner.pose(targets, freeze, step.max_time):
                    iterates.put(("iterate", it))
                    if cancel.is_set():
                        return
                iterates.put(("done", None))
            except BaseException as e:  # handed to the main thread
                iterates.put(("error", e))

        worker = threading.Thread(target=work, name="plush-opt-planner", daemon=True)
        worker.start()
        try:
            self._stream(i, step, iterates, PoseDispatch(f"{self.script.path}: steps[{i}].pose", step.stream,
                                                         self.commanded, step.max_time))
        finally:
            cancel.set()

    def _stream(self, i, step, iterates, dispatch: PoseDispatch):
        """Send the step's commands as ``dispatch`` picks them, in order and
        at most ``rate`` per second, polling the board in between."""
        period, poll = self.period, self.poll_period
        budget = PLANNER_TIME_FACTOR * step.max_time + PLANNER_GRACE
        deadline = time.monotonic() + budget
        outbox: deque = deque()
        last_send, last_io = -math.inf, time.monotonic()
        done = False
        while True:
            now = time.monotonic()
            if outbox and (self.dry or now - last_send >= period):
                k, result = outbox.popleft()
                if self.dry and last_send > -math.inf:
                    self.clock.wait(period)      # a stream's commands are one period apart
                self._send(i, "pose", result.get("contraction", {}), result, iteration=k,
                           converged=result.get("converged"))
                last_send = last_io = time.monotonic()
            elif not self.dry and now - last_io >= poll:
                self._poll(i, "pose", dispatch.latest)
                last_io = time.monotonic()
            if done and not outbox:
                break
            if not done and time.monotonic() > deadline:
                raise SolverError(f"{self.script.path}: steps[{i}].pose: the planner did not finish within "
                                  f"{budget:g} s (max_time {step.max_time:g} s)")
            if self.dry:
                due = time.monotonic() if outbox else deadline
            else:
                due = min(last_send + period if outbox else math.inf, last_io + poll)
            wait = max(0.0, min(due, deadline) - time.monotonic())
            if done:
                time.sleep(wait)
                continue
            try:
                kind, payload = iterates.get(timeout=wait)
            except queue.Empty:
                continue
            if kind == "iterate":
                outbox.extend(dispatch.take(payload))
            elif kind == "done":
                done = True
                outbox.extend(dispatch.finish())
            else:
                raise payload
        if dispatch.latest is None:
            self._line(i, "pose", "no-iterate", info={"status": "planner produced no iterate"})
            return
        self.planner_at = dict(self.commanded)  # the final pose, where the planner stopped
        self._pose_report(i, dispatch.latest)
        self._settle(i, "pose", dispatch.latest)

    def _pose_report(self, i, result):
        """Say how far the pose step ended from its targets; warn when far."""
        err, far = result.get("rms_error"), result.get("far_error")
        if err is None:
            return
        self.pose_errors.append(float(err))
        n = len(self.script.steps)
        if far is not None and err > far:
            self.far_poses.append(i)
            log.warning("%s: steps[%d].pose ended %.3g %s RMS from its targets (more than %.3g %s; %s)",
                        self.script.path.name, i, err, self.unit, far, self.unit, result.get("status"))
        else:
            log.info("step %d/%d pose: %s; %.3g %s RMS from its targets", i + 1, n, result.get("status"), err,
                     self.unit)


def _describe_step(step: Step, unit: str) -> str:
    if step.kind == "set":
        return ", ".join(f"{n} {v:g} {unit}" for n, v in step.contraction.items())
    if step.kind == "pose":
        return f"solving for {len(step.targets)} target(s), at most {step.max_time:g} s"
    if step.kind == "hold":
        return f"{step.seconds:g} s"
    return "every winch to its lower bound"


def default_log_path(script: RunScript) -> Path:
    return Path("out") / "runs" / f"{script.path.stem}-{time.strftime('%Y%m%d-%H%M%S')}.jsonl"


def _board_choice(script: RunScript, calibration: BoardCalibration, port, simulator, dry_run: bool) -> dict:
    """``open_board`` keywords for the board asked for; a serial port
    defaults to the calibration's ``port.device``."""
    if dry_run:
        return {}
    if simulator is not None:
        return {"simulator": simulator, "port": port}
    port = port if port is not None else calibration.port.device
    if port is None:
        raise HardwareError(f"{script.path}: no board to run on: give a serial port (--port), a simulator "
                            f"(--emulator, --simavr) or --dry-run, or set port.device in {calibration.source}")
    return {"port": port}


def _release(link: BoardLink, own: bool, failing: bool) -> None:
    """Stop the board (and close it if the run opened it). A failure to stop
    does not hide the error that ended the run; it is logged instead."""
    try:
        if own:
            link.close()
        else:
            link.stop()
    except HardwareError as e:
        if not failing:
            raise
        log.error("could not stop the board after the run failed: %s", e)


def _play(runner: _Runner, own: bool) -> None:
    """Every step of the script; the board is stopped on every exit."""
    try:
        runner.start()
        for i, step in enumerate(runner.script.steps):
            runner.run_step(i, step)
    except BaseException:
        _release(runner.link, own, failing=True)
        raise
    _release(runner.link, own, failing=False)


def _end_line(runner: _Runner | None, calibration: BoardCalibration, t0: float, status: str) -> dict:
    commanded = runner.commanded if runner is not None else {}
    return {"t": round(runner.now() if runner is not None else time.monotonic() - t0, 4), "step": None, "kind": "end", "event": "end",
            "commanded": commanded, "ticks": calibration.to_ticks(commanded), "acknowledged": None,
            "measured": runner.measured if runner is not None else None, "objective": None, "status": status,
            "steps_done": runner.steps_done if runner is not None else 0,
            "commands": runner.commands if runner is not None else 0}


def _write_end(runlog: RunLog, line: dict, failing: bool, cause: BaseException | None = None) -> None:
    """The log's last line. If it cannot be written (a full disk) while
    another error ends the run, that error is the one reported (alone when
    it is this log's own write error: the same trouble, said once)."""
    try:
        runlog.write(line)
    except OSError as e:
        if not failing:
            raise
        if isinstance(cause, OSError) and cause.filename == e.filename:
            return
        log.error("%s", one_line(f"{e.filename}: could not write the run's end line: {e.strerror or e}"))


def run_script(script_path, board: BoardLink | None = None, *, port: str | None = None,
               simulator: str | None = None, dry_run: bool = False, log_path=None, planner: Planner | None = None,
               progress: bool | None = None) -> RunResult:
    """Run a run script on a board.

    Parameters
    ----------
    script_path : path or RunScript
        The run script (``plush-opt-run/1``).
    board : BoardLink, optional
        An open link (see :func:`~plush_opt.board.open_board`); it is
        stopped, not closed, at the end. Made from the script's calibration
        with ``port`` or ``simulator`` when not given.
    port : str, optional
        Serial port of the board; default the calibration's ``port.device``.
    simulator : {None, "emulator", "simavr"}
        Run on a simulated board started for this run (and stopped after it).
    dry_run : bool
        Compute and log everything, move nothing (``board``, ``port`` and
        ``simulator`` are ignored).
    log_path : path, optional
        JSON-lines log; default ``out/runs/<script>-<time>.jsonl``.
    planner : Planner
        Solves the forward and control problems of the script's problem.
    progress : bool, optional
        Show a progress line on stderr; default: when stderr is a terminal.

    Returns a :class:`RunResult`. The board is stopped on every exit; an
    interrupted (KeyboardInterrupt) or failed run re-raises after writing
    the log's last line (``"kind": "end"``, ``status``).

    Log lines are JSON objects with keys ``t`` (s since start), ``step``
    (index or null), ``kind`` (step kind, ``start`` or ``end``), ``event``,
    ``commanded`` ({winch: mm}), ``ticks`` ({winch: ticks}),
    ``acknowledged`` (true on the line that follows a command the board
    said OK to; null elsewhere), ``measured`` ({winch: mm}, null in a dry
    run), ``objective``, ``status``.
    """
    if planner is None:
        raise TypeError("run_script needs a planner (see plush_opt.apps.runs.Planner)")
    script = script_path if isinstance(script_path, RunScript) else load_run_script(script_path)
    own = board is None or dry_run
    # A given link converts with its own calibration; otherwise the script's is read, once.
    calibration = None if own else getattr(board, "calibration", None)
    calibration = calibration or load_calibration(script.board)
    allowed = check_run_script(script, planner, calibration)
    choice = _board_choice(script, calibration, port, simulator, dry_run) if own else None

    if progress is None:
        progress = sys.stderr.isatty()
    path = Path(log_path) if log_path is not None else default_log_path(script)
    status, runner, t0, ended_by, cause = "error", None, time.monotonic(), {}, None
    with RunLog(path) as runlog:
        try:
            link = open_board(calibration, bounds=allowed, **choice) if own else board
            runner = _Runner(script, planner, calibration, allowed, link, runlog,
                             ProgressLine(sys.stderr, progress), t0)
            _play(runner, own)
            status = "completed"
        except KeyboardInterrupt as e:
            status, ended_by = "interrupted", {"signal": interrupt_status(e)[0]}
            raise
        except BaseException as e:
            status, cause = one_line(f"error: {e}"), e
            raise
        finally:
            # The board is stopped by now.
            if runner is not None:
                runner.progress.finish()
            _write_end(runlog, {**_end_line(runner, calibration, t0, status), **ended_by},
                       failing=status != "completed", cause=cause)
    return RunResult(script=str(script.path), log_path=str(path), dry_run=runner.dry, steps=runner.steps_done,
                     commands=runner.commands, contraction=dict(runner.commanded),
                     pose_errors=tuple(runner.pose_errors), far_poses=tuple(runner.far_poses))
