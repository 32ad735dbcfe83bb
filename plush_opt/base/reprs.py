"""Short reprs of result objects: printing a result in a session shows what
it is in a line or two, never a whole pose.

:func:`compact_repr` is the ``__repr__`` of the solvers' result dataclasses
(equilibria, friction and contact states, control results): scalars as
they are (floats to :data:`DIGITS` significant digits), arrays of up to
:data:`SHOWN` entries inline, larger ones by shape and type, nested results
by name and verdict, long sequences by length.
"""

from __future__ import annotations

import dataclasses
from numbers import Integral, Real

import numpy as np

#: arrays and sequences with at most this many entries are printed inline
SHOWN = 8
#: significant digits of a float
DIGITS = 6


def value_repr(value) -> str:
    """One value of a result, short (see the module docstring)."""
    if isinstance(value, (bool, np.bool_)) or value is None or isinstance(value, str):
        return repr(value if not isinstance(value, np.bool_) else bool(value))
    if isinstance(value, Integral):
        return str(int(value))
    if isinstance(value, Real):
        return f"{float(value):.{DIGITS}g}"
    if isinstance(value, np.ndarray):
        if value.size <= SHOWN and value.ndim >= 1:
            return value_repr(value.tolist())
        return f"<array {value.shape} {value.dtype}>"
    if isinstance(value, (tuple, list)):
        if len(value) > SHOWN or any(dataclasses.is_dataclass(v) for v in value):
            return f"<{len(value)} {type(value).__name__} items>"
        inner = ", ".join(value_repr(v) for v in value)
        return f"({inner}{',' if len(value) == 1 else ''})" if isinstance(value, tuple) else f"[{inner}]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k!r}: {value_repr(v)}" for k, v in value.items()) + "}"
    if dataclasses.is_dataclass(value):
        verdict = getattr(value, "converged", None)
        return f"<{type(value).__name__}{'' if verdict is None else ' converged' if verdict else ' NOT converged'}>"
    return f"<{type(value).__name__}>"


def compact_repr(obj) -> str:
    """``Name(field=value, ...)`` of a dataclass, its fields with
    ``repr=True`` written by :func:`value_repr`."""
    shown = (f"{f.name}={value_repr(getattr(obj, f.name))}" for f in dataclasses.fields(obj) if f.repr)
    return f"{type(obj).__name__}({', '.join(shown)})"
