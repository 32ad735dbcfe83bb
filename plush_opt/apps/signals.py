"""One signal policy for every command: SIGTERM and SIGHUP end a command
the way Ctrl-C does (the board stopped, the run log closed with its end
line), and a repeated signal does not cut that cleanup short."""

from __future__ import annotations

import os
import signal
import threading
import time


#: Signals that end a command the way Ctrl-C does (the board stopped, the
#: run log closed with its end line); their exit status is 128 + signum.
TERMINATING_SIGNALS = ("SIGTERM", "SIGHUP")
CLEANUP_GRACE = 10.0    # s after a first signal during which a repeated one does not cut the cleanup short


def handle_signals() -> dict:
    """SIGTERM and SIGHUP raise :class:`~plush_opt.base.errors.Interrupted` in the
    main thread (Ctrl-C its KeyboardInterrupt), once, and note it
    (:func:`~plush_opt.base.errors.note_interrupt`) for the solvers whose C++
    loops would swallow the exception: a second signal during the cleanup is ignored, so the
    cleanup (stop the board, end the log) is not cut short. Returns the
    previous handlers."""
    from ..base.errors import Interrupted, clear_interrupt, note_interrupt, signals_only_noted
    clear_interrupt()
    if threading.current_thread() is not threading.main_thread():
        return {}
    fired = []

    def again(signum) -> bool:
        """A repeated signal: ignored during the cleanup; after it, the
        default action (a command that swallowed the first still ends)."""
        if not fired:
            fired.append(time.monotonic())
            return False
        if time.monotonic() - fired[0] > CLEANUP_GRACE:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
        return True

    def handler(signum, frame):
        if not again(signum):
            exc = Interrupted(signum, signal.Signals(signum).name)
            note_interrupt(exc)
            if not signals_only_noted():
                raise exc

    def sigint(signum, frame):
        if not again(signum):
            exc = KeyboardInterrupt()
            note_interrupt(exc)
            if not signals_only_noted():
                raise exc

    previous = {}
    for name in TERMINATING_SIGNALS:
        signum = getattr(signal, name, None)
        if signum is not None:
            previous[signum] = signal.signal(signum, handler)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, sigint)
    return previous
