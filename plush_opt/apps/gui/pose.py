"""The pose on screen and the history it follows: the posing session's
fork of the problem's plant (:class:`~plush_opt.solve.plant.Plant`),
committed at every pose shown."""

from __future__ import annotations

import time

import numpy as np

from ...solve.equilibrium import Equilibrium

# where a path-dependent state on screen was driven from (slider moves and
# loop iterates alike: each is reached from the pose shown before it)
SHOWN_BEFORE = "the pose on screen before"


class ShownPose:
    """The pose on screen and the history it follows.

    Every pose shown is committed to ``plant`` (the session's fork of the
    problem's :class:`~plush_opt.solve.plant.Plant`), so a slider move and
    the control loop both start from what is on screen; where the pose
    depends on the path (friction at via points) the robot is driven from
    it, from the scene's start state at first.

    Attributes
    ----------
    plant : the session's plant.
    equilibrium : the equilibrium on screen (None before the first).
    contraction : (n_winches,) its contractions.
    forward_solves : forward solves so far.
    solve_seconds : wall time of every solve of the session (s).
    """

    def __init__(self, plant, options):
        self.plant = plant
        self.options = options            # the forward solves' EquilibriumOptions
        self.equilibrium: Equilibrium | None = None
        self.contraction = None
        self.forward_solves = 0
        self.solve_seconds = 0.0
        self._certified = None            # (equilibrium, the same pose with its eigenvalue)

    @property
    def x(self) -> np.ndarray:
        """(n_dofs,) flat pose on screen."""
        return self.equilibrium.x

    def forward(self, contraction, x0) -> Equilibrium:
        """The pose at ``contraction`` reached from the pose on screen
        (warm-started from ``x0`` where the pose does not depend on the path)."""
        t0 = time.perf_counter()
        eq = self.plant.drive(contraction, x0, self.options, origin=SHOWN_BEFORE)
        self.solve_seconds += time.perf_counter() - t0
        self.forward_solves += 1
        return eq

    def show(self, eq: Equilibrium) -> None:
        """Put ``eq`` on screen: the history now ends there."""
        self.equilibrium = eq
        self.contraction = eq.contraction.copy()
        self.plant.commit(eq)

    def certified(self) -> Equilibrium:
        """The pose on screen with its smallest Hessian eigenvalue, which a
        saved result reports. The loop and the forward solves skip it (it
        costs a few solves), so it is computed here, once per pose: by one
        Newton check from the pose (:meth:`~plush_opt.solve.plant.Plant.certify`:
        where the pose depends on the path, at its state's segment rest
        lengths), unless it has it."""
        eq = self.equilibrium
        if eq.min_eigenvalue is not None:
            return eq
        if self._certified is None or self._certified[0] is not eq:
            t0 = time.perf_counter()
            checked = self.plant.certify(eq, self.options, origin=SHOWN_BEFORE)
            self.solve_seconds += time.perf_counter() - t0
            self._certified = (eq, checked)
        return self._certified[1]
