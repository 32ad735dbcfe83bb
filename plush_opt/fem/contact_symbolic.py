"""The obstacles' contact barrier as a CasADi expression, for the IPOPT
backends (the equilibrium cross-check and the full bilevel formulation;
the floor's is in :meth:`~plush_opt.fem.contact.ContactTerm.expression`).

Newton evaluates the barrier over the pairs a broad phase finds at each
pose (:mod:`plush_opt.fem.contact`); an expression is built once, so it
holds every pair that can ever touch: each obstacle edge against every
boundary node and each obstacle vertex against every boundary segment (a
few thousand pairs for a gripper around an object). A body node inside an
obstacle, or an obstacle vertex inside the body (found by winding
numbers), makes the expression NaN, so
IPOPT's line search backs off from a step through an obstacle as Newton's
collision detection stops it. Self-contact pairs are every pair of
boundary nodes and segments, quadratic in the boundary: it stays with
Newton. The expression is the same energy as the numeric one, pair type
by pair type (:func:`~plush_opt.fem.contact_geometry.pair_type`'s rule,
the same squared distances and the same IPC barrier), so IPOPT and Newton
balance the same forces.
"""

from __future__ import annotations

import casadi as ca
import numpy as np


def barrier(s, dhat2: float):
    """The IPC barrier of :func:`~plush_opt.fem.contact_geometry.barrier`
    on a symbolic squared distance ``s``: -(s - dhat2)^2 ln(s / dhat2)
    below dhat2, 0 above (a pose with s <= 0 evaluates to inf or NaN,
    which IPOPT's line search backs off from)."""
    u = s - dhat2
    return ca.if_else(s < dhat2, -u * u * ca.log(s / dhat2), 0)


def point_segment_sq(px, py, ax, ay, bx, by):
    """Squared distance from p to segment [a, b], elementwise over
    symbolic or numeric rows (each argument a row of the same length or a
    scalar): to the end a where the projection falls before it, to b
    past it, else to the line, as
    :func:`~plush_opt.fem.contact_geometry.point_segment_sq` decides."""
    ex, ey = bx - ax, by - ay
    qx, qy = px - ax, py - ay
    length2 = ex * ex + ey * ey
    along = qx * ex + qy * ey
    cross = ex * qy - ey * qx
    to_a = qx * qx + qy * qy
    to_b = (px - bx) ** 2 + (py - by) ** 2
    # the line's form is evaluated everywhere; a zero-length segment is its end a
    line = cross * cross / ca.fmax(length2, np.finfo(float).tiny)
    return ca.if_else(along <= 0, to_a, ca.if_else(along >= length2, to_b, line))


def _pair_kernel(dhat2: float) -> ca.Function:
    """The barrier of one point-segment pair, (p, a, b, inside) -> b(s),
    compiled from scalar operations (mapped over every pair: one small
    graph whose derivatives CasADi takes once). ``inside`` (0 or 1) flips
    the squared distance's sign: a point inside the other outline (a body
    node in an obstacle, an obstacle vertex in the body) evaluates to NaN,
    value and derivatives, as Newton's admissibility check refuses it."""
    p, a, b = ca.SX.sym("p", 2), ca.SX.sym("a", 2), ca.SX.sym("b", 2)
    inside = ca.SX.sym("inside")
    s = point_segment_sq(p[0], p[1], a[0], a[1], b[0], b[1])
    return ca.Function("contact_pair", [p, a, b, inside], [barrier(ca.if_else(inside, -s, s), dhat2)])


def _angle_kernel() -> ca.Function:
    """The angle segment [a, b] subtends at p, signed, (p, a, b) -> angle:
    summed over a closed outline it is 2 pi times the outline's winding
    number about p (0 outside, +-2 pi inside), constant between crossings."""
    p, a, b = ca.SX.sym("p", 2), ca.SX.sym("a", 2), ca.SX.sym("b", 2)
    u, v = a - p, b - p
    return ca.Function("contact_angle", [p, a, b], [ca.atan2(u[0] * v[1] - u[1] * v[0], ca.dot(u, v))])


def _winding(point, start, end, groups: np.ndarray, n_points: int):
    """(g, n_points): 1 where a point is inside a closed outline, by its
    winding number about it.

    Pairs are point-major (pair ``p * m + j``: point p, segment j of m);
    ``groups`` (g, m) 0/1 says which segments make up each outline. The
    barrier's squared distances are unsigned, so without this a step that
    carries a body node into an obstacle, or an obstacle corner into the
    body, lands on a finite energy (IPOPT has no collision detection)."""
    m = groups.shape[1]
    angles = _angle_kernel().map(n_points * m)(point, start, end)
    return ca.fabs(ca.DM(groups.astype(float)) @ ca.reshape(angles, m, n_points)) > np.pi


def obstacle_energy(P, local: np.ndarray, node_weight: np.ndarray, edges, vertex_weights,
                    stiffness: float, dhat2: float):
    """kappa times the weighted barrier of every obstacle pair.

    ``P`` (2, b) the boundary nodes' symbolic positions; ``local`` (m, 2)
    each boundary segment's ends as indices into them; ``node_weight``
    (b,); ``edges`` a list of (A, B), each (k, 2), the obstacles' edges;
    ``vertex_weights`` a list of (k,) arrays, each obstacle vertex's weight
    (half its two edges)."""
    n_nodes, n_segments = P.shape[1], len(local)
    oa = np.concatenate([a for a, _ in edges])
    ob = np.concatenate([b for _, b in edges])
    ow = np.concatenate(list(vertex_weights))
    k = len(oa)
    # body node i against obstacle edge e, for every (i, e)
    node = np.repeat(np.arange(n_nodes), k)
    edge = np.tile(np.arange(k), n_nodes)
    # obstacle vertex v against body segment j, for every (v, j)
    vertex = np.repeat(np.arange(k), n_segments)
    segment = np.tile(np.arange(n_segments), k)
    point = ca.horzcat(P[:, node.tolist()], ca.DM(oa[vertex].T))
    start = ca.horzcat(ca.DM(oa[edge].T), P[:, local[segment, 0].tolist()])
    end = ca.horzcat(ca.DM(ob[edge].T), P[:, local[segment, 1].tolist()])
    weight = np.concatenate([node_weight[node], ow[vertex]])
    # a body node inside an obstacle flips its pairs with that obstacle's edges
    n_node_pairs = n_nodes * k
    owner = np.equal.outer(np.arange(len(edges)), np.repeat(np.arange(len(edges)), [len(a) for a, _ in edges]))
    node_inside = _winding(point[:, :n_node_pairs], start[:, :n_node_pairs], end[:, :n_node_pairs],
                           owner, n_nodes)
    inside = ca.horzcat(ca.reshape(ca.DM(owner.T.astype(float)) @ node_inside, 1, n_node_pairs),
                        ca.DM.zeros(1, len(weight) - n_node_pairs))
    pairs = _pair_kernel(dhat2).map(len(weight))
    energy = stiffness * ca.dot(ca.DM(weight), pairs(point, start, end, inside).T)
    # an obstacle vertex inside the body (whose segments have the body on their
    # left: winding 1) depends on every boundary node: flagging its pairs would
    # couple them all in the Hessian, so one term per vertex on one coordinate
    # says it instead: 0 outside, NaN inside, value and that coordinate's force
    # (no NaN constant: a zero adjoint times NaN would poison every gradient)
    vertex_inside = _winding(point[:, n_node_pairs:], start[:, n_node_pairs:], end[:, n_node_pairs:],
                             np.ones((1, n_segments)), k)
    return energy + P[0, 0] * ca.sum2(ca.log(1 - 2 * vertex_inside))
