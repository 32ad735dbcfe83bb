"""``python -m plush_opt``: the same as the ``plush-opt`` command."""

import os
import signal
import sys


def _quit_while_starting(signum, frame):
    # Ctrl-C (or a TERM) while the command line is imported: nothing is open
    # or written yet, and an import interrupted inside a C module would turn
    # the KeyboardInterrupt into an ImportError with a traceback
    name = signal.Signals(signum).name
    os.write(2, f"plush-opt: interrupted ({name})\n".encode())
    os._exit(128 + signum)


_STARTING = {s: signal.signal(s, _quit_while_starting) for s in (signal.SIGINT, signal.SIGTERM)}
from plush_opt.apps.cli import main  # noqa: E402 - after the handlers above
for _signum, _handler in _STARTING.items():
    signal.signal(_signum, _handler)

try:
    code = main()
except KeyboardInterrupt:   # a Ctrl-C in the instant after main() put the default handler back
    os.write(2, b"plush-opt: interrupted (SIGINT)\n")
    code = 130
# The command is done: a signal now changes nothing (at exit, CPython would
# otherwise kill itself with a SIGINT that arrived late)
for _signum in (signal.SIGINT, signal.SIGTERM):
    signal.signal(_signum, signal.SIG_IGN)
# Under ``-m``, CPython exits by SIGINT (not with ``code``) when a Ctrl-C, even
# one main() caught, ended code run from a string (dataclasses build their
# methods so); a string evaluation resets that flag.
exec("None")   # noqa: S102 - a constant string
sys.exit(code)
