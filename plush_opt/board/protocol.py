"""Lines of the winch board protocol, version 1 (hw/PROTOCOL.md).

Pure functions and small frozen records: format a command line, parse a
reply line, decode the payloads of ``ID`` and ``GET``. No I/O here; the
serial side is :mod:`plush_opt.board.driver`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from plush_opt.base.errors import HardwareError

PROTOCOL_VERSION = 1
DEFAULT_BAUDRATE = 115200
MAX_LINE = 120          # characters, terminator excluded
MAX_SEQ = 65535
MAX_TICKS = 1_000_000_000
MAX_SPEED = 1_000_000   # ticks/s
MIN_WATCHDOG_MS = 20
MAX_WATCHDOG_MS = 60_000
MAX_AXES = 8
KEEP = "-"              # SETALL argument: leave this axis as it is

# Error codes of "ERR <code> <message>" replies (hw/PROTOCOL.md, "Errors").
E_MALFORMED = 1
E_TOO_LONG = 2
E_UNKNOWN_COMMAND = 3
E_BAD_ARGUMENT = 4
E_BAD_AXIS = 5
E_OUT_OF_LIMITS = 6
E_BUSY = 7
E_CONFLICT = 8

ERROR_NAMES = {
    E_MALFORMED: "MALFORMED",
    E_TOO_LONG: "TOO_LONG",
    E_UNKNOWN_COMMAND: "UNKNOWN_COMMAND",
    E_BAD_ARGUMENT: "BAD_ARGUMENT",
    E_BAD_AXIS: "BAD_AXIS",
    E_OUT_OF_LIMITS: "OUT_OF_LIMITS",
    E_BUSY: "BUSY",
    E_CONFLICT: "CONFLICT",
}

COMMANDS = ("ID", "PING", "GET", "SET", "SETALL", "STOP", "ZERO", "LIMIT", "SPEED", "WDOG")

_REPLY = re.compile(
    r"^(?P<seq>\d{1,5}|\*) (?:(?P<ok>OK)(?P<payload>(?: \S+)*)|ERR (?P<code>\d{1,3}) (?P<message>[ -~]+))$"
)


class ProtocolError(HardwareError):
    """A line from the board that does not follow the protocol."""


@dataclass(frozen=True)
class Reply:
    """One reply line. ``seq`` is None for ``*`` (board could not read ours)."""

    seq: int | None
    ok: bool
    payload: str = ""       # after "OK", without the leading space
    code: int | None = None  # ERR only
    message: str = ""        # ERR only

    @property
    def error_name(self) -> str:
        return ERROR_NAMES.get(self.code, "UNKNOWN_ERROR") if self.code is not None else ""

    def fields(self) -> dict[str, str]:
        """The ``key=value`` fields of an OK payload."""
        return parse_fields(self.payload)


@dataclass(frozen=True)
class BoardInfo:
    """What ``ID`` reports."""

    board: str
    firmware: str
    protocol: int
    winches: int


@dataclass(frozen=True)
class BoardState:
    """What ``GET`` reports; tuples have one entry per board axis (ticks)."""

    position: tuple[int, ...]
    target: tuple[int, ...]
    moving: tuple[bool, ...]
    enabled: tuple[bool, ...]
    watchdog_trips: int

    @property
    def any_moving(self) -> bool:
        return any(self.moving)


def format_command(seq: int, command: str, *args) -> bytes:
    """One command line, LF-terminated.

    Arguments are written as given (ints, or :data:`KEEP`). Raises
    ValueError for a line the board would refuse as malformed, so that a
    bug here never reaches the wire.
    """
    if not 0 <= seq <= MAX_SEQ:
        raise ValueError(f"sequence number {seq} outside 0..{MAX_SEQ}")
    if command not in COMMANDS:
        raise ValueError(f"unknown command {command!r}; known: {', '.join(COMMANDS)}")
    words = [str(seq), command]
    for a in args:
        if isinstance(a, bool) or not (isinstance(a, int) or a == KEEP):
            raise ValueError(f"{command}: argument {a!r} is not an integer or {KEEP!r}")
        words.append(str(a))
    line = " ".join(words)
    if len(line) > MAX_LINE:
        raise ValueError(f"{command}: line of {len(line)} characters exceeds {MAX_LINE}")
    return (line + "\n").encode("ascii")


def parse_reply(line: bytes | str) -> Reply:
    """Parse one reply line (terminator optional). Raises :class:`ProtocolError`."""
    if isinstance(line, bytes):
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            raise ProtocolError(f"reply is not ASCII: {line!r}") from None
    else:
        text = line
    text = text.rstrip("\r\n")
    m = _REPLY.match(text)
    if m is None:
        raise ProtocolError(f"not a reply line: {text!r}")
    seq = None if m["seq"] == "*" else int(m["seq"])
    if seq is not None and seq > MAX_SEQ:
        raise ProtocolError(f"sequence number {seq} outside 0..{MAX_SEQ}: {text!r}")
    if m["ok"]:
        return Reply(seq=seq, ok=True, payload=m["payload"].lstrip(" "))
    return Reply(seq=seq, ok=False, code=int(m["code"]), message=m["message"])


def parse_fields(payload: str) -> dict[str, str]:
    """``"a=1 b=x,y"`` -> ``{"a": "1", "b": "x,y"}``. Raises :class:`ProtocolError`."""
    out = {}
    for word in payload.split():
        key, sep, value = word.partition("=")
        if not sep or not key or not value:
            raise ProtocolError(f"bad payload field {word!r} in {payload!r}")
        out[key] = value
    return out


def _field(fields: dict[str, str], key: str, payload: str) -> str:
    try:
        return fields[key]
    except KeyError:
        raise ProtocolError(f"reply lacks field {key!r}: {payload!r}") from None


def _ints(text: str, key: str, payload: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ProtocolError(f"field {key!r} is not a list of integers: {payload!r}") from None


def parse_info(payload: str) -> BoardInfo:
    """Decode the payload of an ``ID`` reply."""
    f = parse_fields(payload)
    try:
        protocol = int(_field(f, "proto", payload))
        winches = int(_field(f, "winches", payload))
    except ValueError:
        raise ProtocolError(f"ID reply with non-integer proto/winches: {payload!r}") from None
    return BoardInfo(board=_field(f, "board", payload), firmware=_field(f, "fw", payload),
                     protocol=protocol, winches=winches)


def parse_state(payload: str, n_axes: int) -> BoardState:
    """Decode the payload of a ``GET`` reply from a board with ``n_axes`` axes."""
    f = parse_fields(payload)
    lists = {k: _ints(_field(f, k, payload), k, payload) for k in ("pos", "tgt", "mov", "en")}
    for key, values in lists.items():
        if len(values) != n_axes:
            raise ProtocolError(f"GET field {key!r} has {len(values)} values, board has {n_axes} axes: {payload!r}")
    try:
        wd = int(_field(f, "wd", payload))
    except ValueError:
        raise ProtocolError(f"GET field 'wd' is not an integer: {payload!r}") from None
    return BoardState(position=lists["pos"], target=lists["tgt"],
                      moving=tuple(bool(v) for v in lists["mov"]),
                      enabled=tuple(bool(v) for v in lists["en"]), watchdog_trips=wd)
