"""The exception family of plush_opt.

Every error a user can cause is a :class:`PlushError`; the command line
prints its message on one line and exits non-zero.
"""


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


class HardwareError(PlushError, RuntimeError):
    """The winch board misbehaved: timeout, bad reply, refused command."""


def format_number(x) -> str:
    """A number as error messages write it: ``repr`` of the float (``-6.0``)."""
    return repr(float(x))


def format_point(p) -> str:
    """A point as error messages write it: ``(81.0, 3.0)``."""
    return f"({format_number(p[0])}, {format_number(p[1])})"
