"""Sensitivities of an equilibrium with respect to the contractions.

At an equilibrium grad_x E(x(c), c) = 0 for all c, so differentiating,

    H dx/dc = -d2E/dx dc                      (H the Hessian of E at x)

and for the objective, with one adjoint solve whatever the number of winches,

    H lam = dO/dx,     dO/dc = -lam^T d2E/dx dc.

Both reuse the Cholesky factor of H kept by the equilibrium solve: no new
factorisation. (docs/control.md shows this equals the paper's chain rule
through the tensions, dx/dtau dtau/dc.)
"""

from __future__ import annotations

import numpy as np

from .equilibrium import Equilibrium
from ..base.errors import SolverError
from ..fem.model import Model


def _factor(eq: Equilibrium):
    if eq.factor is None:
        raise SolverError("sensitivity needs a certified equilibrium (positive definite Hessian); "
                          f"this one is not: {eq.status}")
    return eq.factor


def state_sensitivity(model: Model, eq: Equilibrium, columns=None) -> np.ndarray:
    """dx/dc at ``eq``, dense (n_dofs, n_winches) (only ``columns`` if given,
    the others zero)."""
    M = model.mixed(eq.x, eq.contraction)
    out = np.zeros_like(M)
    cols = range(model.n_winches) if columns is None else columns
    factor = _factor(eq)
    for w in cols:
        if np.any(M[:, w]):
            out[:, w] = -factor.solve(M[:, w])
    return out


def objective_gradient(model: Model, eq: Equilibrium, dO_dx: np.ndarray) -> np.ndarray:
    """dO/dc at ``eq`` by one adjoint solve, (n_winches,)."""
    lam = _factor(eq).solve(np.asarray(dO_dx, dtype=np.float64))
    return -(model.mixed(eq.x, eq.contraction).T @ lam)
