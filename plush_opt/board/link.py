"""The one way apps talk to a winch board: the :class:`BoardLink` protocol.

Contractions are ``{winch name: length}`` in the problem's length unit
everywhere above this module; only the board package converts them to
ticks (:mod:`plush_opt.board.limits`). Every app (scripted runs, the
posing window) holds a :class:`BoardLink` made by
:func:`plush_opt.board.open_board`, and never a
:class:`~plush_opt.board.driver.Driver` or a simulator process of its own.
The implementations are in :mod:`plush_opt.board.transports`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol


class BoardLink(Protocol):
    """A winch board as the apps see it.

    Implementations: a serial board, a simulated board (the host emulator
    or simavr) behind a pseudo-terminal, and a dry run that checks and
    records but moves nothing (:mod:`plush_opt.board.transports`).
    """

    @property
    def winch_names(self) -> tuple[str, ...]:
        """The winches this board drives (its calibration's order)."""

    def send(self, contraction: Mapping[str, float]) -> None:
        """Command these contractions (a subset of the winches is allowed).

        Raises :class:`~plush_opt.base.errors.HardwareError` for a name the board
        does not drive or a value outside the allowed range, before anything
        is sent."""

    def positions(self) -> dict[str, float] | None:
        """Measured contractions, or None when the board cannot measure."""

    def moving(self) -> bool:
        """True while any winch is still on its way to its command."""

    def clock(self) -> float:
        """The board's time in seconds, what waits for a move are measured in
        (a simulator's own clock runs slower than the wall's under load)."""

    def stop(self) -> None:
        """Stop every winch where it is."""

    def close(self) -> None:
        """Stop and release the board (and any process behind it)."""
