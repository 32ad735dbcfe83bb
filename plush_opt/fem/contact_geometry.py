"""(placeholder until the geometry module lands) The IPC barrier."""

from __future__ import annotations

import numpy as np


def barrier(s, dhat2):
    """b(s) = -(s - dhat2)^2 ln(s / dhat2) for 0 < s < dhat2, else 0; and
    its first and second derivatives in s."""
    s = np.asarray(s, dtype=np.float64)
    active = s < dhat2
    with np.errstate(divide="ignore", invalid="ignore"):
        u = s - dhat2
        log = np.log(s / dhat2)
        b = np.where(active, -u * u * log, 0.0)
        db = np.where(active, -2 * u * log - u * u / s, 0.0)
        d2b = np.where(active, -2 * log - 4 * u / s + u * u / (s * s), 0.0)
    b = np.where(s <= 0, np.inf, b)
    return b, db, d2b
