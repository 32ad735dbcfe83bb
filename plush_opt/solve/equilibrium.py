"""Quasi-static equilibria: local minimisers of E(x; c), by one call,
:func:`solve_equilibrium`.

Two backends on the same energy:

* ``newton`` (default, :mod:`plush_opt.solve.newton`): Newton on the exact
  sparse Hessian, CHOLMOD factorisation (symbolic analysis once per model),
  backtracking line search that never accepts a non-admissible pose (some
  J <= 0) or a non-finite energy, a multiple of the identity added when the
  Hessian is not positive definite, and an escape along the most negative
  curvature direction when the gradient vanishes at a saddle.
* ``ipopt`` (:mod:`plush_opt.solve.ipopt_equilibrium`): IPOPT minimising the
  CasADi expression of E, for cross-checks (:class:`IpoptEquilibrium`,
  which keeps the NLPs it builds for its model; no module holds state).

Both return an :class:`Equilibrium` that is *certified* by the same test
(:mod:`plush_opt.solve.certificate`): ``converged`` only if the residual
|grad_x E| is within tolerance relative to the force scale and the
Hessian is positive definite (Cholesky succeeds).
"""

from __future__ import annotations

import numpy as np

from ..base.errors import SolverError
from ..fem.model import Model
from .certificate import BACKENDS, LEFT_BRANCH, Equilibrium, EquilibriumOptions, certify, residual
from .ipopt_equilibrium import IpoptEquilibrium
from .newton import solve_newton

__all__ = ["BACKENDS", "LEFT_BRANCH", "Equilibrium", "EquilibriumOptions", "IpoptEquilibrium", "certify",
           "residual", "solve_equilibrium"]


def solve_equilibrium(model: Model, contraction, x0=None, options: EquilibriumOptions | None = None,
                      ipopt: IpoptEquilibrium | None = None, chord=None) -> Equilibrium:
    """Equilibrium of ``model`` at ``contraction`` (n_winches,), from ``x0``
    (flat or (n_nodes, 2); default the rest pose). ``x0`` must be admissible.

    ``ipopt`` : the IPOPT backend's solver of this model, which keeps the
    NLPs it built (default: a new one, built for this solve alone).
    ``chord`` : the factor of a nearby certified equilibrium (Newton's
    first steps reuse it while they converge fast: :func:`solve_newton`)."""
    options = options or EquilibriumOptions()
    c = np.array(contraction, dtype=np.float64).reshape(-1)
    if c.shape != (model.n_winches,):
        raise SolverError(f"contraction: expected {model.n_winches} values, got {c.size}")
    x = model.X.copy() if x0 is None else np.array(x0, dtype=np.float64).reshape(-1)
    if x.shape != (model.n_dofs,):
        raise SolverError(f"x0: expected {model.n_dofs} coordinates, got {x.size}")
    if options.backend == "ipopt":
        if ipopt is None:
            ipopt = IpoptEquilibrium(model)
        elif ipopt.model is not model:
            raise ValueError("ipopt: an IpoptEquilibrium of another model")
        return ipopt.solve(c, x, options)
    return solve_newton(model, c, x, options, chord)
