"""The control side of scripted runs and interactive sessions: one model,
its current certified pose, and the two things a robot is asked to do
(go to contractions, go to targets)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .control.gradient import ControlOptions, Controller
from .equilibrium import solve_equilibrium
from .errors import SceneError, SolverError
from .mesh import build_mesh
from .model import build_model
from .objective import Targets
from .scene import load_scene


class ControlPlanner:
    """Implements :class:`plush_opt.runs.Planner` on the real model.

    Keeps the current contractions and pose: each forward solve and each
    control run starts from where the previous one ended (warm starts).
    """

    def __init__(self, problem: Path | str, options: ControlOptions | None = None):
        self.scene = load_scene(problem)
        self.mesh = build_mesh(self.scene)
        self.model = build_model(self.scene, self.mesh)
        self.options = options or ControlOptions()
        self.winch_names = self.model.winch_names
        self.lower = self.model.lower
        self.upper = self.model.upper
        self.contraction = self.scene.contraction.copy()
        eq = solve_equilibrium(self.model, self.contraction, options=self.options.equilibrium)
        if not eq.converged:
            raise SolverError(f"{self.scene.source}: starting pose: {eq.status}")
        self.x = eq.x

    def _named(self, c) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.winch_names, c)}

    def forward(self, contraction: dict[str, float]) -> dict:
        c = self.contraction.copy()
        for name, value in contraction.items():
            if name not in self.winch_names:
                raise SceneError(f"contraction: no winch named {name!r}")
            c[self.winch_names.index(name)] = float(value)
        eq = solve_equilibrium(self.model, c, self.x, self.options.equilibrium)
        if eq.converged:
            self.contraction, self.x = c, eq.x
        return {"contraction": self._named(c), "objective": 0.0, "converged": eq.converged,
                "status": eq.status}

    def pose(self, targets: list[dict], freeze: list[str], max_time: float) -> Iterator[dict]:
        goal = Targets.at_points(self.mesh, [t["at"] for t in targets], [t["to"] for t in targets],
                                 [t.get("weight", 1.0) for t in targets])
        frozen = np.array([n in freeze for n in self.winch_names])
        ctl = Controller(self.model, goal, self.contraction, frozen, self.x,
                         dataclasses.replace(self.options, max_time=max_time))
        t0 = time.perf_counter()
        for it in ctl.iterates():
            self.contraction, self.x = it.contraction.copy(), it.x
            yield {"contraction": self._named(it.contraction), "objective": it.objective,
                   "converged": False, "status": "running", "t": time.perf_counter() - t0}
        last = ctl.history[-1]
        yield {"contraction": self._named(last.contraction), "objective": last.objective,
               "converged": ctl.converged, "status": ctl.status, "t": time.perf_counter() - t0}
