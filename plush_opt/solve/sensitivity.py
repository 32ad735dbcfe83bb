"""Sensitivities of an equilibrium: one implicit differentiation for all.

At an equilibrium grad_x E(x(p), p) = 0 for every parameter p (the winch
contractions c in control, the material and tendon parameters theta in
calibration, the contractions with the stick/slip modes held in the
friction path), so differentiating,

    H dx/dp = -d2E/dx dp                      (H the Hessian of E at x)

:func:`implicit_derivative` solves that with the factorisation of H the
equilibrium solve kept (no new factorisation), and is the one place that
does. For the objective, one adjoint solve whatever the number of winches,

    H lam = dO/dx,     dO/dc = -lam^T d2E/dx dc.

(docs/control.md shows this equals the paper's chain rule through the
tensions, dx/dtau dtau/dc.)
"""

from __future__ import annotations

import numpy as np

from .equilibrium import Equilibrium
from ..base.errors import SolverError
from ..fem.model import Model


def implicit_derivative(factor, mixed, columns=None) -> np.ndarray:
    """dx/dp = -H^-1 d2E/dx dp at an equilibrium.

    Parameters
    ----------
    factor : the factorisation of the Hessian H at the equilibrium (its
        ``solve(B)`` returns H^-1 B for B (n_dofs,) or (n_dofs, m)), as
        the equilibrium solve kept it.
    mixed : (n_dofs, n_params) dense d2E/dx dp, in the units of the
        gradient (force) per unit of each parameter.
    columns : the parameters to differentiate by (indices), default all;
        the other columns of the result are zero.

    Returns
    -------
    (n_dofs, n_params) dx/dp (length per unit of each parameter), laid out
    in memory as ``mixed`` is (its columns contiguous if ``mixed``'s are:
    a product with a strided column rounds differently). A zero column of
    ``mixed`` (a parameter the energy does not depend on here) gives a
    zero column without a solve; the others are solved for in one block.
    """
    mixed = np.asarray(mixed)
    out = np.zeros_like(mixed, dtype=np.float64)      # the same memory layout as ``mixed``
    cols = [j for j in (range(mixed.shape[1]) if columns is None else columns) if np.any(mixed[:, j])]
    if cols:
        # one solve of all the columns at once (a blocked substitution: a
        # fraction of the columns' cost one by one)
        out[:, cols] = -factor.solve(np.asarray(mixed[:, cols], dtype=np.float64)).reshape(len(mixed), len(cols))
    return out


def equilibrium_factor(eq: Equilibrium):
    """The Hessian factorisation ``eq`` kept; a :class:`SolverError` if it
    has none (it is not a certified, positive definite equilibrium)."""
    if eq.factor is None:
        raise SolverError("sensitivity needs a certified equilibrium (positive definite Hessian); "
                          f"this one is not: {eq.status}")
    return eq.factor


def state_sensitivity(model: Model, eq: Equilibrium, columns=None) -> np.ndarray:
    """dx/dc at ``eq``, dense (n_dofs, n_winches) (only ``columns`` if given,
    the others zero)."""
    return implicit_derivative(equilibrium_factor(eq), model.mixed(eq.x, eq.contraction), columns)


def objective_gradient(model: Model, eq: Equilibrium, dO_dx: np.ndarray) -> np.ndarray:
    """dO/dc at ``eq`` by one adjoint solve, (n_winches,)."""
    lam = equilibrium_factor(eq).solve(np.asarray(dO_dx, dtype=np.float64))
    return -(model.mixed(eq.x, eq.contraction).T @ lam)
