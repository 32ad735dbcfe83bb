"""Marker positions predicted by the model, and their derivatives.

One :class:`Predictor` per calibration: for parameters theta it builds the
model once (the mesh stays), solves the equilibrium of every pose, each
warm-started from that pose's last accepted equilibrium moved to first
order, x + dx/dtheta (theta - theta_accepted), and gives the
marker positions y and, from the converged Newton factor,

    H dx/dtheta = -d2E/dx dtheta,    dy/dtheta = B dx/dtheta

(:func:`~plush_opt.solve.sensitivity.implicit_derivative`)
(B the markers' barycentric selection): one back-substitution per
parameter and pose, never a finite difference of solves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..solve.equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium
from ..solve.sensitivity import implicit_derivative
from ..base.errors import SolverError
from ..io.measurement import Measurements
from ..fem.mesh import Mesh
from ..fem.model import Model, build_model
from ..fem.objective import Targets
from .parameters import Values, mixed_columns, scene_with, values_from_theta


@dataclass(frozen=True)
class Prediction:
    """Markers at the equilibria of every pose for one theta.

    ``y`` (n_poses, n_markers, 2); ``jacobian`` (n_poses, 2 n_markers,
    n_params) dy/dtheta or None; ``equilibria`` one per pose.
    """

    theta: np.ndarray
    values: Values
    model: Model
    y: np.ndarray
    jacobian: np.ndarray | None
    equilibria: tuple[Equilibrium, ...]
    dx: tuple[np.ndarray, ...] | None = None    # dx/dtheta per pose, (n_dofs, n_params)


class Predictor:
    """Equilibria and marker sensitivities of the measured poses."""

    def __init__(self, meas: Measurements, mesh: Mesh, params, base: Values,
                 options: EquilibriumOptions | None = None):
        self.meas, self.mesh, self.params, self.base = meas, mesh, tuple(params), base
        self.options = options or EquilibriumOptions(eigenvalue=False)
        self.markers = Targets.at_points(mesh, meas.markers, np.zeros_like(meas.markers))
        self.B = self.markers.selection(2 * mesh.n_nodes)
        self._accepted: Prediction | None = None
        self.solves = 0
        self.order = _chain(meas.contractions, meas.scene.contraction)

    def accept(self, pred: Prediction) -> None:
        """Warm-start later solves from these equilibria."""
        self._accepted = pred

    def _warm(self, i: int, theta: np.ndarray) -> np.ndarray | None:
        acc = self._accepted
        if acc is None:
            return None
        x = acc.equilibria[i].x
        if acc.dx is None:
            return x
        return x + acc.dx[i] @ (theta - acc.theta)

    def __call__(self, theta, jacobian: bool = True) -> Prediction:
        """Predict every pose at ``theta``; SolverError if a pose has no
        certified equilibrium (from its warm start or from rest)."""
        theta = np.asarray(theta, dtype=np.float64)
        values = values_from_theta(self.base, self.params, theta)
        model = build_model(scene_with(self.meas.scene, values), self.mesh)
        n_poses, n_markers = self.meas.n_poses, self.meas.n_markers
        y = np.empty((n_poses, n_markers, 2))
        J = np.empty((n_poses, 2 * n_markers, len(self.params))) if jacobian else None
        eqs, dxs = [None] * n_poses, [None] * n_poses
        previous = None
        for i in self.order:
            c = self.meas.contractions[i] + values.winch_offset
            x0 = self._warm(i, theta)
            eq = self._solve(model, c, x0 if x0 is not None else _tangent(model, previous, c), i)
            previous = eqs[i] = eq
            y[i] = (self.B @ eq.x).reshape(-1, 2)
            if jacobian:
                D = mixed_columns(model, values, self.params, eq.x, c)
                dxs[i] = implicit_derivative(eq.factor, D)
                J[i] = self.B @ dxs[i]
        return Prediction(theta, values, model, y, J, tuple(eqs), tuple(dxs) if jacobian else None)

    def _solve(self, model: Model, c, x0, pose: int) -> Equilibrium:
        """From x0 (if admissible), else from the last accepted pose, else from rest."""
        starts = [x0] if x0 is not None and model.admissible(x0) else []
        if self._accepted is not None:
            starts.append(self._accepted.equilibria[pose].x)
        starts.append(None)
        for start in starts:
            self.solves += 1
            eq = solve_equilibrium(model, c, start, self.options)
            if eq.converged:
                break
        if not eq.converged or eq.factor is None:
            raise SolverError(f"poses[{pose}]: no equilibrium at these parameters: {eq.status}")
        return eq


def _tangent(model: Model, eq: Equilibrium | None, c) -> np.ndarray | None:
    """The pose at contraction ``c`` to first order from equilibrium ``eq``
    (dx = -H^-1 d2E/dx dc dc, with eq's factor): the first solve of each
    pose starts from the previous pose moved along its tangent."""
    if eq is None:
        return None
    dc = np.asarray(c) - eq.contraction
    return eq.x + implicit_derivative(eq.factor, (model.mixed(eq.x, eq.contraction) @ dc)[:, None])[:, 0]


def _chain(contractions: np.ndarray, start: np.ndarray) -> list[int]:
    """Poses in the order of a short path through contraction space from
    ``start`` (greedy nearest neighbour): the first sweep solves each pose
    from the one before it, so the steps between them should be small."""
    left, order, here = list(range(len(contractions))), [], np.asarray(start, dtype=np.float64)
    while left:
        k = min(left, key=lambda i: float(np.linalg.norm(contractions[i] - here)))
        left.remove(k)
        order.append(k)
        here = contractions[k]
    return order
