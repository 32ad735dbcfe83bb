"""Allowed contractions: the board file's winch limits within the scene's winch bounds.

Two pure functions, the only place where contractions are checked against
limits and turned into ticks. :func:`allowed_ranges` intersects the
board file's limits (:class:`~plush_opt.board.board_file.BoardCalibration`)
with the scene's bounds (once, where a link or a
driver is made); :func:`check_contractions` checks one command against
those ranges and converts it to ticks. The driver, every board link and
the run checker call them, so a command refused by one is refused by all.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping

from plush_opt.board.board_file import BoardCalibration
from plush_opt.base.errors import HardwareError

BOUND_TOLERANCE = 1e-9
"""Relative slack at a limit: a solver at an active bound may overshoot it
by float noise, which is clamped, never more."""


def allowed_ranges(calibration: BoardCalibration,
                   bounds: Mapping[str, tuple[float, float]] | None = None) -> dict[str, tuple[float, float]]:
    """Allowed contraction per calibrated winch, ``{name: (lower, upper)}``.

    Parameters
    ----------
    calibration : the board's calibration; its ``limits`` bound every winch.
    bounds : the scene's winch bounds ``{name: (lower, upper)}`` (length
        unit of the problem), optional; each must name a calibrated winch.

    Raises :class:`HardwareError` for a scene winch that is not calibrated
    or whose bounds do not overlap the calibration's limits.
    """
    allowed = {w.name: w.limits for w in calibration.winches}
    for name, (lo, hi) in (bounds or {}).items():
        if name not in allowed:
            raise HardwareError(f"{calibration.source}: scene winch {name!r} is not calibrated; "
                                f"calibrated winches: {', '.join(allowed)}")
        c_lo, c_hi = allowed[name]
        lower, upper = max(c_lo, float(lo)), min(c_hi, float(hi))
        if lower > upper:
            raise HardwareError(f"{calibration.source}: winch {name!r}: scene bounds [{float(lo):g}, {float(hi):g}] "
                                f"and calibration limits [{c_lo:g}, {c_hi:g}] do not overlap")
        allowed[name] = (lower, upper)
    return allowed


def _is_number(value) -> bool:
    # bool is an int to Python, and a string may parse as a number: neither
    # is a contraction.
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def check_contractions(contraction: Mapping[str, float], allowed: Mapping[str, tuple[float, float]],
                       calibration: BoardCalibration) -> dict[str, int]:
    """Check ``{winch: length}`` against ``allowed`` and convert it to ``{winch: ticks}``.

    Sends nothing and changes nothing. Values within float noise of a limit
    (:data:`BOUND_TOLERANCE`) are clamped onto it.

    Raises :class:`HardwareError` naming the winch and the value for a
    winch not in ``allowed``, a value that is not a finite real number
    (a string, a bool, None, nan, inf), or one outside the winch's range.
    """
    ticks = {}
    for name, value in contraction.items():
        if name not in allowed:
            raise HardwareError(f"no winch {name!r} in calibration {calibration.source}; "
                                f"calibrated winches: {', '.join(allowed)}")
        if not _is_number(value) or not math.isfinite(value):
            raise HardwareError(f"contraction {value!r} for winch {name!r} is not a finite number")
        lo, hi = allowed[name]
        c = float(value)
        tol = BOUND_TOLERANCE * max(1.0, abs(lo), abs(hi))
        if not lo - tol <= c <= hi + tol:
            raise HardwareError(f"contraction {c:g} for winch {name!r} is outside its allowed range "
                                f"[{lo:g}, {hi:g}] (calibration limits within scene bounds)")
        ticks[name] = calibration.winch(name).to_ticks(min(max(c, lo), hi))
    return ticks
