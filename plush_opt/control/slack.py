"""Winches whose tendons are all slack, and how to take the slack up.

A winch whose tendons are all slack (G <= -eps) has a zero gradient:
nothing tells a local method whether pulling would help. Both control
methods detect it and reel the slack in to where the tightest tendon just
enters the smoothing zone, which leaves the pose unchanged.
"""

from __future__ import annotations

import numpy as np

from ..fem.model import Model

# Where the take-up leaves the tightest tendon: this fraction of eps inside
# the smoothing zone (G = -(1 - SLACK_MARGIN) eps), so E (and the pose) is
# unchanged but the next pull already has a gradient.
SLACK_MARGIN = 0.1


def slack_winches(model: Model, x, c, free, gradient=None) -> list[int]:
    """Free winches (bool mask ``free``) whose tendons are all slack at (x, c).

    With ``gradient`` given, only those whose gradient is exactly zero."""
    if not model.has_tendons:
        return []
    G = model.tendon_state(x, c)["stretch"]
    eps = model.tendon_smoothing
    out = []
    for w in np.flatnonzero(free):
        mine = model.tendon_winch == w
        if gradient is not None and gradient[w] != 0.0:
            continue
        if mine.any() and np.all(G[mine] <= -eps):
            out.append(int(w))
    return out


def take_up(model: Model, x, c, w: int) -> float:
    """The contraction of winch ``w`` at which its tightest tendon is just
    inside the smoothing zone (not clipped to the bounds)."""
    G = model.tendon_state(x, c)["stretch"]
    eps = model.tendon_smoothing
    mine = model.tendon_winch == w
    return float(c[w] + (float(np.min(-G[mine] - eps)) + SLACK_MARGIN * eps))
