"""Scripted runs: a run script drives the robot through a list of steps.

A run script (YAML, format ``plush-opt-run/1``, see docs/hardware.md)
names a problem file, a board calibration, a streaming rate and steps::

    format: plush-opt-run/1
    problem: ../problems/gripper.yaml     # relative to the script
    board: ../hw/boards/gripper.yaml
    rate: 20                              # Hz, at most this many commands per second
    steps:
      - set: {grip: 10.0}                 # contractions, mm; other winches keep theirs
      - pose: {targets: [{at: [-78, 122], to: [-74, 80], weight: 1}], freeze: [grip], max_time: 5}
      - hold: 1.5                         # seconds
      - release                           # every winch back to its lower bound

The control problems are solved by a :class:`Planner` passed in (the
runner never imports a solver); its iterates are streamed to the board at
most at ``rate`` (the latest iterate wins, the final one is always sent).
Every run writes a JSON-lines log, one object per line, flushed and
fsync'ed line by line, and stops the board however it ends.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import queue
import shutil
import stat
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from plush_opt.board.calibration import BoardCalibration, load_calibration
from plush_opt.board.driver import Driver
from plush_opt.board.emulator import Emulator
from plush_opt.errors import HardwareError, SolverError
from plush_opt.io import Checker
from plush_opt.io.run_script import RunScript, Step, load_run_script

log = logging.getLogger(__name__)

PLANNER_GRACE = 10.0       # s beyond 2 * max_time before a silent planner is an error
SETTLE_MARGIN = 2.0        # s added to twice the slowest move when waiting for arrival


class Planner(Protocol):
    """What a run needs from the control side (implemented elsewhere).

    ``lower``/``upper`` are the scene's winch bounds, in ``winch_names``
    order. Result dicts have the keys ``contraction`` (``{name: value}``),
    ``objective`` (float), ``converged`` (bool) and ``status`` (str).
    """

    winch_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray

    def forward(self, contraction: dict[str, float]) -> dict:
        """Equilibrium at these contractions; also the start of the next :meth:`pose`."""

    def pose(self, targets: list[dict], freeze: list[str], max_time: float) -> Iterator[dict]:
        """Control iterates towards ``targets`` (``{"at", "to", "weight"}`` dicts),
        starting from the last contraction solved for, keeping ``freeze`` winches;
        each a stable equilibrium within bounds."""


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

    def to_dict(self) -> dict:
        return {"script": self.script, "log": self.log_path, "dry_run": self.dry_run, "steps": self.steps,
                "commands": self.commands, "contraction": dict(self.contraction), "status": self.status}


def _fail(source, key: str, message: str):
    Checker(source).fail(key, message)


def _allowed(planner: Planner, calibration: BoardCalibration) -> dict[str, tuple[float, float]]:
    """Per scene winch: scene bounds within calibration limits."""
    out = {}
    for name, lo, hi in zip(planner.winch_names, planner.lower, planner.upper):
        w = calibration.winch(name)
        out[name] = (max(float(lo), w.limits[0]), min(float(hi), w.limits[1]))
    return out


def check_run_script(script: RunScript, planner: Planner, calibration: BoardCalibration) -> None:
    """Check every name and value of the script against the scene (planner)
    and the calibration, before any port is opened. Raises :class:`SceneError`."""
    names = tuple(planner.winch_names)
    missing = [n for n in names if n not in calibration.winch_names]
    if missing:
        _fail(script.path, "board", f"calibration {calibration.source} has no winch {', '.join(map(repr, missing))} "
                                    f"of problem {script.problem} (calibrated: {', '.join(calibration.winch_names)})")
    allowed = _allowed(planner, calibration)
    for name, (lo, hi) in allowed.items():
        if lo > hi:
            _fail(script.path, "board", f"winch {name!r}: scene bounds and calibration limits "
                                        f"{calibration.winch(name).limits} do not overlap")
    for i, step in enumerate(script.steps):
        key = f"steps[{i}].{step.kind}"
        unknown = [n for n in (*step.contraction, *step.freeze) if n not in names]
        if unknown:
            _fail(script.path, key, f"unknown winch {unknown[0]!r}; winches of {script.problem.name}: "
                                    f"{', '.join(names)}")
        for name, value in step.contraction.items():
            lo, hi = allowed[name]
            if not lo <= value <= hi:
                _fail(script.path, f"{key}.{name}", f"{value:g} is outside [{lo:g}, {hi:g}] (scene bounds "
                                                    f"within calibration limits)")


# -------------------------------------------------------------------- log --

def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None  # strict JSON has no NaN
    if x is None or isinstance(x, str):
        return x
    return str(x)


class RunLog:
    """JSON-lines file; every line is written whole, flushed and fsync'ed,
    so a crash or Ctrl-C leaves only complete lines."""

    def __init__(self, path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb", buffering=0)
        # A pipe or /dev/null cannot be fsync'ed, and needs not be.
        self._sync = stat.S_ISREG(os.fstat(self._f.fileno()).st_mode)
        self.lines = 0

    def write(self, obj: dict) -> None:
        data = memoryview((json.dumps(_jsonable(obj), allow_nan=False, separators=(",", ":"))
                           + "\n").encode())
        while data:   # an unbuffered write may take only part of the line
            written = self._f.write(data)
            if not written:
                raise OSError(f"{self.path}: could not write the run log")
            data = data[written:]
        if self._sync:
            os.fsync(self._f.fileno())
        self.lines += 1

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class _Progress:
    """One updating status line on a terminal (the CLI's progress display)."""

    def __init__(self, stream, enabled: bool):
        self.stream = stream
        self.enabled = enabled
        self._shown = False
        self._last = 0.0

    def update(self, text: str) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < 0.1:
            return
        self._last = now
        width = max(20, shutil.get_terminal_size((100, 20)).columns - 1)
        self.stream.write("\r" + text[:width] + "\x1b[K")
        self.stream.flush()
        self._shown = True

    def finish(self) -> None:
        if self._shown:
            self.stream.write("\n")
            self.stream.flush()
            self._shown = False


# ----------------------------------------------------------------- runner --

class _Runner:
    """Executes the steps of one script. The driver is None in a dry run."""

    def __init__(self, script: RunScript, planner: Planner, calibration: BoardCalibration,
                 driver: Driver | None, checker: Driver, runlog: RunLog, progress: _Progress):
        self.script = script
        self.planner = planner
        self.calibration = calibration
        self.driver = driver
        self.checker = checker          # validates contractions in a dry run
        self.log = runlog
        self.progress = progress
        self.names = tuple(planner.winch_names)
        self.lower = {n: float(v) for n, v in zip(self.names, planner.lower)}
        self.upper = {n: float(v) for n, v in zip(self.names, planner.upper)}
        self.period = 1.0 / script.rate
        # Polls also feed the board's watchdog: several per watchdog period.
        self.poll_period = self.period if driver is None else min(self.period, driver.watchdog_ms / 3000.0)
        self.t0 = time.monotonic()
        self.commanded: dict[str, float] = {}
        self.planner_at: dict[str, float] | None = None   # contraction the planner last solved for
        self.commands = 0
        self.steps_done = 0
        self.measured: dict[str, float] | None = None
        self._wd0 = None    # board watchdog trips when the run started
        self._step = None   # (index, kind) for the progress line

    # -- log lines ---------------------------------------------------------
    def _line(self, step, kind, event, *, commanded=None, acknowledged=None, info=None, **extra):
        commanded = dict(commanded if commanded is not None else self.commanded)
        info = info or {}
        self.log.write({
            "t": round(time.monotonic() - self.t0, 4), "step": step, "kind": kind, "event": event,
            "commanded": commanded,
            "ticks": {n: self.calibration.winch(n).to_ticks(c) for n, c in commanded.items()},
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
        self.progress.update("  ".join(parts) + " mm")

    # -- board I/O ---------------------------------------------------------
    def _read(self):
        state = self.driver.read_state()
        positions = self.driver.positions_mm(state)
        self.measured = {n: positions[n] for n in self.names}
        if self._wd0 is None:
            self._wd0 = state.watchdog_trips
        elif state.watchdog_trips > self._wd0:
            raise HardwareError(f"{self.driver.port}: the board's watchdog stopped the motors (no command for "
                                f"{self.driver.watchdog_ms} ms while moving); the host stalled")
        return state

    def _send(self, i, kind, contraction, info, **extra):
        full = {**self.commanded, **{n: float(v) for n, v in contraction.items()}}
        acknowledged = None
        if self.driver is not None:
            self.driver.set_contractions(full)  # validates everything before sending
            acknowledged = True
        else:
            self.checker.check_contractions(full)
        self.commanded = full
        self.commands += 1
        if self.driver is not None:
            self._read()
        self._line(i, kind, "command", acknowledged=acknowledged, info=info, **extra)

    def _poll(self, i, kind, info=None):
        state = self._read()
        self._line(i, kind, "measure", info=info)
        return state

    def _settle(self, i, kind, info):
        """Wait, polling, until every scene winch has arrived."""
        if self.driver is None:
            return
        axes = {n: self.calibration.winch(n).axis for n in self.names}
        measured = self.measured or {}
        slowest = max((abs(self.commanded[n] - measured.get(n, self.commanded[n])) / self.calibration.winch(n).max_speed
                       for n in self.names), default=0.0)
        timeout = 2.0 * slowest + SETTLE_MARGIN
        deadline = time.monotonic() + timeout
        while True:
            state = self._poll(i, kind, info)
            stopped = [n for n, a in axes.items() if not state.enabled[a]]
            if stopped:
                raise HardwareError(f"{self.driver.port}: the board stopped winch {stopped[0]!r} before it "
                                    f"reached {self.commanded[stopped[0]]:.2f} mm")
            if not any(state.moving[a] for a in axes.values()):
                self._line(i, kind, "arrived", info=info)
                return
            if time.monotonic() >= deadline:
                late = [n for n, a in axes.items() if state.moving[a]]
                raise HardwareError(
                    f"{self.driver.port}: winch {late[0]!r} did not reach {self.commanded[late[0]]:.2f} mm within "
                    f"{timeout:.1f} s (at {self.measured[late[0]]:.2f} mm): tendon jammed or motor stalled?")
            time.sleep(self.poll_period)

    def _forward(self, contraction):
        result = self.planner.forward(dict(contraction))
        self.planner_at = dict(contraction)
        return result

    # -- steps -------------------------------------------------------------
    def start(self):
        if self.driver is not None:
            self._read()
            # Start from where the winches are, as far as the scene allows.
            start = {n: min(max(self.measured[n], self.lower[n]), self.upper[n]) for n in self.names}
        else:
            start = {n: min(max(0.0, self.lower[n]), self.upper[n]) for n in self.names}
        self.commanded = start
        info = self._forward(start)
        self._line(None, "start", "start", info=info, script=str(self.script.path), problem=str(self.script.problem),
                   board=str(self.script.board), dry_run=self.driver is None, rate=self.script.rate,
                   winches=list(self.names))

    def run_step(self, i: int, step: Step):
        self._step = (i, step.kind)
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
        if self.driver is None:
            self._line(i, "hold", "hold", seconds=step.seconds)
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
            self._stream(i, step, iterates)
        finally:
            cancel.set()

    def _stream(self, i, step, iterates):
        period, poll = self.period, self.poll_period
        deadline = time.monotonic() + 2.0 * step.max_time + PLANNER_GRACE
        pending = latest = None
        n_iterates = 0
        last_send = -math.inf
        last_io = time.monotonic()
        done = False
        while True:
            now = time.monotonic()
            if pending is not None and now - last_send >= period:
                self._send(i, "pose", pending.get("contraction", {}), pending, iteration=n_iterates,
                           converged=pending.get("converged"))
                pending = None
                last_send = last_io = time.monotonic()
            elif self.driver is not None and now - last_io >= poll:
                self._poll(i, "pose", latest)
                last_io = time.monotonic()
            if done and pending is None:
                break
            if not done and time.monotonic() > deadline:
                raise SolverError(f"{self.script.path}: steps[{i}].pose: the planner did not finish within "
                                  f"{2.0 * step.max_time + PLANNER_GRACE:g} s (max_time {step.max_time:g} s)")
            due = last_send + period if pending is not None else (last_io + poll if self.driver else deadline)
            wait = max(0.0, min(due, deadline) - time.monotonic())
            if done:
                time.sleep(wait)
                continue
            try:
                kind, payload = iterates.get(timeout=wait)
            except queue.Empty:
                continue
            if kind == "iterate":
                pending = latest = payload
                n_iterates += 1
            elif kind == "done":
                done = True
            else:
                raise payload
        if n_iterates == 0:
            self._line(i, "pose", "no-iterate", info={"status": "planner produced no iterate"})
            return
        self.planner_at = dict(self.commanded)  # the final iterate, where the planner stopped
        self._settle(i, "pose", latest)


def _default_log_path(script: RunScript) -> Path:
    return Path("out") / "runs" / f"{script.path.stem}-{time.strftime('%Y%m%d-%H%M%S')}.jsonl"


def run_script(script_path, board=None, dry_run: bool = False, log_path=None, planner: Planner | None = None,
               progress: bool | None = None) -> RunResult:
    """Run a run script on a board.

    Parameters
    ----------
    script_path : path or RunScript
        The run script (``plush-opt-run/1``).
    board : Driver or str, optional
        An open or unopened :class:`~plush_opt.board.driver.Driver`, or a
        serial port path (a driver is made from the script's calibration).
        Default: the calibration's ``port.device``. Ignored with ``dry_run``.
    dry_run : bool
        Compute and log everything, open no port.
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
    ``acknowledged`` (board said OK; null when nothing was sent),
    ``measured`` ({winch: mm}, null in a dry run), ``objective``, ``status``.
    """
    if planner is None:
        raise TypeError("run_script needs a planner (see plush_opt.runs.Planner)")
    script = script_path if isinstance(script_path, RunScript) else load_run_script(script_path)
    calibration = load_calibration(script.board)
    if isinstance(board, Driver) and not dry_run:
        calibration = board.calibration  # conversions must match what that driver sends
    check_run_script(script, planner, calibration)
    bounds = {n: (float(lo), float(hi)) for n, lo, hi in zip(planner.winch_names, planner.lower, planner.upper)}

    driver, own = None, False
    if not dry_run:
        if board is None:
            board = calibration.port.device
            if board is None:
                raise HardwareError(f"{script.path}: no board to run on: give a serial port (--port), the "
                                    f"emulator (--emulator) or --dry-run, or set port.device in {calibration.source}")
        if isinstance(board, Driver):
            driver = board
            driver.set_scene_bounds(bounds)
        else:
            driver, own = Driver(os.fspath(board), calibration, bounds=bounds), True
    checker = driver or Driver("(dry run)", calibration, bounds=bounds)

    if progress is None:
        progress = sys.stderr.isatty()
    path = Path(log_path) if log_path is not None else _default_log_path(script)
    status = "error"
    with RunLog(path) as runlog:
        runner = _Runner(script, planner, calibration, driver, checker, runlog, _Progress(sys.stderr, progress))
        try:
            if driver is None:
                session = contextlib.nullcontext()
            elif own:
                session = driver            # opens; stops and closes on exit
            else:
                if not driver.is_open:
                    driver.open()
                session = driver.stop_on_exit()
            with session:
                runner.start()
                for i, step in enumerate(script.steps):
                    runner.run_step(i, step)
            status = "completed"
        except KeyboardInterrupt:
            status = "interrupted"
            raise
        except BaseException as e:
            status = f"error: {e}"
            raise
        finally:
            # The board is stopped by now (the session exited first).
            runner.progress.finish()
            runner._step = None
            runlog.write({"t": round(time.monotonic() - runner.t0, 4), "step": None, "kind": "end", "event": "end",
                          "commanded": runner.commanded, "ticks": calibration.to_ticks(runner.commanded),
                          "acknowledged": None, "measured": runner.measured, "objective": None, "status": status,
                          "steps_done": runner.steps_done, "commands": runner.commands})
    return RunResult(script=str(script.path), log_path=str(path), dry_run=driver is None, steps=runner.steps_done,
                     commands=runner.commands, contraction=dict(runner.commanded))


# -------------------------------------------------------------------- CLI --

def add_run_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the arguments of ``plush-opt run`` to ``parser``."""
    parser.add_argument("script", type=Path, help="run script (YAML, format plush-opt-run/1)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--port", help="serial port of the winch board (default: port.device of the board file)")
    where.add_argument("--emulator", action="store_true",
                       help="run against the board emulator (build it with `make -C hw`)")
    parser.add_argument("--dry-run", action="store_true", help="plan and log every step, open no port")
    parser.add_argument("--log", type=Path, metavar="FILE",
                        help="JSON-lines log of the run (default: out/runs/SCRIPT-TIME.jsonl)")
    return parser


def cli_run(args: argparse.Namespace, planner_factory) -> int:
    """``plush-opt run``: ``planner_factory(problem_path) -> Planner``.

    Returns the exit status: 0 when the run completed, 130 when interrupted
    (the board has been stopped). Other errors propagate as
    :class:`~plush_opt.errors.PlushError`.
    """
    script = load_run_script(args.script)
    calibration = load_calibration(script.board)
    planner = planner_factory(script.problem)
    log_path = args.log if args.log is not None else _default_log_path(script)
    emulator = None
    try:
        if args.emulator and not args.dry_run:
            # The physical top speed must not be what limits: the board's SPEED does.
            top = 2 * max(w.speed_ticks for w in calibration.winches)
            emulator = Emulator(winches=calibration.n_axes_required, speed=top)
            board = emulator.start()
        else:
            board = args.port
        result = run_script(script, board=board, dry_run=args.dry_run, log_path=log_path, planner=planner)
    except KeyboardInterrupt:
        sys.stderr.write(f"\ninterrupted: board stopped; log {log_path}\n")
        return 130
    finally:
        if emulator is not None:
            emulator.close()
    where = "dry run" if result.dry_run else ("emulator" if emulator is not None else "board")
    sys.stderr.write(f"run {script.path.name} completed on {where}: {result.steps} steps, "
                     f"{result.commands} commands, log {result.log_path}\n")
    return 0
