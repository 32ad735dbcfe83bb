"""Contraction bounds by reparametrisation: c = f(xi), lower <= f <= upper.

f is the identity away from the bounds and bends smoothly onto them in a
blend zone of width 2 delta around each bound:

    f(xi) = xi                                  lower + delta <= xi <= upper - delta
    f(xi) = xi - (xi - upper + delta)^2 / (4 delta)   upper - delta < xi < upper + delta
    f(xi) = upper                               xi >= upper + delta

(and the mirror image at the lower bound). f is C1, monotone, never leaves
[lower, upper] and reaches a bound exactly at xi = bound +- delta. The loop
keeps xi inside [lower - delta, upper + delta] (past that f is flat and a
saturated winch would have no gradient to come back with), and its search
direction floors f' at ``slope_floor`` so a winch sitting on a bound moves
back as soon as the gradient points inwards.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Reparametrisation:
    """f and f' for a set of winches, arrays (n_winches,)."""

    lower: np.ndarray
    upper: np.ndarray
    delta: np.ndarray

    @classmethod
    def for_bounds(cls, lower, upper, blend: float = 0.02) -> "Reparametrisation":
        lower = np.asarray(lower, dtype=np.float64)
        upper = np.asarray(upper, dtype=np.float64)
        if np.any(upper <= lower):
            raise ValueError("bounds: every lower must be < upper")
        if not 0 < blend <= 0.25:
            raise ValueError(f"blend: expected 0 < blend <= 0.25, got {blend!r}")
        return cls(lower, upper, blend * (upper - lower))

    def f(self, xi) -> np.ndarray:
        xi = np.clip(np.asarray(xi, dtype=np.float64), self.lower - self.delta, self.upper + self.delta)
        c = xi.copy()
        d = self.delta
        hi = xi > self.upper - d
        c[hi] = xi[hi] - (xi[hi] - self.upper[hi] + d[hi]) ** 2 / (4 * d[hi])
        lo = xi < self.lower + d
        c[lo] = xi[lo] + (self.lower[lo] + d[lo] - xi[lo]) ** 2 / (4 * d[lo])
        return np.clip(c, self.lower, self.upper)  # exact already; clip guards round-off

    def df(self, xi) -> np.ndarray:
        xi = np.clip(np.asarray(xi, dtype=np.float64), self.lower - self.delta, self.upper + self.delta)
        s = np.ones_like(xi)
        d = self.delta
        hi = xi > self.upper - d
        s[hi] = 1 - (xi[hi] - self.upper[hi] + d[hi]) / (2 * d[hi])
        lo = xi < self.lower + d
        s[lo] = 1 - (self.lower[lo] + d[lo] - xi[lo]) / (2 * d[lo])
        return s

    def inverse(self, c) -> np.ndarray:
        """A xi with f(xi) = c (the one inside the blend zone at a bound)."""
        c = np.clip(np.asarray(c, dtype=np.float64), self.lower, self.upper)
        xi = c.copy()
        d = self.delta
        # upper blend: c = xi - (xi - u + d)^2/(4d); with t = xi - u + d in [0, 2d]:
        # c - u + d = t - t^2/(4d)  =>  t = 2d (1 - sqrt(1 - (c - u + d)/d))
        hi = c > self.upper - d
        s = (c[hi] - self.upper[hi] + d[hi]) / d[hi]
        xi[hi] = self.upper[hi] - d[hi] + 2 * d[hi] * (1 - np.sqrt(np.clip(1 - s, 0, None)))
        lo = c < self.lower + d
        s = (self.lower[lo] + d[lo] - c[lo]) / d[lo]
        xi[lo] = self.lower[lo] + d[lo] - 2 * d[lo] * (1 - np.sqrt(np.clip(1 - s, 0, None)))
        return xi

    def clamp(self, xi) -> np.ndarray:
        return np.clip(xi, self.lower - self.delta, self.upper + self.delta)
