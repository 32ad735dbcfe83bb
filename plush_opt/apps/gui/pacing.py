"""Board pacing: the poses of a session go to a :class:`BoardLink` at a
bounded rate (the latest pose wins, the last one is always sent), and its
positions are read now and then (which also keeps its watchdog fed)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping

from ...board.link import BoardLink

log = logging.getLogger(__name__)

# commands remembered in ``BoardPacer.sent`` (enough to look back over a
# minute at the default rate; a long session does not grow)
SENT_KEPT = 1000


class BoardPacer:
    """Sends a session's poses to a board at most ``send_rate`` times a
    second and reads its positions ``poll_rate`` times a second.

    A board error is kept (``error``), the board is told to stop, and
    nothing more is sent: the session goes on as a simulation.

    Attributes
    ----------
    sends : commands sent.
    sent : (clock time, contraction dict) of the last commands sent.
    measured : the last positions read, or None.
    error : the board error that stopped it, or None.
    stopped : :meth:`stop` was called: nothing more is sent.
    """

    def __init__(self, board: BoardLink, clock: Callable[[], float], *, send_rate: float,
                 poll_rate: float):
        self.board = board
        self.clock = clock
        self.send_period = 1.0 / send_rate
        self.poll_period = 1.0 / poll_rate
        self.pending: dict[str, float] | None = None   # latest pose not yet sent
        self._last_send = -math.inf
        self._last_poll = -math.inf
        self.sends = 0
        self.sent: list[tuple[float, dict[str, float]]] = []
        self.measured: dict[str, float] | None = None
        self.error: str | None = None
        self.stopped = False

    def queue(self, contraction: Mapping[str, float]) -> None:
        """The pose to send next (replaces one not sent yet)."""
        self.pending = {n: float(c) for n, c in contraction.items()}

    def service(self) -> str | None:
        """Send the pending pose if the rate allows; read positions if it is
        time. Returns the error message if the board failed just now."""
        if self.error is not None or self.stopped:
            return None
        now = self.clock()
        try:
            if self.pending is not None and now - self._last_send >= self.send_period:
                self.board.send(self.pending)
                self.sends += 1
                self.sent.append((now, self.pending))
                del self.sent[:-SENT_KEPT]
                self.pending = None
                self._last_send = now
            if now - self._last_poll >= self.poll_period:
                self._last_poll = now
                self.measured = self.board.positions()
        except Exception as exc:  # noqa: BLE001 - show it, stop the board, keep the session
            self.error = str(exc)
            log.error("board error: %s", exc)
            self._stop_board()
            return self.error
        return None

    def stop(self) -> None:
        """Stop the winches and send nothing more (idempotent; after a board
        error it tries once more); never raises."""
        if self.stopped:
            return
        self.stopped = True
        self._stop_board()

    def _stop_board(self) -> None:
        try:
            self.board.stop()
            log.info("board stopped")
        except Exception as exc:  # noqa: BLE001 - stopping must not fail the caller
            log.error("could not stop the board: %s", exc)

    def lag(self, contraction: Mapping[str, float]) -> float | None:
        """Largest |measured - shown| contraction, or None if unknown."""
        if not self.measured:
            return None
        diffs = [abs(self.measured[n] - c) for n, c in contraction.items() if n in self.measured]
        return max(diffs) if diffs else None

    def state(self) -> dict:
        """For a saved result: commands, error, last measured positions."""
        return {"commands": self.sends, "error": self.error,
                "measured": None if self.measured is None else dict(self.measured)}
