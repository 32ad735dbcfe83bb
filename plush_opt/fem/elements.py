"""Element types: the linear 3-node triangle (P1) and the quadratic 6-node
triangle (P2), straight-sided, as docs/problem-format.md defines them.

A P2 triangle lists its nodes ``[a, b, c, ab, bc, ca]`` (corners
counter-clockwise, then the midpoints of edges a-b, b-c, c-a). With
barycentric coordinates (l1, l2, l3) the shape functions are

    N_a = l1 (2 l1 - 1), N_b = l2 (2 l2 - 1), N_c = l3 (2 l3 - 1),
    N_ab = 4 l1 l2,      N_bc = 4 l2 l3,      N_ca = 4 l3 l1.

The geometry is straight-sided, so dl/dX is the constant of the corner
triangle (the rows of Dm^-1) and F(l) = sum_i x_i (dN_i/dX)(l) is linear in
l. The elastic energy uses the 3-point rule (points (2/3, 1/6, 1/6) and its
permutations, weights 1/3): exact for the quadratic integrands of a linear
displacement field and of the mass of a quadratic one. This module holds
what differs between the two element types; the model (plush_opt/fem/model.py)
assembles either the same way.
"""

from __future__ import annotations

import functools

import casadi as ca
import numpy as np

from ..base.kernels import compiled

ELEMENTS = ("P1", "P2")
NODES_PER_ELEMENT = {"P1": 3, "P2": 6}

# The 3-point rule on a triangle (degree 2), barycentric points and weights.
P2_QUAD_POINTS = np.array([[2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])
P2_QUAD_WEIGHTS = np.full(3, 1 / 3)

# Share of an element's mass carried by each node (the exact integral of
# the shape functions: the P2 corner functions integrate to zero).
GRAVITY_SHARE = {"P1": np.full(3, 1 / 3), "P2": np.array([0, 0, 0, 1 / 3, 1 / 3, 1 / 3])}

# The three edges of a P2 triangle, in the order of its midside nodes.
P2_EDGES = ((0, 1), (1, 2), (2, 0))


def shape_values(beta: np.ndarray) -> np.ndarray:
    """The six P2 shape functions at barycentric points, (k, 3) -> (k, 6)."""
    l1, l2, l3 = np.asarray(beta, dtype=np.float64).reshape(-1, 3).T
    return np.stack([l1 * (2 * l1 - 1), l2 * (2 * l2 - 1), l3 * (2 * l3 - 1),
                     4 * l1 * l2, 4 * l2 * l3, 4 * l3 * l1], axis=1)


def interpolation_weights(element: str, beta: np.ndarray) -> np.ndarray:
    """Weights of the element's nodes at barycentric points: beta itself for
    P1, the six shape functions for P2."""
    beta = np.asarray(beta, dtype=np.float64).reshape(-1, 3)
    return shape_values(beta) if element == "P2" else beta


def _shape_derivatives(l1, l2, l3):
    """dN_i/dl_j of the six P2 functions at one point, as a 6 x 3 nested list
    (works on numbers and on CasADi symbols alike)."""
    return [[4 * l1 - 1, 0, 0], [0, 4 * l2 - 1, 0], [0, 0, 4 * l3 - 1],
            [4 * l2, 4 * l1, 0], [0, 4 * l3, 4 * l2], [4 * l3, 0, 4 * l1]]


def quadrature_gradients(Dinv: np.ndarray) -> np.ndarray:
    """dN_i/dX at each quadrature point of each element, (n_elems, 3, 6, 2).

    ``Dinv`` is (n_elems, 2, 2), the inverse of Dm of the corner triangle:
    its rows are the gradients of l2 and l3 (l1 = 1 - l2 - l3)."""
    g2, g3 = Dinv[:, 0, :], Dinv[:, 1, :]
    G = np.stack([-(g2 + g3), g2, g3], axis=1)                     # (n, 3 l's, 2)
    dN = np.array([_shape_derivatives(*lq) for lq in P2_QUAD_POINTS], dtype=np.float64)
    return np.einsum("qij,ejd->eqid", dN, G)


def p2_jacobians(xe: np.ndarray, grads: np.ndarray) -> np.ndarray:
    """J = det F at each quadrature point, (n_elems, 3), from the element
    coordinates ``xe`` (n_elems, 12) and :func:`quadrature_gradients`."""
    xn = xe.reshape(-1, 6, 2)
    F = np.einsum("eia,eqib->eqab", xn, grads)
    return F[..., 0, 0] * F[..., 1, 1] - F[..., 0, 1] * F[..., 1, 0]


def element_functions(name: str, psi, args) -> tuple[ca.Function, ca.Function, ca.Function]:
    """An element energy ``psi`` of (xe, Dinv, w, mu, lam) as three named
    Functions: the energy, energy and gradient, energy, gradient and Hessian
    (the fast path asks each evaluation order for only what it needs)."""
    xe = args[0]
    g = ca.gradient(psi, xe)
    H = ca.densify(ca.hessian(psi, xe)[0])
    names = ["xe", "Dinv", "w", "mu", "lam"]
    return (ca.Function(name, args, [psi], names, ["psi"]),
            ca.Function(f"{name}_grad", args, [psi, g], names, ["psi", "grad"]),
            ca.Function(f"{name}_derivs", args, [psi, g, H], names, ["psi", "grad", "hess"]))


def _p1_kernels():
    """psi(xe, Dinv, w, mu, lam): w * Psi(F) of one linear triangle, and its
    derivatives. ``xe`` = [xa, ya, xb, yb, xc, yc], ``Dinv`` = Dm^-1
    column-major, ``w`` = thickness * rest area."""
    xe = ca.SX.sym("xe", 6)
    Dinv = ca.SX.sym("Dinv", 4)
    w = ca.SX.sym("w")
    mu = ca.SX.sym("mu")
    lam = ca.SX.sym("lam")
    d = ca.horzcat(xe[2:4] - xe[0:2], xe[4:6] - xe[0:2])
    F = d @ ca.reshape(Dinv, 2, 2)
    logJ = ca.log(ca.det(F))
    psi = w * (mu / 2 * (ca.sumsqr(F) - 2) - mu * logJ + lam / 2 * logJ**2)
    return element_functions("psi", psi, [xe, Dinv, w, mu, lam])


def _p2_kernels():
    """psi2(xe, Dinv, w, mu, lam): w * sum_q (1/3) Psi(F(l_q)) of one P2
    element, and its derivatives. Same inputs as the P1 kernel except
    ``xe`` has 12 entries (the six nodes, interleaved)."""
    xe = ca.SX.sym("xe", 12)
    Dinv = ca.SX.sym("Dinv", 4)
    w = ca.SX.sym("w")
    mu = ca.SX.sym("mu")
    lam = ca.SX.sym("lam")
    D = ca.reshape(Dinv, 2, 2)
    G = ca.vertcat(-(D[0, :] + D[1, :]), D[0, :], D[1, :])        # rows: grad l1, l2, l3
    xn = ca.reshape(xe, 2, 6)                                       # column i: node i
    psi = 0
    for lq, wq in zip(P2_QUAD_POINTS, P2_QUAD_WEIGHTS):
        dN = ca.DM(_shape_derivatives(*lq))                         # 6 x 3
        F = xn @ dN @ G
        logJ = ca.log(ca.det(F))
        psi += wq * (mu / 2 * (ca.sumsqr(F) - 2) - mu * logJ + lam / 2 * logJ**2)
    psi = w * psi
    return element_functions("psi2", psi, [xe, Dinv, w, mu, lam])


P1_PSI, P1_PSI_GRAD, P1_PSI_DERIVS = _p1_kernels()
P2_PSI, P2_PSI_GRAD, P2_PSI_DERIVS = _p2_kernels()
#: the element energy kernels by element type (the CasADi expression
#: differentiates these; the fast path evaluates them compiled)
KERNELS = {"P1": (P1_PSI, P1_PSI_GRAD, P1_PSI_DERIVS), "P2": (P2_PSI, P2_PSI_GRAD, P2_PSI_DERIVS)}


@functools.lru_cache(maxsize=None)
def fast_kernels(element: str) -> dict[str, ca.Function]:
    """An element's kernels compiled (cached on disk) once per process,
    under one set of names for either element."""
    psi, grad, derivs = KERNELS[element]
    return {"psi": compiled(psi), "psi_grad": compiled(grad), "psi_derivs": compiled(derivs)}
