"""Small CasADi kernels compiled to C, cached on disk.

The per-element and per-segment kernels are evaluated for every element at
every Newton step; compiled to C they run several times faster than in
CasADi's virtual machine (docs/benchmarks.md). Only these small kernels are
compiled, once per source: the assembled model never is. The cache key is a hash of
the generated C source, the compiler command and the platform, so a changed
kernel or a new machine compiles afresh. Without a working C compiler the
kernels run in the virtual machine, with a warning.

Environment: ``PLUSH_OPT_CACHE`` (default ``$XDG_CACHE_HOME/plush_opt`` or
``~/.cache/plush_opt``) and ``PLUSH_OPT_COMPILE=0`` to switch compiling off.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

log = logging.getLogger(__name__)

CFLAGS = ["-O3", "-fPIC", "-shared"]
VERIFY_SEED = 20240601     # the fixed test point a loaded kernel must reproduce
VERIFY_RTOL = 1e-9         # compiled and virtual-machine kernels differ only by round-off
WARNING_CHARS = 300        # a compiler's or CasADi's message is cut to one readable line
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
    try:
        return _load_or_build(fn, cc, source, name, target)
    except (OSError, subprocess.SubprocessError, RuntimeError) as exc:
        if not _warned:
            log.warning("compiling kernel %s failed (%s): running uncompiled",
                        name, " ".join(str(exc).split())[:WARNING_CHARS])
            _warned = True
        return fn


def _load_or_build(fn: ca.Function, cc: str, source: str, name: str, target: Path) -> ca.Function:
    """The cached kernel, verified; a missing or broken entry is (re)built
    under a lock, so concurrent cold starts compile it once."""
    loaded = _load_verified(fn, target)
    if loaded is not None:
        return loaded
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target.with_suffix(".lock"), "a") as lock:
        fcntl.flock(lock.fileno(), fcntl.LOCK_EX)     # released when the file closes
        loaded = _load_verified(fn, target)          # built by another process meanwhile?
        if loaded is not None:
            return loaded
        _build(cc, source, name, target)
    loaded = _load_verified(fn, target)
    if loaded is None:
        raise RuntimeError(f"the kernel just built at {target} does not verify")
    return loaded


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _load_verified(fn: ca.Function, target: Path) -> ca.Function | None:
    """The cache entry as an external Function if its checksum matches (so a
    truncated or corrupted library is never loaded) and it computes what
    ``fn`` does at a test point; None (the entry removed) otherwise."""
    sums = target.with_name(target.name + ".sha256")
    try:
        ok = sums.read_text().strip() == _digest(target)
    except (OSError, ValueError):
        ok = False
    if ok:
        try:
            ext = ca.external(fn.name(), str(target))
            if _same_values(fn, ext):
                return ext
        except RuntimeError:
            pass
    if target.exists() or sums.exists():
        # an entry of an older version has no checksum: rebuilt quietly
        (log.warning if sums.exists() else log.info)("kernel cache entry %s is broken: rebuilding it", target)
        for p in (target, sums):
            try:
                p.unlink()
            except FileNotFoundError:
                pass
    return None


def _same_values(fn: ca.Function, ext: ca.Function) -> bool:
    """``ext`` and ``fn`` agree at a fixed point (inputs of a fixed seed)."""
    rng = np.random.default_rng(VERIFY_SEED)
    args = [ca.DM(rng.uniform(0.5, 1.5, fn.size_in(i))) for i in range(fn.n_in())]
    if ext.n_in() != fn.n_in() or ext.n_out() != fn.n_out():
        return False
    for a, b in zip(fn.call(args), ext.call(args)):
        a, b = np.asarray(a.full()), np.asarray(b.full())
        if a.shape != b.shape or not np.allclose(a, b, rtol=VERIFY_RTOL, atol=VERIFY_RTOL, equal_nan=True):
            return False
    return True


def _fsync_write(path: Path, data: bytes) -> None:
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def _build(cc: str, source: str, name: str, target: Path) -> None:
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        src = Path(tmp, f"{name}.c")
        src.write_text(source)
        out = Path(tmp, f"{name}.so")
        subprocess.run([cc, *CFLAGS, str(src), "-o", str(out), "-lm"], check=True,
                       capture_output=True, timeout=120)
        with open(out, "rb") as fh:
            os.fsync(fh.fileno())                   # on disk before it is renamed into place
        sums = Path(tmp, "sha256")
        _fsync_write(sums, _digest(out).encode())
        os.replace(out, target)   # atomic: concurrent builds cannot leave half a library
        os.replace(sums, target.with_name(target.name + ".sha256"))
    dir_fd = os.open(target.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)                            # the renames themselves
    finally:
        os.close(dir_fd)
    log.info("compiled kernel %s -> %s", name, target)
