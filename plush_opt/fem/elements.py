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
what differs between the two element types, as one object per type
(:data:`P1`, :data:`P2`, both :class:`Element`): the mesh carries it
(``Mesh.element``) and the model assembles either the same way through it.
No other module compares element names; a file's ``mesh.element`` string is
turned into the object by :func:`named`.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .kernel_set import KernelSet

# The 3-point rule on a triangle (degree 2), barycentric points and weights.
P2_QUAD_POINTS = np.array([[2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])
P2_QUAD_WEIGHTS = np.full(3, 1 / 3)

# The three edges of a P2 triangle, in the order of its midside nodes.
P2_EDGES = ((0, 1), (1, 2), (2, 0))


def shape_values(beta: np.ndarray) -> np.ndarray:
    """The six P2 shape functions at barycentric points, (k, 3) -> (k, 6)."""
    l1, l2, l3 = np.asarray(beta, dtype=np.float64).reshape(-1, 3).T
    return np.stack([l1 * (2 * l1 - 1), l2 * (2 * l2 - 1), l3 * (2 * l3 - 1),
                     4 * l1 * l2, 4 * l2 * l3, 4 * l3 * l1], axis=1)


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


def add_midside_nodes(X: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Turn a P1 mesh into a P2 mesh: one new node at the midpoint of each
    edge, numbered after every corner node (corner numbering is kept, so
    pins, via points and points stay the nodes they were).

    Returns the new ``X`` (n_nodes + n_edges, 2) and the 6-node triangles
    ``[a, b, c, ab, bc, ca]`` (n_elems, 6), in edge order of first use."""
    tris = np.asarray(tris, dtype=np.int64)
    n_elems = len(tris)
    edges = np.stack([tris[:, list(e)] for e in P2_EDGES], axis=1).reshape(-1, 2)
    key = np.sort(edges, axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    # number the edges by first use, so the numbering follows the triangles
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    mid_of = rank[inverse].reshape(n_elems, 3)
    uniq = key[first[order]]
    mids = 0.5 * (X[uniq[:, 0]] + X[uniq[:, 1]])
    return np.vstack([X, mids]), np.hstack([tris, len(X) + mid_of])


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


class Element:
    """One element type: what the mesh, the model and the targets need to
    know about it. One instance per type (:data:`P1`, :data:`P2`); compare
    elements with ``is`` or ``==`` (identity), never by name.

    Attributes
    ----------
    name : "P1" or "P2", the name used in problem and result files
        (``str(element)`` is the name).
    nodes : nodes per triangle (3 or 6).
    degree : polynomial degree of the shape functions (1 or 2).
    kernels : :class:`~plush_opt.fem.kernel_set.KernelSet` of the element
        energy ``psi(xe, Dinv, w, mu, lam)`` = w * Psi(F) integrated over
        the element, under the names "psi" (energy), "psi_grad" (energy,
        gradient), "psi_derivs" (energy, gradient, Hessian); ``xe`` is the
        element's 2 * nodes coordinates, interleaved, ``Dinv`` = Dm^-1 of
        the corner triangle column-major, ``w`` = thickness * rest area.
    """

    name: str = ""
    nodes: int = 0
    degree: int = 0

    def __init__(self, functions: tuple[ca.Function, ca.Function, ca.Function]):
        psi, grad, derivs = functions
        self.kernels = KernelSet(psi=psi, psi_grad=grad, psi_derivs=derivs)

    def __str__(self) -> str:
        return self.name

    def __repr__(self) -> str:
        return f"<element {self.name}>"

    def __reduce__(self):
        return named, (self.name,)        # unpickled: the same instance

    def interpolation_weights(self, beta: np.ndarray) -> np.ndarray:
        """Weights of the element's nodes at barycentric points (of its
        corner triangle), (k, 3) -> (k, nodes)."""
        raise NotImplementedError

    def nodal_shares(self, values: np.ndarray) -> np.ndarray:
        """A quantity of each element (n_elems,), such as its mass, shared
        among its nodes by the exact integrals of the shape functions,
        (n_elems, nodes)."""
        raise NotImplementedError

    def complete(self, X: np.ndarray, tris: np.ndarray):
        """The element's nodes on a triangulation: ``tris`` (n_elems, 3)
        corner triangles, or (n_elems, nodes) element rows of an explicit
        mesh. Returns ``(X, triangles, elements)``: the nodes (added ones
        numbered after the given ones), the corner triangles, and the
        element rows (None when they are the corner triangles)."""
        raise NotImplementedError

    def jacobian_data(self, Dinv: np.ndarray, rest_area: np.ndarray) -> np.ndarray:
        """What :meth:`jacobians` needs of the rest geometry, from Dm^-1
        (n_elems, 2, 2) and the rest areas (n_elems,) of the corner triangles."""
        raise NotImplementedError

    def jacobians(self, xe: np.ndarray, data: np.ndarray) -> np.ndarray:
        """J = det F of every element at the element coordinates ``xe``
        (n_elems, 2 * nodes); the smallest over the element where F varies."""
        raise NotImplementedError

    def jacobian_expression(self, x: ca.MX, elem_dofs: np.ndarray, data: np.ndarray) -> ca.MX:
        """J = det F as a CasADi expression of the flat pose ``x``: one
        entry per element (P1) or per quadrature point of every element (P2)."""
        raise NotImplementedError


class ElementP1(Element):
    """The linear 3-node triangle: F is constant on it."""

    name, nodes, degree = "P1", 3, 1

    def interpolation_weights(self, beta):
        return np.asarray(beta, dtype=np.float64).reshape(-1, 3)

    def nodal_shares(self, values):
        return np.repeat(values / 3, 3).reshape(-1, 3)

    def complete(self, X, tris):
        return X, tris, None

    def jacobian_data(self, Dinv, rest_area):
        return rest_area

    def jacobians(self, xe, data):
        x = xe.T              # (one coordinate per row: no (n, 2) temporaries)
        return ((x[2] - x[0]) * (x[5] - x[1]) - (x[3] - x[1]) * (x[4] - x[0])) / (2 * data)

    def jacobian_expression(self, x, elem_dofs, data):
        xe = [x[elem_dofs[:, i].tolist()] for i in range(6)]
        det = (xe[2] - xe[0]) * (xe[5] - xe[1]) - (xe[3] - xe[1]) * (xe[4] - xe[0])
        return det / ca.DM(2 * data)


class ElementP2(Element):
    """The quadratic 6-node triangle ``[a, b, c, ab, bc, ca]``, straight-sided:
    F is linear on it, J is checked at the quadrature points."""

    name, nodes, degree = "P2", 6, 2
    # the integral of each shape function over the element, a share of its
    # area: the corner functions integrate to zero
    SHARES = np.array([0, 0, 0, 1 / 3, 1 / 3, 1 / 3])

    def interpolation_weights(self, beta):
        return shape_values(beta)

    def nodal_shares(self, values):
        return np.outer(values, self.SHARES)

    def complete(self, X, tris):
        if tris.shape[1] == 3:
            X, elements = add_midside_nodes(X, tris)
            return X, tris, elements
        return X, tris[:, :3], tris

    def jacobian_data(self, Dinv, rest_area):
        return quadrature_gradients(Dinv)

    def jacobians(self, xe, data):
        return p2_jacobians(xe, data).min(axis=1)

    def jacobian_expression(self, x, elem_dofs, data):
        xe = [x[elem_dofs[:, i].tolist()] for i in range(12)]
        dets = []
        for q in range(data.shape[1]):
            F = [[sum(xe[2 * i + a] * ca.DM(data[:, q, i, b]) for i in range(6)) for b in range(2)]
                 for a in range(2)]
            dets.append(F[0][0] * F[1][1] - F[0][1] * F[1][0])
        return ca.vertcat(*dets)


#: the element types, one instance each (each holds its compiled kernels)
P1 = ElementP1((P1_PSI, P1_PSI_GRAD, P1_PSI_DERIVS))
P2 = ElementP2((P2_PSI, P2_PSI_GRAD, P2_PSI_DERIVS))
ELEMENTS = (P1, P2)


def named(name: str) -> Element:
    """The element type a file names ("P1" or "P2")."""
    for element in ELEMENTS:
        if element.name == name:
            return element
    raise ValueError(f"element {name!r}: expected one of {', '.join(e.name for e in ELEMENTS)}")


def with_nodes(nodes: int) -> Element:
    """The element type with ``nodes`` nodes per triangle (3 or 6)."""
    for element in ELEMENTS:
        if element.nodes == nodes:
            return element
    raise ValueError(f"no element type has {nodes} nodes per triangle")
