"""Board files (hw/boards/*.yaml, format ``plush-board/1``) -> :class:`BoardCalibration`.

A board file describes one winch board as wired to one robot: which board
axis drives which winch, how encoder ticks relate to winch contraction
(spool, encoder, gearing, direction), each winch's allowed contraction and
top speed, and the serial port settings. Its classes keep the names
``BoardCalibration`` and ``WinchCalibration`` (and the functions
``load_calibration``, ``calibration_from_dict``); "calibration" here means
ticks per length, not fitting the model to a robot, which is
``plush-opt calibrate`` (:mod:`plush_opt.fit`). This is the only place where lengths
become ticks: with ``k = ticks_per_rev * gear_ratio / (2 pi spool_radius)``
ticks per length unit,

    ticks = round(direction * k * contraction)
    contraction = direction * ticks / k

so a contraction survives length -> ticks -> length within half a tick
and ticks survive ticks -> length -> ticks exactly. The format is
``plush-board/1`` and is described in docs/hardware.md.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace

from plush_opt.board.protocol import (DEFAULT_BAUDRATE, MAX_AXES, MAX_SPEED, MAX_TICKS, MIN_WATCHDOG_MS,
                                      MAX_WATCHDOG_MS)
from plush_opt.io import Checker, read_yaml
from plush_opt.io.checker import at_index, at_key, describe

FORMAT = "plush-board/1"
DEADBAND_TICKS = 3
"""ticks: the board reports a winch arrived within this many ticks of its
target (the firmware's DEADBAND, hw/firmware/plush_winch/plush_winch.ino)."""
ROUNDING_TICKS = 0.5
"""ticks: a contraction is sent as the nearest whole tick."""
_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
MAX_WAIT = 60.0
"""s: the longest port ``timeout`` and ``boot_time``: a board silent for a
minute is gone, and longer waits overflow the serial library's timers."""
MAX_BAUDRATE = 12_000_000
"""baud: the fastest USB serial adapters; beyond it the port cannot be opened."""
MAX_TICKS_PER_REV = float(MAX_TICKS)
"""an encoder's ticks per revolution (and the gear ratio times it) stay within
the board's position range, so one revolution is representable."""
MAX_GEAR_RATIO = 1e6
MAX_LIMIT = 1e12
"""length units: contraction limits, like the problem file's lengths."""
MIN_TICKS_PER_UNIT = 1e-6
"""ticks per length unit at the least: fewer, and one tick is a kilometre."""
MAX_RETRIES = 100
"""further attempts after a timeout: more only delays the error."""
"""motor revolutions per spool revolution: no gearbox reduces further."""


def _round(x: float) -> int:
    """Round half up: monotone, so rounded limits still bound rounded values."""
    return int(math.floor(x + 0.5))


@dataclass(frozen=True)
class PortSettings:
    """How to talk to the board."""

    device: str | None = None       # default serial device, e.g. /dev/ttyACM0
    baudrate: int = DEFAULT_BAUDRATE
    timeout: float = 0.5            # s to wait for one reply
    retries: int = 2                # further attempts after a timeout
    watchdog_ms: int = 1000         # board watchdog set on connect
    boot_time: float = 0.0          # s the board may take to answer after the port opens


@dataclass(frozen=True)
class WinchCalibration:
    """One winch: board axis, spool and encoder geometry, limits.

    Lengths are in the problem's length unit (mm in the shipped files).
    """

    name: str
    axis: int                      # board axis, 0-based
    spool_radius: float            # mm
    ticks_per_rev: float           # encoder ticks per motor revolution (x4 decoded)
    gear_ratio: float              # motor revolutions per spool revolution
    direction: int                 # +1: increasing ticks reel the tendon in
    limits: tuple[float, float]    # allowed contraction [lower, upper], mm
    max_speed: float               # mm/s
    tolerance: float | None = None  # mm an arrived winch may be off; None: min_tolerance

    def __post_init__(self):
        if self.tolerance is None:
            object.__setattr__(self, "tolerance", self.min_tolerance)

    @property
    def ticks_per_mm(self) -> float:
        """Encoder ticks per length unit of contraction (always > 0)."""
        return self.ticks_per_rev * self.gear_ratio / (2.0 * math.pi * self.spool_radius)

    def to_ticks(self, contraction: float) -> int:
        """Contraction (mm) -> board position (ticks)."""
        return _round(self.direction * self.ticks_per_mm * float(contraction))

    def to_mm(self, ticks: int) -> float:
        """Board position (ticks) -> contraction (mm)."""
        return self.direction * float(ticks) / self.ticks_per_mm + 0.0  # + 0.0: no "-0.0" in logs

    @property
    def tick_limits(self) -> tuple[int, int]:
        """Soft limits for the board, ``(lo, hi)`` ticks, lo <= hi.

        Every contraction within :attr:`limits` maps into them (rounding is
        monotone).
        """
        a, b = self.to_ticks(self.limits[0]), self.to_ticks(self.limits[1])
        return (min(a, b), max(a, b))

    @property
    def min_tolerance(self) -> float:
        """The closest an arrived winch is sure to be to a commanded contraction,
        mm: the board's deadband plus half a tick of rounding."""
        return (DEADBAND_TICKS + ROUNDING_TICKS) / self.ticks_per_mm

    @property
    def speed_ticks(self) -> int:
        """Speed limit for the board, ticks/s (at least 1)."""
        return max(1, _round(self.max_speed * self.ticks_per_mm))


@dataclass(frozen=True)
class BoardCalibration:
    """A validated board file: its winches (axis, ticks per length, limits,
    speed), port settings, name and description, and where it was read."""

    name: str
    winches: tuple[WinchCalibration, ...]
    port: PortSettings = PortSettings()
    description: str = ""
    source: str = "<memory>"

    def __post_init__(self):
        object.__setattr__(self, "winches", tuple(self.winches))

    @property
    def winch_names(self) -> tuple[str, ...]:
        return tuple(w.name for w in self.winches)

    @property
    def n_axes_required(self) -> int:
        """Smallest number of board axes that has every calibrated axis."""
        return max(w.axis for w in self.winches) + 1

    def winch(self, name: str) -> WinchCalibration:
        for w in self.winches:
            if w.name == name:
                return w
        raise KeyError(f"{self.source}: no winch {name!r}; calibrated winches: {', '.join(self.winch_names)}")

    def to_ticks(self, contraction: Mapping[str, float]) -> dict[str, int]:
        """``{winch: mm}`` -> ``{winch: ticks}``."""
        return {name: self.winch(name).to_ticks(c) for name, c in contraction.items()}

    def to_mm(self, ticks: Mapping[str, int]) -> dict[str, float]:
        """``{winch: ticks}`` -> ``{winch: mm}``."""
        return {name: self.winch(name).to_mm(t) for name, t in ticks.items()}


# --------------------------------------------------------------- loading --

_TOP_KEYS = ("format", "name", "description", "port", "winches")
_PORT_KEYS = ("device", "baudrate", "timeout", "retries", "watchdog_ms", "boot_time")
_WINCH_KEYS = ("name", "axis", "spool_radius", "ticks_per_rev", "gear_ratio", "direction", "limits",
               "max_speed", "tolerance")
_WINCH_REQUIRED = ("name", "spool_radius", "ticks_per_rev", "gear_ratio", "limits", "max_speed")


def _name(c: Checker, value, key: str) -> str:
    if not isinstance(value, str) or not _NAME.match(value):
        c.fail(key, f"must be a name of letters, digits, '_' or '-', got {describe(value)}")
    return value


def _get(d: dict, key: str, default):
    """Value of an optional key; an explicit null counts as absent."""
    value = d.get(key)
    return default if value is None else value


def calibration_from_dict(data, source: str = "<memory>") -> BoardCalibration:
    """Validate an already parsed calibration document. Raises :class:`SceneError`."""
    c = Checker(source)
    top = c.document(data, _TOP_KEYS, required=("format", "name", "winches"))
    if top["format"] != FORMAT:
        c.fail("format", f"must be {FORMAT!r}, got {describe(top['format'])}")
    name = _name(c, top["name"], "name")
    description = _get(top, "description", "")
    description = c.string(description, "description")
    port = PortSettings() if top.get("port") is None else _port_section(c, top["port"])
    items = c.seq(top["winches"], "winches", min_len=1, what="list of winches")
    winches = []
    for i, item in enumerate(items):
        winches.append(_winch_section(c, item, i, winches))
    return BoardCalibration(name=name, winches=tuple(winches), port=port, description=description, source=source)


def _shown_int(n: int) -> str:
    """An integer for a message, long ones shortened."""
    return str(n) if abs(n) < 10 ** 12 else f"{float(n):.3g}"


def _at_most(c: Checker, x: float, limit: float, key: str, unit: str) -> float:
    if x > limit:
        c.fail(key, f"must be <= {limit:g}{' ' + unit if unit else ''}, got {x:g}")
    return x


def _port_section(c: Checker, raw) -> PortSettings:
    p = c.mapping(raw, "port", _PORT_KEYS)
    default = PortSettings()
    device = p.get("device")
    if device is not None and (not isinstance(device, str) or not device):
        c.fail("port.device", f"must be a device path or null, got {describe(device)}")
    baud = c.integer(_get(p, "baudrate", default.baudrate), "port.baudrate")
    if not 0 < baud <= MAX_BAUDRATE:
        c.fail("port.baudrate", f"must be in 1..{MAX_BAUDRATE}, got {_shown_int(baud)}")
    timeout = _at_most(c, c.number(_get(p, "timeout", default.timeout), "port.timeout", gt=0), MAX_WAIT,
                       "port.timeout", "s")
    retries = c.integer(_get(p, "retries", default.retries), "port.retries")
    if retries < 0:
        c.fail("port.retries", f"must be >= 0, got {retries}")
    if retries > MAX_RETRIES:
        c.fail("port.retries", f"must be <= {MAX_RETRIES}, got {_shown_int(retries)}")
    wd = c.integer(_get(p, "watchdog_ms", default.watchdog_ms), "port.watchdog_ms")
    if not MIN_WATCHDOG_MS <= wd <= MAX_WATCHDOG_MS:
        c.fail("port.watchdog_ms", f"must be in {MIN_WATCHDOG_MS}..{MAX_WATCHDOG_MS}, got {wd}")
    boot = _at_most(c, c.number(_get(p, "boot_time", default.boot_time), "port.boot_time", ge=0), MAX_WAIT,
                    "port.boot_time", "s")
    return PortSettings(device=device, baudrate=baud, timeout=timeout, retries=retries, watchdog_ms=wd,
                        boot_time=boot)


def _winch_section(c: Checker, item, i: int, before: list[WinchCalibration]) -> WinchCalibration:
    """Entry ``i`` of ``winches``; ``before`` are the entries already read."""
    key = at_index("winches", i)
    w = c.mapping(item, key, _WINCH_KEYS, required=_WINCH_REQUIRED)
    wname = _name(c, w["name"], at_key(key, "name"))
    if wname in {b.name for b in before}:
        c.fail(at_key(key, "name"), f"duplicate winch name {wname!r}")
    axis = c.integer(_get(w, "axis", i), at_key(key, "axis"))
    if not 0 <= axis < MAX_AXES:
        c.fail(at_key(key, "axis"), f"must be in 0..{MAX_AXES - 1}, got {axis}")
    if axis in {b.axis for b in before}:
        c.fail(at_key(key, "axis"), f"axis {axis} is already used by another winch")
    direction = _get(w, "direction", 1)
    if direction not in (1, -1) or isinstance(direction, bool):
        c.fail(at_key(key, "direction"), f"must be 1 or -1, got {describe(direction)}")
    limits = w["limits"]
    if not isinstance(limits, list) or len(limits) != 2:
        c.fail(at_key(key, "limits"), f"must be [lower, upper], got {describe(limits)}")
    lo, hi = (c.number(limits[k], at_index(at_key(key, "limits"), k)) for k in (0, 1))
    for k, v in enumerate((lo, hi)):
        if abs(v) > MAX_LIMIT:
            c.fail(at_index(at_key(key, "limits"), k), f"{v:g} is too large (lengths are limited to "
                   f"{MAX_LIMIT:g} in magnitude)")
    if not lo < hi:
        c.fail(at_key(key, "limits"), f"lower must be < upper, got [{lo}, {hi}]")
    scale = dict(
        spool_radius=c.number(w["spool_radius"], at_key(key, "spool_radius"), gt=0),
        ticks_per_rev=_at_most(c, c.number(w["ticks_per_rev"], at_key(key, "ticks_per_rev"), gt=0),
                               MAX_TICKS_PER_REV, at_key(key, "ticks_per_rev"), "ticks"),
        gear_ratio=_at_most(c, c.number(w["gear_ratio"], at_key(key, "gear_ratio"), gt=0),
                            MAX_GEAR_RATIO, at_key(key, "gear_ratio"), ""),
        max_speed=c.number(w["max_speed"], at_key(key, "max_speed"), gt=0))
    _check_scale(c, key, **scale)
    wc = WinchCalibration(name=wname, axis=axis, direction=int(direction), limits=(lo, hi), **scale)
    if w.get("tolerance") is not None:
        tolerance = c.number(w["tolerance"], at_key(key, "tolerance"), gt=0)
        if tolerance < wc.min_tolerance:
            c.fail(at_key(key, "tolerance"), f"must be >= {wc.min_tolerance:.4g} mm (the board's {DEADBAND_TICKS}-tick "
                                             f"deadband plus half a tick of rounding), got {tolerance}")
        if tolerance > hi - lo:
            c.fail(at_key(key, "tolerance"), f"must be <= the span of the limits ({hi - lo:g}), got {tolerance:g}: "
                   "every position would count as arrived")
        wc = replace(wc, tolerance=tolerance)
    t_lo, t_hi = wc.tick_limits
    if max(abs(t_lo), abs(t_hi)) > MAX_TICKS:
        c.fail(at_key(key, "limits"), f"[{lo}, {hi}] is [{t_lo}, {t_hi}] ticks, beyond the board's +-{MAX_TICKS}")
    return wc


def _check_scale(c: Checker, key: str, spool_radius, ticks_per_rev, gear_ratio, max_speed) -> None:
    """Ticks per length unit (:attr:`WinchCalibration.ticks_per_mm`) within
    the board's position range, and the speed limit within its speed range."""
    per = ticks_per_rev * gear_ratio / (2.0 * math.pi * spool_radius)
    if not MIN_TICKS_PER_UNIT <= per <= MAX_TICKS:
        c.fail(at_key(key, "spool_radius"), f"{spool_radius:g} gives {per:.3g} ticks per length unit "
               f"(ticks_per_rev * gear_ratio / (2 pi spool_radius)); the board's range is "
               f"{MIN_TICKS_PER_UNIT:g}..{MAX_TICKS}")
    speed = max_speed * per
    if not 1 <= speed <= MAX_SPEED:
        c.fail(at_key(key, "max_speed"), f"{max_speed:g} is {speed:.3g} ticks/s; the board moves at "
               f"1..{MAX_SPEED} ticks/s ({1 / per:.4g}..{MAX_SPEED / per:.4g} per second)")


def load_calibration(path) -> BoardCalibration:
    """Read and validate a board calibration file. Raises :class:`SceneError`."""
    source = str(path)
    return calibration_from_dict(read_yaml(path, what="board calibration file", source=source), source=source)
