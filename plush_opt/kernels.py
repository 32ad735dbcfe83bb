"""Small CasADi kernels compiled to C, cached on disk.

The per-element and per-segment kernels are evaluated for every element at
every Newton step; compiled, they run about four times faster than in
CasADi's virtual machine. Only these small kernels are compiled (well under
a second, once): the assembled model never is. The cache key is a hash of
the generated C source, the compiler command and the platform, so a changed
kernel or a new machine compiles afresh. Without a working C compiler the
kernels run in the virtual machine, with a warning.

Environment: ``PLUSH_OPT_CACHE`` (default ``$XDG_CACHE_HOME/plush_opt`` or
``~/.cache/plush_opt``) and ``PLUSH_OPT_COMPILE=0`` to switch compiling off.
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca

log = logging.getLogger(__name__)

CFLAGS = ["-O3", "-fPIC", "-shared"]
_warned = False


def cache_dir() -> Path:
    root = os.environ.get("PLUSH_OPT_CACHE")
    if root:
        return Path(root)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "plush_opt"


def _compiler() -> str | None:
    return os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")


def compiled(fn: ca.Function) -> ca.Function:
    """``fn`` as a compiled external Function (same inputs and outputs), or
    ``fn`` itself if compiling is switched off or impossible."""
    global _warned
    if os.environ.get("PLUSH_OPT_COMPILE", "1") == "0":
        return fn
    cc = _compiler()
    if cc is None:
        if not _warned:
            log.warning("no C compiler found: kernels run uncompiled (slower)")
            _warned = True
        return fn
    name = fn.name()
    with tempfile.TemporaryDirectory() as tmp:
        gen = ca.CodeGenerator(f"{name}.c", {"with_header": False})
        gen.add(fn)
        gen.generate(tmp + os.sep)
        source = Path(tmp, f"{name}.c").read_text()
    key = hashlib.sha256("\n".join([source, cc, *CFLAGS, platform.machine(), platform.system(),
                                    ca.__version__]).encode()).hexdigest()[:16]
    target = cache_dir() / f"{name}-{key}.so"
    if not target.exists():
        try:
            _build(cc, source, name, target)
        except (OSError, subprocess.CalledProcessError) as exc:
            if not _warned:
                log.warning("compiling kernel %s failed (%s): running uncompiled", name, exc)
                _warned = True
            return fn
    return ca.external(name, str(target))


def _build(cc: str, source: str, name: str, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        src = Path(tmp, f"{name}.c")
        src.write_text(source)
        out = Path(tmp, f"{name}.so")
        subprocess.run([cc, *CFLAGS, str(src), "-o", str(out), "-lm"], check=True,
                       capture_output=True, timeout=120)
        os.replace(out, target)   # atomic: concurrent builds cannot leave half a library
    log.info("compiled kernel %s -> %s", name, target)
