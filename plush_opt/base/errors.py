"""The exception family of plush_opt.

Every error a user can cause is a :class:`PlushError`; the command line
prints its message on one line and exits non-zero.
"""

import contextlib


class PlushError(Exception):
    """Base class of every error raised on purpose by plush_opt."""


class SceneError(PlushError, ValueError):
    """A problem file (or a scene built in code) is invalid.

    The message names the file, the key and, where there is one, the list
    index: ``gripper.yaml: tendons.list[2].path[4]: point (81.0, 3.0) lies
    outside the body``.
    """


class SolverError(PlushError, RuntimeError):
    """A solver could not be run (as opposed to running and not converging,
    which is reported by a result's ``converged``/``status``)."""


class SettingError(SolverError):
    """A setting outside the files is invalid (an environment variable such
    as ``PLUSH_OPT_LINALG``): bad input, exit 2, the message names it. A
    :class:`SolverError` too, for callers that caught a bad backend as one."""


class HardwareError(PlushError, RuntimeError):
    """The winch board misbehaved: timeout, bad reply, refused command."""


def format_number(x) -> str:
    """A number as error messages write it: ``repr`` of the float (``-6.0``)."""
    return repr(float(x))


def format_point(p) -> str:
    """A point as error messages write it: ``(81.0, 3.0)``."""
    return f"({format_number(p[0])}, {format_number(p[1])})"


#: an echoed value (a name, a string from a file) is cut to this many characters in a message
MAX_ECHOED = 80


def shown(value) -> str:
    """``repr`` of a value a message echoes, at most about :data:`MAX_ECHOED`
    characters: a longer one keeps its start, an ellipsis and how much was
    left out (``'nnnn... (3925 of 4000 characters left out)``)."""
    text = repr(value)
    if len(text) <= MAX_ECHOED:
        return text
    kept = MAX_ECHOED - 4
    size = len(value) if isinstance(value, str) else len(text)
    left = size - (kept - 1 if isinstance(value, str) else kept)     # a string's repr starts with its quote
    return f"{text[:kept]}... ({left} of {size} characters left out)"


MESSAGE_MAX_CHARS = 2000     # a message is one terminal-readable line, not an echo of a hostile input
MESSAGE_KEEP_TAIL = 200      # a cut message keeps its end too: it usually says what went wrong


def one_line(text, max_chars: int = MESSAGE_MAX_CHARS) -> str:
    """``text`` as one printable line of at most about ``max_chars`` characters.

    Control characters (newlines, NUL, escape sequences) are written as
    escapes (``\\n``, ``\\x00``) so that a hostile name cannot add lines or
    drive the terminal; an overlong message keeps its start and its end.
    """
    text = str(text)
    out = []
    for ch in text:
        code = ord(ch)
        if code < 0x20 or code == 0x7f or 0x80 <= code < 0xa0 or ch in "\u2028\u2029":
            out.append(ch.encode("unicode_escape").decode("ascii"))
        else:
            out.append(ch)
    line = "".join(out)
    if len(line) > max_chars:
        head = max_chars - MESSAGE_KEEP_TAIL
        line = (f"{line[:head]} ... ({len(line) - head - MESSAGE_KEEP_TAIL} characters left out) ... "
                f"{line[-MESSAGE_KEEP_TAIL:]}")
    return line


class Interrupted(KeyboardInterrupt):
    """A termination signal (SIGTERM, SIGHUP) handled like Ctrl-C: the run
    stops the board, writes its log's last line and exits ``128 + signum``."""

    def __init__(self, signum: int, name: str):
        super().__init__(name)
        self.signum = signum
        self.name = name


def interrupt_status(exc: BaseException) -> tuple[str, int]:
    """Which signal interrupted (``"SIGTERM"``; Ctrl-C is ``"SIGINT"``) and the exit status."""
    if isinstance(exc, Interrupted):
        return exc.name, 128 + exc.signum
    return "SIGINT", 130


# The interruption a signal handler noted. A handler's exception is lost
# where it is raised inside a C++ solver's callback (IPOPT turns it into a
# failed step or a stop on request); the solver's caller re-raises the noted
# one (:func:`raise_if_interrupted`), and IPOPT's iteration callback stops
# the solve when one is noted (:func:`interrupt_noted`).
_noted: list[KeyboardInterrupt] = []
_only_noted = [0]     # > 0: inside a loop that stops itself on a noted signal (see only_note_signals)


def note_interrupt(exc: KeyboardInterrupt) -> None:
    """Remember ``exc`` (an :class:`Interrupted` or a Ctrl-C) until cleared; the first one wins."""
    if not _noted:
        _noted.append(exc)


def interrupt_noted() -> bool:
    """Whether a signal has been noted since the last :func:`clear_interrupt`."""
    return bool(_noted)


@contextlib.contextmanager
def only_note_signals():
    """Inside: a signal is noted, not raised (for a C++ loop that checks
    :func:`interrupt_noted` itself and stops cleanly, rather than seeing the
    exception as a failed evaluation)."""
    _only_noted[0] += 1
    try:
        yield
    finally:
        _only_noted[0] -= 1


def signals_only_noted() -> bool:
    """Whether a signal handler should only note the signal (see :func:`only_note_signals`)."""
    return _only_noted[0] > 0


def clear_interrupt() -> None:
    """Forget a noted signal (a command's start; a test's)."""
    _noted.clear()


def raise_if_interrupted() -> None:
    """Raise the noted interruption again, if any (after a solver returns)."""
    if _noted:
        raise _noted[0].with_traceback(None)
