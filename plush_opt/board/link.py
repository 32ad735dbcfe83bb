"""The one way apps talk to a winch board.

Contractions are ``{winch name: length}`` in the problem's length unit
everywhere above this module; only the driver converts them to ticks.
Every app (scripted runs, the posing window) holds a :class:`BoardLink`
and never a :class:`~plush_opt.board.driver.Driver` or an emulator
process of its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol


class BoardLink(Protocol):
    """A winch board as the apps see it.

    Implementations: a serial board, the host emulator behind a serial
    line, and a dry run that checks and records but moves nothing.
    """

    @property
    def winch_names(self) -> tuple[str, ...]:
        """The winches this board drives (its calibration's order)."""

    def send(self, contraction: Mapping[str, float]) -> None:
        """Command these contractions (a subset of the winches is allowed).

        Raises :class:`~plush_opt.errors.HardwareError` for a name the board
        does not drive or a value outside the allowed range, before anything
        is sent."""

    def positions(self) -> dict[str, float] | None:
        """Measured contractions, or None when the board cannot measure."""

    def moving(self) -> bool:
        """True while any winch is still on its way to its command."""

    def stop(self) -> None:
        """Stop every winch where it is."""

    def close(self) -> None:
        """Stop and release the board (and any process behind it)."""
