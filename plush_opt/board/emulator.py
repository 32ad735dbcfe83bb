"""Run the board emulator (hw/emulator, built by ``make -C hw``) as a subprocess.

Outside a source checkout (an installed wheel) the emulator is compiled
from the sources the wheel ships, once, into a user cache
(:func:`emulator_binary`).

The emulator serves the board protocol on a pseudo-terminal whose path it
prints first; :class:`Emulator` starts it, returns that path (open it with
:class:`~plush_opt.board.driver.Driver` like a real port) and reads the
emulator's state file, which holds the true motor positions.
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import logging
import os
import selectors
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from plush_opt.base.data_files import EMULATOR_SOURCES, data_root
from plush_opt.base.errors import HardwareError

log = logging.getLogger(__name__)

BINARY_ENV = "PLUSH_BOARD_EMU"
"""Environment variable that overrides the emulator binary's path."""

_REPO_BINARY = Path(__file__).resolve().parents[2] / "hw" / "emulator" / "build" / "plush-board-emu"

CACHE_ENV = "PLUSH_OPT_CACHE"
"""Environment variable that overrides where built emulators are kept
(default ``$XDG_CACHE_HOME/plush_opt``, else ``~/.cache/plush_opt``): the
same cache as the compiled CasADi kernels (plush_opt/base/kernels.py)."""

COMPILERS = ("c++", "g++", "clang++")   # tried in this order after $CXX
# hw/Makefile's flags: what the emulator has been tested with
CXX_FLAGS = ("-std=c++17", "-O2")
BUILD_TIMEOUT = 300.0    # s; one file pair, a few seconds on a slow machine


_PR_SET_PDEATHSIG = 1   # <sys/prctl.h>: the signal a process gets when its parent dies


def _die_with_parent():
    """A ``preexec_fn`` (Linux) that has the child killed when this process
    dies, or None where that is not available. The signal follows the
    thread that started the child, so start it from one that lives as long
    as the child should (the main thread)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    parent, kill = os.getpid(), int(signal.SIGKILL)

    def preexec():
        prctl(_PR_SET_PDEATHSIG, kill, 0, 0, 0)
        if os.getppid() != parent:   # the parent died before prctl took effect
            os._exit(1)
    return preexec


def simulator_popen_options() -> dict:
    """``subprocess.Popen`` keyword arguments for a board simulator process.

    Its own session, so that a Ctrl-C at the terminal reaches only the host,
    which then stops the board before the "board" goes away; and, on Linux,
    killed when the host dies, so that no simulator outlives a crashed host.
    """
    options = {"start_new_session": True}
    preexec = _die_with_parent()
    if preexec is not None:
        options["preexec_fn"] = preexec
    return options


def emulator_binary(path: str | os.PathLike | None = None, *, build: bool = True) -> Path:
    """Path of the emulator binary: ``path``, else ``$PLUSH_BOARD_EMU``, else
    ``hw/emulator/build/plush-board-emu`` of the source tree when it is
    built, else the one compiled into the user cache (compiled now, from
    the shipped sources, when it is not there yet and ``build``).

    Raises :class:`HardwareError` saying how to build it if it is missing
    (and, building, when no C++ compiler is found or the build fails).
    """
    if path is not None:
        binary = Path(path)
    elif os.environ.get(BINARY_ENV):
        binary = Path(os.environ[BINARY_ENV])
    elif _executable(_REPO_BINARY):
        return _REPO_BINARY
    else:
        binary = cached_emulator_path()
        if not _executable(binary) and build:
            build_emulator(binary)
    if not _executable(binary):
        raise HardwareError(
            f"board emulator not built: {binary} does not exist or is not executable; build it with "
            f"`make -C hw` in the plush_opt source tree (needs g++ and make), or point {BINARY_ENV} at it")
    return binary


def _executable(path: Path) -> bool:
    return path.is_file() and os.access(path, os.X_OK)


def _cache_dir() -> Path:
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "plush_opt"


def cached_emulator_path() -> Path:
    """Where the emulator built from this package's sources is kept: one
    folder per version of the sources, so that an upgrade builds anew."""
    root = data_root()
    digest = hashlib.sha256()
    for rel in EMULATOR_SOURCES:
        digest.update(rel.encode() + b"\0" + (root / rel).read_bytes())
    return _cache_dir() / f"emulator-{digest.hexdigest()[:12]}" / "plush-board-emu"


def _compiler() -> str:
    for name in (os.environ.get("CXX"), *COMPILERS):
        if name and shutil.which(name):
            return shutil.which(name)
    tried = ", ".join(n for n in (os.environ.get("CXX"), *COMPILERS) if n)
    raise HardwareError(f"the board emulator is compiled on first use and no C++ compiler was found "
                        f"(tried {tried}); install one (Debian/Ubuntu: apt-get install g++) or point "
                        f"{BINARY_ENV} at a built emulator")


def build_emulator(binary: Path) -> Path:
    """Compile the shipped emulator sources into ``binary`` (as hw/Makefile
    does). The file appears whole or not at all, so two runs that build at
    once do not see a half-written one."""
    root = data_root()
    sources = [root / rel for rel in EMULATOR_SOURCES if rel.endswith(".cpp")]
    missing = [str(s) for s in sources if not s.is_file()]
    if missing:
        raise HardwareError(f"board emulator sources missing ({', '.join(missing)}); reinstall plush_opt")
    compiler = _compiler()
    binary.parent.mkdir(parents=True, exist_ok=True)
    tmp = binary.with_name(f".{binary.name}.{os.getpid()}")
    log.warning("compiling the board emulator (once) into %s", binary)
    cmd = [compiler, *CXX_FLAGS, "-o", str(tmp), *map(str, sources)]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=BUILD_TIMEOUT)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise HardwareError(f"could not compile the board emulator with {compiler}: {e}") from None
    if done.returncode != 0:
        tmp.unlink(missing_ok=True)
        detail = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise HardwareError(f"compiling the board emulator with {compiler} failed: {detail}")
    os.replace(tmp, binary)
    return binary


class Emulator:
    """An emulated winch board on a pseudo-terminal.

    Parameters
    ----------
    winches : int
        Number of axes, 1..8.
    speed : float
        Speed of every motor at full PWM, ticks/s (the board's SPEED limits it further).
    tau : float
        Mechanical time constant of the motors, s. The motors are driven by
        the firmware's own control law (hw/emulator/README.md).
    watchdog_ms, deadband : int, optional
        Power-up watchdog timeout (ms) and arrival deadband (ticks).
    state_file : path, optional
        Where the emulator writes its true state (JSON); a temporary file
        by default. See :meth:`read_state`.
    binary : path, optional
        The emulator binary (see :func:`emulator_binary`).

    ``with Emulator(3) as emu: Driver(emu.port, calibration)``.
    """

    def __init__(self, winches: int = 4, *, speed: float = 3000.0, tau: float = 0.05,
                 watchdog_ms: int | None = None, deadband: int | None = None,
                 state_file: str | os.PathLike | None = None, state_interval_ms: int = 10,
                 binary: str | os.PathLike | None = None, extra_args=(), start_timeout: float = 5.0):
        self.binary = emulator_binary(binary)
        self.winches = int(winches)
        self._tmp = None
        if state_file is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="plush-emu-")
            state_file = Path(self._tmp.name) / "state.json"
        self.state_file = Path(state_file)
        args = [str(self.binary), "--winches", str(self.winches), "--speed", repr(float(speed)),
                "--tau", repr(float(tau)), "--state-file", str(self.state_file),
                "--state-interval", str(int(state_interval_ms))]
        if watchdog_ms is not None:
            args += ["--watchdog", str(int(watchdog_ms))]
        if deadband is not None:
            args += ["--deadband", str(int(deadband))]
        self.args = args + [str(a) for a in extra_args]
        self.start_timeout = float(start_timeout)
        self.port: str | None = None
        self._proc: subprocess.Popen | None = None
        self._stderr = None

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    def start(self) -> str:
        """Start the emulator; return the path of its pseudo-terminal."""
        if self.running:
            return self.port
        self._stderr = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(self.args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                      stderr=self._stderr, **simulator_popen_options())
        line = b""
        deadline = time.monotonic() + self.start_timeout
        with selectors.DefaultSelector() as sel:
            sel.register(self._proc.stdout, selectors.EVENT_READ)
            while not line.endswith(b"\n"):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not sel.select(remaining):
                    break
                chunk = os.read(self._proc.stdout.fileno(), 256)
                if not chunk:
                    break
                line += chunk
        self._proc.stdout.close()
        if not line.endswith(b"\n"):
            detail = self._stderr_text()
            self.stop()
            raise HardwareError(f"board emulator {self.binary} did not report its terminal within "
                                f"{self.start_timeout:.1f} s{': ' + detail if detail else ''}")
        self.port = line.decode().strip()
        log.info("board emulator (pid %d) on %s", self._proc.pid, self.port)
        return self.port

    def _stderr_text(self) -> str:
        if self._stderr is None:
            return ""
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace").strip()[-2000:]

    def read_state(self, fresh: bool = True, timeout: float = 2.0) -> dict:
        """The emulator's true state.

        With ``fresh`` (default), waits for a state computed after this call
        (two more writes of the file, a few ms each), so that the effect of
        every command already answered is in it; else returns the last one
        written.

        Keys: ``position`` (float ticks, true motor positions), ``ticks``,
        ``target``, ``enabled``, ``moving``, ``limit_lo``, ``limit_hi``,
        ``speed``, ``min_ticks``/``max_ticks`` (extremes since start),
        ``watchdog_ms``, ``stops`` (``command``/``watchdog``/``hangup``
        counts), ``lines``, ``errors``, ``connected``, ``time``. Lists
        have one entry per axis. See hw/emulator/README.md.
        """
        deadline = time.monotonic() + timeout
        seen, state = [], None
        while True:
            try:
                state = json.loads(self.state_file.read_text())
            except (OSError, ValueError):
                state = None  # not written yet
            if state is not None:
                if state["time"] not in seen:
                    seen.append(state["time"])
                # The first file read may predate the call, the second may
                # have been computed just before it; the third cannot.
                if not fresh or len(seen) >= 3:
                    return state
            if time.monotonic() >= deadline:
                if state is not None and not self.running:
                    return state  # an exited emulator writes no more
                raise HardwareError(f"board emulator wrote no fresh state to {self.state_file} "
                                    f"within {timeout:.1f} s")
            time.sleep(0.002)

    def new_window(self, timeout: float = 2.0) -> dict:
        """Close the simulator's window of position extremes and open the next.

        Both simulators track, per axis, the lowest and highest position
        (``ticks``) since the last window was closed (``window_min``/
        ``window_max`` in the state) besides since start; ``SIGUSR1`` closes
        the window. Returns the closed window's ``{"min": [...], "max":
        [...]}`` (one entry per axis), which covers everything up to a
        moment after this call; the new window starts at the position then.
        Raises :class:`HardwareError` if the simulator does not answer within
        ``timeout`` s.
        """
        if not self.running:
            raise HardwareError("board simulator is not running: no window of extremes to close")
        before = self.read_state(fresh=False, timeout=timeout)["windows"]
        os.kill(self._proc.pid, signal.SIGUSR1)
        deadline = time.monotonic() + timeout
        while True:
            state = self.read_state(fresh=False, timeout=timeout)
            if state["windows"] > before:
                return {"min": state["closed_min"], "max": state["closed_max"]}
            if time.monotonic() >= deadline:
                raise HardwareError(f"board simulator did not close its window of extremes within {timeout:.1f} s")
            time.sleep(0.002)

    def stop(self, timeout: float = 5.0) -> int | None:
        """Stop the emulator (SIGTERM, then SIGKILL after ``timeout``); return its exit status."""
        proc, rc = self._proc, None
        if proc is not None:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout)
                except subprocess.TimeoutExpired:
                    log.warning("board emulator (pid %d) ignored SIGTERM; killing it", proc.pid)
                    proc.kill()
                    proc.wait()
            rc = proc.returncode
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None
        return rc

    def close(self) -> None:
        """Stop the emulator and remove its temporary files."""
        self.stop()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> "Emulator":
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()
        return False
