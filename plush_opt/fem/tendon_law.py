"""The tendon's two energy kernels, defined once: the length of a segment
and the C2 unilateral spring law U(G) of the paper (zero when slack, cubic
in the smoothing zone |G| < eps, quadratic beyond), with their derivatives.
The model maps them over every segment and tendon; :data:`KERNELS` holds
their compiled forms (plush_opt.fem.kernel_set)."""

from __future__ import annotations

import casadi as ca

from .kernel_set import KernelSet


def segment_kernels():
    """seg(xs): length of the segment [xa, ya, xb, yb], and its derivatives."""
    xs = ca.SX.sym("xs", 4)
    length = ca.norm_2(xs[2:4] - xs[0:2])
    g = ca.gradient(length, xs)
    H = ca.densify(ca.hessian(length, xs)[0])
    length_fn = ca.Function("seg", [xs], [length], ["xs"], ["length"])
    derivs = ca.Function("seg_derivs", [xs], [length, g, H], ["xs"], ["length", "grad", "hess"])
    return length_fn, derivs


def tendon_kernels():
    """U(G, K, eps): C2 unilateral spring energy, tension U' and U''."""
    G = ca.SX.sym("G")
    K = ca.SX.sym("K")
    eps = ca.SX.sym("eps")
    U = ca.if_else(G <= -eps, 0,
                   ca.if_else(G < eps, K * (G + eps) ** 3 / (6 * eps),
                              K * G**2 + K * eps**2 / 3))
    dU = ca.if_else(G <= -eps, 0,
                    ca.if_else(G < eps, K * (G + eps) ** 2 / (2 * eps), 2 * K * G))
    d2U = ca.if_else(G <= -eps, 0,
                     ca.if_else(G < eps, K * (G + eps) / eps, 2 * K))
    energy = ca.Function("U", [G, K, eps], [U], ["G", "K", "eps"], ["U"])
    derivs = ca.Function("U_derivs", [G, K, eps], [U, dU, d2U],
                         ["G", "K", "eps"], ["U", "tension", "dtension"])
    return energy, derivs


SEG, SEG_DERIVS = segment_kernels()
U, U_DERIVS = tendon_kernels()
#: the kernels the fast path evaluates, compiled on first use
KERNELS = KernelSet(seg_derivs=SEG_DERIVS, U_derivs=U_DERIVS)
