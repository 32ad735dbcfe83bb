"""Board calibration files (hw/boards/*.yaml) -> :class:`BoardCalibration`.

A calibration says which board axis drives which winch and how encoder
ticks relate to winch contraction. This is the only place where lengths
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
from dataclasses import dataclass
from pathlib import Path

import yaml

from plush_opt.board.protocol import DEFAULT_BAUDRATE, MAX_AXES, MAX_TICKS, MIN_WATCHDOG_MS, MAX_WATCHDOG_MS
from plush_opt.errors import SceneError

FORMAT = "plush-board/1"
_NAME = re.compile(r"^[A-Za-z0-9_-]+$")


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
    def speed_ticks(self) -> int:
        """Speed limit for the board, ticks/s (at least 1)."""
        return max(1, _round(self.max_speed * self.ticks_per_mm))


@dataclass(frozen=True)
class BoardCalibration:
    """A validated calibration file."""

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

class _Checker:
    """Typed reads from a parsed YAML mapping, errors naming file and key."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, key: str, message: str):
        raise SceneError(f"{self.source}: {key or 'document'}: {message}")

    def mapping(self, value, key: str, allowed: set[str], required: set[str]) -> dict:
        if not isinstance(value, dict):
            self.fail(key, f"must be a mapping, got {type(value).__name__}")
        for k in value:
            if k not in allowed:
                self.fail(f"{key}.{k}" if key else str(k),
                          f"unknown key; allowed keys: {', '.join(sorted(allowed))}")
        for k in sorted(required):
            if k not in value:
                self.fail(f"{key}.{k}" if key else k, "is required")
        return value

    def number(self, value, key: str, *, positive=False, integer=False) -> float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if ok and integer:
            ok = float(value).is_integer()
        if not ok or not math.isfinite(value):
            self.fail(key, f"must be {'an integer' if integer else 'a number'}, got {value!r}")
        if positive and value <= 0:
            self.fail(key, f"must be > 0, got {value!r}")
        return int(value) if integer else float(value)

    def name(self, value, key: str) -> str:
        if not isinstance(value, str) or not _NAME.match(value):
            self.fail(key, f"must be a name of letters, digits, '_' or '-', got {value!r}")
        return value


def calibration_from_dict(data, source: str = "<memory>") -> BoardCalibration:
    """Validate an already parsed calibration document. Raises :class:`SceneError`."""
    c = _Checker(source)
    top = c.mapping(data, "", {"format", "name", "description", "port", "winches"},
                    {"format", "name", "winches"})
    if top["format"] != FORMAT:
        c.fail("format", f"must be {FORMAT!r}, got {top['format']!r}")
    name = c.name(top["name"], "name")
    description = top.get("description", "")
    if not isinstance(description, str):
        c.fail("description", f"must be a string, got {description!r}")

    port = PortSettings()
    if top.get("port") is not None:
        p = c.mapping(top["port"], "port", {"device", "baudrate", "timeout", "retries", "watchdog_ms", "boot_time"},
                      set())
        device = p.get("device")
        if device is not None and (not isinstance(device, str) or not device):
            c.fail("port.device", f"must be a device path or null, got {device!r}")
        baud = c.number(p.get("baudrate", port.baudrate), "port.baudrate", positive=True, integer=True)
        timeout = c.number(p.get("timeout", port.timeout), "port.timeout", positive=True)
        retries = c.number(p.get("retries", port.retries), "port.retries", integer=True)
        if retries < 0:
            c.fail("port.retries", f"must be >= 0, got {retries}")
        wd = c.number(p.get("watchdog_ms", port.watchdog_ms), "port.watchdog_ms", integer=True)
        if not MIN_WATCHDOG_MS <= wd <= MAX_WATCHDOG_MS:
            c.fail("port.watchdog_ms", f"must be in {MIN_WATCHDOG_MS}..{MAX_WATCHDOG_MS}, got {wd}")
        boot = c.number(p.get("boot_time", port.boot_time), "port.boot_time")
        if boot < 0:
            c.fail("port.boot_time", f"must be >= 0, got {boot}")
        port = PortSettings(device=device, baudrate=baud, timeout=timeout, retries=retries, watchdog_ms=wd,
                            boot_time=boot)

    items = top["winches"]
    if not isinstance(items, list) or not items:
        c.fail("winches", f"must be a non-empty list, got {items!r}")
    winches = []
    names, axes = set(), set()
    for i, item in enumerate(items):
        key = f"winches[{i}]"
        w = c.mapping(item, key,
                      {"name", "axis", "spool_radius", "ticks_per_rev", "gear_ratio", "direction", "limits",
                       "max_speed"},
                      {"name", "spool_radius", "ticks_per_rev", "gear_ratio", "limits", "max_speed"})
        wname = c.name(w["name"], f"{key}.name")
        if wname in names:
            c.fail(f"{key}.name", f"duplicate winch name {wname!r}")
        names.add(wname)
        axis = c.number(w.get("axis", i), f"{key}.axis", integer=True)
        if not 0 <= axis < MAX_AXES:
            c.fail(f"{key}.axis", f"must be in 0..{MAX_AXES - 1}, got {axis}")
        if axis in axes:
            c.fail(f"{key}.axis", f"axis {axis} is already used by another winch")
        axes.add(axis)
        direction = w.get("direction", 1)
        if direction not in (1, -1) or isinstance(direction, bool):
            c.fail(f"{key}.direction", f"must be 1 or -1, got {direction!r}")
        limits = w["limits"]
        if not isinstance(limits, list) or len(limits) != 2:
            c.fail(f"{key}.limits", f"must be [lower, upper], got {limits!r}")
        lo = c.number(limits[0], f"{key}.limits[0]")
        hi = c.number(limits[1], f"{key}.limits[1]")
        if not lo < hi:
            c.fail(f"{key}.limits", f"lower must be < upper, got [{lo}, {hi}]")
        wc = WinchCalibration(
            name=wname, axis=axis,
            spool_radius=c.number(w["spool_radius"], f"{key}.spool_radius", positive=True),
            ticks_per_rev=c.number(w["ticks_per_rev"], f"{key}.ticks_per_rev", positive=True),
            gear_ratio=c.number(w["gear_ratio"], f"{key}.gear_ratio", positive=True),
            direction=int(direction), limits=(lo, hi),
            max_speed=c.number(w["max_speed"], f"{key}.max_speed", positive=True))
        t_lo, t_hi = wc.tick_limits
        if max(abs(t_lo), abs(t_hi)) > MAX_TICKS:
            c.fail(f"{key}.limits", f"[{lo}, {hi}] is [{t_lo}, {t_hi}] ticks, beyond the board's +-{MAX_TICKS}")
        winches.append(wc)
    return BoardCalibration(name=name, winches=tuple(winches), port=port, description=description, source=source)


def load_calibration(path) -> BoardCalibration:
    """Read and validate a board calibration file. Raises :class:`SceneError`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise SceneError(f"{path}: cannot read calibration file: {e.strerror or e}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise SceneError(f"{path}: not valid YAML: {e}") from None
    return calibration_from_dict(data, source=str(path))
