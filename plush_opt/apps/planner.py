"""The control side of scripted runs and interactive sessions: one problem,
its current certified pose, and the two things a robot is asked to do
(go to contractions, go to targets)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from plush_opt import problem as problems
from plush_opt.control.gradient import ControlOptions, Controller
from plush_opt.base.errors import SolverError
from plush_opt.fem.objective import Targets

# A pose step that ends farther than this fraction of the body's size from
# its targets (RMS) is reported as poor: a few percent is already visible.
FAR_FROM_TARGETS = 0.02


class ControlPlanner:
    """Implements :class:`plush_opt.apps.runs.Planner` on the real model.

    Keeps the current contractions and pose: each forward solve and each
    control run starts from where the previous one ended (warm starts).
    Its own fork of the problem's plant (:class:`~plush_opt.solve.plant.Plant`)
    holds what the robot went through: every step is driven from the state
    the steps before left (with friction at via points the robot's friction
    state, so what it does depends on them).
    """

    def __init__(self, problem: Path | str, options: ControlOptions | None = None):
        self.problem = problems.load(problem)
        self.options = options or ControlOptions()
        model = self.problem.model
        self.winch_names = model.winch_names
        self.lower = model.lower
        self.upper = model.upper
        self.contraction = self.problem.scene.contraction.copy()
        eq = self.problem.equilibrium(options=self.options.equilibrium)
        if not eq.converged:
            raise SolverError(f"{self.problem.source}: starting pose: {eq.status}")
        self.x = eq.x
        self.plant = self.problem.plant.fork()         # the robot's history: committed steps
        self.plant.commit(eq)

    @property
    def state(self):
        """The robot's committed state (the plant's, :attr:`Plant.state`)."""
        return self.plant.state

    def _named(self, c) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.winch_names, c)}

    def forward(self, contraction: dict[str, float]) -> dict:
        """Equilibrium at these contractions (the others keep theirs); raises
        :class:`~plush_opt.base.errors.SceneError` for an unknown winch or a value outside its bounds."""
        c = self.problem.contraction_vector({**self._named(self.contraction), **contraction})
        eq = self.plant.drive(c, self.x, self.options.equilibrium, origin="the run's previous step")
        c = eq.contraction
        if eq.converged:
            self.contraction, self.x = c.copy(), eq.x
            self.plant.commit(eq)
        return {"contraction": self._named(c), "objective": 0.0, "converged": eq.converged,
                "status": eq.status}

    def check_targets(self, targets: list[dict]) -> None:
        """Raise :class:`~plush_opt.base.errors.SceneError` (``targets[k].at: ...``)
        for a target off the body: a run checks every pose step before it starts."""
        Targets.at_points(self.problem.mesh, [t["at"] for t in targets], [t["to"] for t in targets],
                          [t.get("weight", 1.0) for t in targets])

    def pose(self, targets: list[dict], freeze: list[str], max_time: float) -> Iterator[dict]:
        goal = Targets.at_points(self.problem.mesh, [t["at"] for t in targets], [t["to"] for t in targets],
                                 [t.get("weight", 1.0) for t in targets])
        frozen = np.array([n in freeze for n in self.winch_names])
        options = dataclasses.replace(self.options, max_time=max_time)
        ctl = Controller(self.problem.model, goal, self.contraction, frozen, self.x, options, plant=self.plant)
        for it in ctl.iterates():             # the controller commits every iterate to the plant
            self.contraction, self.x = it.contraction.copy(), it.x
            yield {"contraction": self._named(it.contraction), "objective": it.objective,
                   "converged": False, "status": "running", "certified": it.dispatchable}
        last = ctl.history[-1]
        # the loop's time rule decides its stop (or skips a look-further move) once
        # its last iterate is past max_time: then the pose depends on the computer's speed
        yield {"contraction": self._named(last.contraction), "objective": last.objective,
               "converged": ctl.converged, "status": ctl.status, "certified": last.dispatchable,
               "time_limited": last.t_wall >= max_time, "rms_error": goal.rms_error(last.x),
               "far_error": FAR_FROM_TARGETS * self.problem.scene.diameter}
