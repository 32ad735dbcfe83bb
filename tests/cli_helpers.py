"""Running the command line as a user does, and what its errors must look like."""

from __future__ import annotations

import subprocess
import sys


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
