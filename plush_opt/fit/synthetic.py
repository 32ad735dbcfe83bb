"""Synthetic measurements: markers of a robot whose true parameters are
known, with seeded Gaussian noise. The tests check that a calibration
recovers them; the example in docs/calibration.md is made this way."""

from __future__ import annotations

import numpy as np

from ..solve.equilibrium import EquilibriumOptions, solve_equilibrium
from ..base.errors import SolverError
from ..io.measurement import FORMAT
from ..fem.mesh import Mesh
from ..fem.model import build_model
from ..fem.objective import Targets
from ..io.scene import Scene
from .parameters import Values, scene_with


def true_values(scene: Scene, youngs_modulus=None, poisson_ratio=None, tendon_stiffness=None,
                assembly_offset=None, winch_offset=None) -> Values:
    """The scene's values with the given ones replaced (offsets by name)."""
    v = Values.of_scene(scene)
    d, z = v.assembly_offset.copy(), v.winch_offset.copy()
    names = [t.name for t in scene.tendons]
    for name, value in (assembly_offset or {}).items():
        d[names.index(name)] = value
    for name, value in (winch_offset or {}).items():
        z[scene.winch_names.index(name)] = value
    return Values(youngs_modulus or v.youngs_modulus, poisson_ratio or v.poisson_ratio,
                  tendon_stiffness or v.tendon_stiffness, d, z)


def synthesize(scene: Scene, mesh: Mesh, truth: Values, markers, contractions, *, sigma: float,
               seed: int, problem: str, hidden: float = 0.0) -> dict:
    """A measurement document (``plush-opt-measurements/1``) of ``truth``.

    ``contractions`` (n_poses, n_winches) as the robot reports them (the
    winches are really at contractions + truth.winch_offset); each marker
    coordinate gets N(0, sigma^2) noise; a fraction ``hidden`` of the
    markers is unseen (null) at random.
    """
    rng = np.random.default_rng(seed)
    model = build_model(scene_with(scene, truth), mesh)
    sel = Targets.at_points(mesh, markers, np.zeros_like(np.asarray(markers, float)))
    poses, x = [], None
    for c in np.asarray(contractions, dtype=np.float64):
        eq = solve_equilibrium(model, c + truth.winch_offset, x, EquilibriumOptions(eigenvalue=False))
        if not eq.converged:
            raise SolverError(f"synthetic pose at {c.tolist()}: {eq.status}")
        x = eq.x
        y = sel.y(eq.x) + rng.normal(0.0, sigma, (len(markers), 2))
        seen = rng.random(len(markers)) >= hidden
        poses.append({"contractions": {n: float(v) for n, v in zip(scene.winch_names, c)},
                      "positions": [p.tolist() if s else None for p, s in zip(y, seen)]})
    return {"format": FORMAT, "problem": problem,
            "markers": np.asarray(markers, float).tolist(), "poses": poses, "sigma": float(sigma)}
