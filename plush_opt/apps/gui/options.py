"""Options of the posing window (no numpy, no matplotlib: the command line
imports this to build its parser)."""

from __future__ import annotations

import os
from dataclasses import dataclass

# the window runs the loop for as long as the user wants: no iteration budget
UNLIMITED_ITERATIONS = 10**9


@dataclass(frozen=True)
class GuiOptions:
    """Options of the posing session and its window.

    Attributes
    ----------
    interval_ms : period of the timer that steps the control loop, ms
        (each tick takes at most one iterate).
    send_rate : board commands per second at most (the latest pose wins;
        the last one is always sent).
    poll_rate : board position reads per second (they also keep the
        board's watchdog fed while nothing moves).
    pick_radius : how close (pixels) a press must be to a target marker to
        grab it, or to the body to start a new target.
    target_weight : weight w_k of targets made by dragging.
    save_path : where ``s`` writes the result JSON (the PNG goes next to
        it, same name, ``.png``); default ``out/gui-<timestamp>.json``.
    control : :class:`~plush_opt.control.gradient.ControlOptions` of the
        loop; default: the loop's defaults with no iteration or time limit.
    equilibrium : :class:`~plush_opt.solve.equilibrium.EquilibriumOptions` of the
        forward solves (sliders, reset); default: without the eigenvalue
        (the one a saved result needs is computed when saving).
    max_history : iterates a controller keeps before the session starts a
        fresh one from the current pose (bounds the memory of long sessions).
    rate_window : seconds over which the status line's iterate rate is
        counted (long enough to smooth, short enough to follow a change).
    status_period : seconds between redraws of the status numbers at most
        (text costs as much to draw as the mesh).
    slider_period : seconds between redraws of a slider's value at most
        (same reason; the pose itself is redrawn at once).
    figsize : window size, inches.
    """

    interval_ms: int = 30
    send_rate: float = 20.0
    poll_rate: float = 5.0
    pick_radius: float = 10.0
    target_weight: float = 1.0
    save_path: str | os.PathLike | None = None
    control: object | None = None
    equilibrium: object | None = None
    max_history: int = 2000
    rate_window: float = 2.0
    status_period: float = 0.2
    slider_period: float = 0.1
    figsize: tuple[float, float] = (13.0, 7.6)

    def __post_init__(self):
        if not (isinstance(self.interval_ms, int) and self.interval_ms >= 1):
            raise ValueError(f"interval_ms: expected an integer >= 1, got {self.interval_ms!r}")
        for name in ("send_rate", "poll_rate", "pick_radius", "target_weight", "rate_window"):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"{name}: expected > 0, got {value!r}")
        for name in ("status_period", "slider_period"):
            value = getattr(self, name)
            if not value >= 0:
                raise ValueError(f"{name}: expected >= 0, got {value!r}")
        if self.max_history < 2:
            raise ValueError(f"max_history: expected >= 2, got {self.max_history!r}")

    def control_options(self):
        """The loop's options: ``control``, or the defaults without limits."""
        if self.control is not None:
            return self.control
        from ...control.gradient import ControlOptions
        return ControlOptions(max_iterations=UNLIMITED_ITERATIONS)

    def equilibrium_options(self):
        """The forward solves' options: ``equilibrium``, or the defaults
        without the eigenvalue."""
        if self.equilibrium is not None:
            return self.equilibrium
        from ...solve.equilibrium import EquilibriumOptions
        return EquilibriumOptions(eigenvalue=False)
