"""Running the command line as a user does, and what its errors must look like."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

#: s to wait for a signalled process to end: generous (an interrupted solve ends within about a second)
SIGNAL_WAIT = 120.0


def cli(*args, cwd=None, timeout=120, env=None) -> subprocess.CompletedProcess:
    """``python -m plush_opt ARGS`` in a fresh process: its exit code, stdout and stderr."""
    return subprocess.run([sys.executable, "-m", "plush_opt", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, timeout=timeout, env=env)


def one_error_line(p: subprocess.CompletedProcess, code: int = 2) -> str:
    """The one line a refused command prints (exit ``code``, no traceback)."""
    assert p.returncode == code, (p.returncode, p.stderr[-2000:])
    assert "Traceback" not in p.stderr, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1, p.stderr
    return lines[0]


def interrupt(proc: subprocess.Popen, name: str, wait: float = SIGNAL_WAIT) -> tuple[int, str]:
    """Send signal ``name`` (``"SIGTERM"``) to ``proc`` a moment after the
    caller saw it mid-work; its (exit code, stderr), or a test failure if
    it does not end within ``wait`` seconds."""
    time.sleep(0.3)
    proc.send_signal(getattr(signal, name))
    try:
        _, err = proc.communicate(timeout=wait)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"{name} did not end the process within {wait} s")
    return proc.returncode, err
