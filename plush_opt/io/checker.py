"""Typed reads from parsed YAML with the house error messages.

Every file kind (problem files, board calibrations, run scripts) checks
its document with one :class:`Checker`; a failure is one
:class:`~plush_opt.base.errors.SceneError` line naming the file, the key path
and the list index::

    gripper.yaml: tendons.list[2].path[4]: expected a number, got string 'x'

Numbers are ints and floats (also numpy scalars), never booleans or
strings; YAML's ``1e1`` is a number (see :mod:`plush_opt.io.yaml_reader`).
"""

from __future__ import annotations

import difflib
import json
import math
import numbers

import numpy as np

from ..base.errors import SceneError, format_number

MAX_COORD = 1e12                  # keeps squared lengths and areas far from overflow
#: target weights: a weight times a squared distance (both within MAX_COORD) stays finite
MAX_WEIGHT = 1e12
#: strings longer than this are cut in messages, so a message stays one short line
MAX_SHOWN = 40


def at_key(path: str, key) -> str:
    """Key path of ``key`` inside ``path``: ``tendons`` + ``list`` -> ``tendons.list``."""
    return f"{path}.{key}" if path else str(key)


def at_index(path: str, i: int) -> str:
    """Key path of entry ``i`` of the list at ``path``: ``winches[2]``."""
    return f"{path}[{i}]"


def describe(value) -> str:
    """What a value is, for "expected ..., got ..." messages."""
    if value is None:
        return "null"
    if isinstance(value, (bool, np.bool_)):
        return f"boolean {str(bool(value)).lower()}"
    if isinstance(value, str):
        if len(value) <= MAX_SHOWN:
            return f"string {value!r}"
        return f"string {value[:MAX_SHOWN - 3] + '...'!r} ({len(value)} characters)"
    if isinstance(value, numbers.Number):
        s = repr(value)
        if len(s) > MAX_SHOWN:
            s = f"{s[:12]}... ({len(s)} characters)"
        return f"number {s}"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, (list, tuple, np.ndarray)):
        return f"a list of {len(value)}"
    return f"a {type(value).__name__}"


def parse_json(raw: bytes, ck: "Checker", path: str = ""):
    """JSON of ``raw`` bytes: the parsed value,
    or one :class:`SceneError` line (``ck`` names the file, ``path`` the part)
    for bytes that are not UTF-8, text that is not JSON, or nesting too deep
    for the parser."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        ck.fail(path, f"not UTF-8 text (byte {exc.start})")
    try:
        return json.loads(text)     # NaN, Infinity: refused where read, under their key
    except RecursionError:
        ck.fail(path, "not JSON of plush-opt: nested too deeply")
    except ValueError as exc:
        ck.fail(path, f"not JSON: {exc}")


def _as_list(value):
    return list(value) if isinstance(value, np.ndarray) else value


class Checker:
    """Validation helpers bound to one source (file) name; every failure raises.

    ``path`` arguments are key paths such as ``winches[1].bounds`` (build
    them with :func:`at_key` and :func:`at_index`); ``""`` is the document.
    """

    def __init__(self, source: str):
        self.source = str(source)

    def fail(self, path: str, message: str):
        """Raise the :class:`SceneError` "SOURCE: PATH: MESSAGE"."""
        where = f"{path}: " if path else ""
        raise SceneError(f"{self.source}: {where}{message}")

    # -- structure --------------------------------------------------------
    def document(self, value, allowed, required=()) -> dict:
        """The top-level mapping of a file."""
        if not isinstance(value, dict):
            self.fail("", f"the document must be a mapping of keys, got {describe(value)}")
        return self.mapping(value, "", allowed, required)

    def mapping(self, value, path: str, allowed, required=()) -> dict:
        """A mapping with only ``allowed`` keys and every ``required`` key set."""
        if not isinstance(value, dict):
            self.fail(path, f"expected a mapping, got {describe(value)}")
        allowed = tuple(allowed)
        for k in value:
            if not isinstance(k, str) or k not in allowed:
                hint = difflib.get_close_matches(str(k), allowed, n=1)
                hint = f" (did you mean '{hint[0]}'?)" if hint else ""
                self.fail(at_key(path, k), f"unknown key{hint}; allowed keys: {', '.join(allowed)}")
        for k in required:
            if k not in value:
                self.fail(at_key(path, k), "missing required key")
            if value[k] is None:
                self.fail(at_key(path, k), "required key has no value")
        return value

    def seq(self, value, path: str, *, min_len: int = 0, what: str = "list") -> list:
        """A list (``what`` names it in messages) of at least ``min_len`` entries."""
        value = _as_list(value)
        if not isinstance(value, (list, tuple)):
            self.fail(path, f"expected a {what}, got {describe(value)}")
        if len(value) < min_len:
            if len(value) == 0:
                self.fail(path, f"empty list; at least {min_len} required")
            self.fail(path, f"expected at least {min_len} entries, got {len(value)}")
        return value

    # -- scalars ----------------------------------------------------------
    def string(self, value, path: str) -> str:
        if not isinstance(value, str):
            scalar = value is not None and not isinstance(value, (dict, list, tuple))
            hint = " (put it in quotes to make it a string)" if scalar else ""
            self.fail(path, f"expected a string, got {describe(value)}{hint}")
        return value

    def name(self, value, path: str) -> str:
        """A non-blank string."""
        s = self.string(value, path)
        if not s.strip():
            self.fail(path, "empty name")
        return s

    def number(self, value, path: str, *, gt=None, ge=None, lt=None) -> float:
        """A finite real number (not a boolean), optionally bounded."""
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            self.fail(path, f"expected a number, got {describe(value)}")
        try:
            x = float(value)
        except (OverflowError, ValueError, TypeError):
            self.fail(path, f"expected a finite number, got {describe(value)}")
        if not math.isfinite(x):
            self.fail(path, f"expected a finite number, got {x!r}")
        if gt is not None and not x > gt:
            self.fail(path, f"must be > {gt:g}, got {format_number(x)}")
        if ge is not None and not x >= ge:
            self.fail(path, f"must be >= {ge:g}, got {format_number(x)}")
        if lt is not None and not x < lt:
            self.fail(path, f"must be < {lt:g}, got {format_number(x)}")
        return x

    def numbers(self, value, path: str, names) -> dict[str, float]:
        """A mapping of some of ``names`` to finite numbers (contractions by winch)."""
        return {k: self.number(v, at_key(path, k)) for k, v in self.mapping(value, path, names).items()}

    def integer(self, value, path: str) -> int:
        """An integer written without a fraction (not a boolean)."""
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
            self.fail(path, f"expected an integer, got {describe(value)}")
        return int(value)

    def boolean(self, value, path: str) -> bool:
        if not isinstance(value, (bool, np.bool_)):
            self.fail(path, f"expected true or false, got {describe(value)}")
        return bool(value)

    # -- points -----------------------------------------------------------
    def point(self, value, path: str) -> tuple[float, float]:
        """A point ``[x, y]`` of finite coordinates at most :data:`MAX_COORD` in magnitude."""
        value = _as_list(value)
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            self.fail(path, f"expected a point [x, y], got {describe(value)}")
        xy = (self.number(value[0], at_index(path, 0)), self.number(value[1], at_index(path, 1)))
        for i, v in enumerate(xy):
            if abs(v) > MAX_COORD:
                self.fail(at_index(path, i), f"{format_number(v)} is too large (coordinates are "
                          f"limited to {MAX_COORD:g} in magnitude)")
        return xy

    def points(self, value, path: str, *, min_len: int = 1) -> np.ndarray:
        """A list of points, as a (k, 2) float64 array."""
        value = self.seq(value, path, min_len=min_len, what="list of points [[x, y], ...]")
        pts = [self.point(p, at_index(path, i)) for i, p in enumerate(value)]
        return np.array(pts, dtype=np.float64).reshape(-1, 2)
