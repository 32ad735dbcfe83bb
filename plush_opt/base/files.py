"""Files written so that nothing is lost: atomic writes (a crash leaves the
old file or the complete new one) and output paths checked before any work."""

from __future__ import annotations

import contextlib
import glob
import json
import os
import tempfile
import threading
from pathlib import Path

from .errors import SceneError, one_line

_UMASK_LOCK = threading.Lock()


def write_json_atomic(path, doc: dict) -> Path:
    """Write ``doc`` as JSON to ``path`` atomically (see :func:`write_text_atomic`).
    A value that is not a finite number (strict JSON has none) is a
    :class:`SceneError` naming the file and its key; nothing is written."""
    try:
        text = json.dumps(doc, indent=1, allow_nan=False)
    except ValueError:
        key, value = _non_finite(doc)
        raise SceneError(f"{path}: {key}: {value!r} is not a finite number: an input beyond the "
                         "model's range? (nothing written)") from None
    return write_text_atomic(path, text + "\n")


def _non_finite(doc, key: str = ""):
    """(key path, value) of the first non-finite float in ``doc``, or ("", None)."""
    if isinstance(doc, float):
        return ("", None) if doc == doc and abs(doc) != float("inf") else (key, doc)
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, (list, tuple)) else ()
    for k, v in items:
        found = _non_finite(v, f"{key}[{k}]" if isinstance(k, int) else f"{key}.{k}" if key else str(k))
        if found[1] is not None:
            return found
    return "", None


def _umask() -> int:
    """The process umask (read without changing it where the system tells it)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _UMASK_LOCK:      # elsewhere: set and restore, one thread at a time
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def _remove_stale_temps(path: Path) -> None:
    """Temp files of earlier writes of ``path`` whose writer was killed
    (``kill -9``) mid-write: they are left behind only then."""
    for tmp in path.parent.glob(f".{glob.escape(path.name)}.*.tmp*"):
        pid = tmp.name[len(path.name) + 2:].split(".")[0]
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            os.kill(int(pid), 0)
        except (ProcessLookupError, OverflowError):      # no such process (nor pid)
            try:
                tmp.unlink()
            except OSError:
                pass
        except OSError:
            pass          # alive but not ours (EPERM): not stale


def check_output_path(path, option: str, *, stream_ok: bool = False) -> Path:
    """Refuse an output path that cannot be written, before any work.

    ``option`` names it in the message (``--out``). The folder is created
    later, by the write, as ``--out`` always did; here only the nearest
    existing folder must be writable. ``stream_ok``: an existing pipe or
    device (``/dev/null``) is fine too (a log). Raises :class:`SceneError`.
    """
    path = Path(path)
    where = f"{option} {one_line(path)}"
    if str(path) in ("", ".") or path.name in ("", ".", ".."):
        raise SceneError(f"{where}: not a file name")
    if path.is_dir():
        raise SceneError(f"{where}: is a directory, not a file")
    if path.exists() and not path.is_file() and not (stream_ok and os.access(path, os.W_OK)):
        raise SceneError(f"{where}: exists and is not a regular file")
    parent = path.parent
    while not parent.exists():
        if parent == parent.parent:
            break
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise SceneError(f"{where}: {one_line(parent)} is not a folder")
    if path.exists() and not path.is_file():
        return path          # a stream, writable
    _probe_folder(parent, where)
    if path.exists() and not os.access(path, os.W_OK):
        raise SceneError(f"{where}: the file is not writable")
    return path


def check_output_folder(path, option: str) -> Path:
    """Refuse an output folder that cannot be made or written, before any work."""
    path = Path(path)
    where = f"{option} {one_line(path)}"
    if path.exists() and not path.is_dir():
        raise SceneError(f"{where}: exists and is not a folder")
    parent = path
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise SceneError(f"{where}: {one_line(parent)} is not a folder")
    _probe_folder(parent, where)
    return path


def _probe_folder(folder: Path, where: str) -> None:
    """A file can be made in ``folder`` (tried, not guessed from the mode
    bits: root passes every access check, yet cannot write to /proc or a
    read-only mount). The probe leaves nothing behind."""
    try:
        with tempfile.TemporaryFile(dir=folder, prefix=".plush-opt-probe."):
            pass
    except OSError as exc:
        raise SceneError(f"{where}: cannot write in {one_line(folder)}: {exc.strerror or exc}") from None


@contextlib.contextmanager
def atomic_path(path):
    """A temp path beside ``path`` (same suffix) to write a file by any
    means (``savefig``); renamed into place on success, removed on any
    failure, so a full disk leaves no partial file. Errors name ``path``."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        _remove_stale_temps(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=f".tmp{path.suffix}",
                                   dir=path.parent)
        os.fchmod(fd, 0o666 & ~_umask())
        os.close(fd)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write: {exc.strerror or exc}", str(path)) from None
    try:
        yield Path(tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError):
            raise OSError(exc.errno, f"cannot write: {exc.strerror or exc}; nothing was written",
                          str(path)) from None
        raise


def write_text_atomic(path, text: str) -> Path:
    """Write ``text`` to ``path`` so that a crash leaves either the old file
    or the complete new one, never a partial file.

    The file gets the usual permissions (0666 less the umask). A failure
    (a full disk) raises :class:`OSError` whose ``filename`` is ``path``,
    not the temp file's.
    """
    with atomic_path(path) as tmp:
        tmp.write_bytes(text.encode("utf-8"))
    return Path(path)


def replace_between(text: str, begin: str, end: str, body: str, where: str = "the text") -> str:
    """``text`` with what lies between the first ``begin`` marker and the
    ``end`` marker after it replaced by ``body`` (the markers kept, ``body``
    on the lines between them: given without a newline at either end); a
    missing marker is a :class:`ValueError` naming ``where`` and both."""
    head, found, rest = text.partition(begin)
    _, found_end, tail = rest.partition(end)
    if not found or not found_end:
        raise ValueError(f"{where}: no block {begin!r} ... {end!r}")
    return f"{head}{begin}\n{body}\n{end}{tail}"


def read_between(text: str, begin: str, end: str) -> str | None:
    """The ``body`` :func:`replace_between` puts between ``begin`` and
    ``end`` (without the newlines around it), or None where a marker is
    missing."""
    _, found, rest = text.partition(begin)
    inner, found_end, _ = rest.partition(end)
    if not found or not found_end:
        return None
    return inner.removeprefix("\n").removesuffix("\n")


def rewrite_block(path, begin: str, end: str, body: str) -> bool:
    """Replace the block between ``begin`` and ``end`` in the text file
    ``path`` by ``body`` (:func:`replace_between`), atomically and only if it
    changed; whether it did."""
    path = Path(path)
    text = path.read_text()
    new = replace_between(text, begin, end, body, str(path))
    if new != text:
        write_text_atomic(path, new)
    return new != text
