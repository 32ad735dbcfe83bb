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


class ReparamBounds:
    """Bounds by reparametrisation: the loop steps on xi, c = f(xi).

    ``blend`` is the blend zone's width as a fraction of each range; a
    winch within that fraction of a bound counts as held there."""

    name = "reparam"

    def __init__(self, lower, upper, blend: float):
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.reparam = Reparametrisation.for_bounds(lower, upper, blend)
        self.blend = blend

    def to_xi(self, c) -> np.ndarray:
        return self.reparam.inverse(c)

    def f(self, xi) -> np.ndarray:
        return self.reparam.f(xi)

    def slope(self, xi, floor: float) -> np.ndarray:
        """f', floored so a winch sitting on a bound can come back."""
        return np.maximum(self.reparam.df(xi), floor)

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Where xi stops: past these f is flat."""
        return self.lower - self.reparam.delta, self.upper + self.reparam.delta

    def clamp(self, xi) -> np.ndarray:
        return self.reparam.clamp(xi)

    def predicted(self, xi, step, floor: float) -> np.ndarray:
        """The xi whose contraction is the one the step's linear model
        predicts, f(xi) + f'(xi) step (f' floored at ``floor``, as the search
        direction uses it), kept within the bounds; a winch with no step
        keeps its xi. Away from the blend zones this is xi + step; inside
        them f(xi + step) moves a winch the floor had scaled down by up to
        1 / ``floor`` times what the model predicted."""
        c = np.clip(self.f(xi) + self.slope(xi, floor) * step, self.lower, self.upper)
        return np.where(step == 0, xi, self.to_xi(c))

    def margin(self) -> np.ndarray:
        """How close to a bound a winch counts as held there."""
        return (self.upper - self.lower) * self.blend


class ClipBounds:
    """Bounds by clipping: the loop steps on c itself and clips (the baseline)."""

    name = "clip"
    # a winch counts as held when it is at its bound to round-off
    HELD = 1e-12

    def __init__(self, lower, upper):
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)

    def to_xi(self, c) -> np.ndarray:
        return np.array(c, dtype=np.float64)

    def f(self, xi) -> np.ndarray:
        return np.clip(xi, self.lower, self.upper)

    def slope(self, xi, floor: float) -> np.ndarray:
        return np.ones_like(xi)

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        return self.lower, self.upper

    def clamp(self, xi) -> np.ndarray:
        return np.clip(xi, self.lower, self.upper)

    def predicted(self, xi, step, floor: float) -> np.ndarray:
        """The step's contraction, clipped (the linear model's prediction itself)."""
        return self.clamp(xi + step)

    def margin(self) -> np.ndarray:
        return (self.upper - self.lower) * self.HELD


def bounds_strategy(name: str, lower, upper, blend: float):
    """The bounds strategy called ``name`` ('reparam' or 'clip')."""
    if name == "reparam":
        return ReparamBounds(lower, upper, blend)
    if name == "clip":
        return ClipBounds(lower, upper)
    raise ValueError(f"bounds: expected 'reparam' or 'clip', got {name!r}")
