"""Friction at via points: a tendon split into segments with their own rest
lengths (docs/model.md, "Friction at via points").

A tendon t with friction mu_t > 0 and at least one interior via point is no
longer one spring: segment j (between via points j and j+1, stopper end
first) has rest length r_j, sum_j r_j = a_t - c_w, share
phi_j = r_j / (a_t - c_w) and energy phi_j U(G_j / phi_j) with
G_j = |P_{j+1} - P_j| - r_j; its tension is T_j = U'(G_j / phi_j). With the
rest lengths held fixed this is an ordinary energy in the pose, minimised by
the equilibrium Newton (:meth:`FrictionModel.fixed`); which rest lengths
hold is decided by the path-following solver (plush_opt/solve/friction_path.py).

Tendons without friction stay in the ordinary :class:`~plush_opt.fem.model.Model`
(exactly today's terms): the friction model is a model of the scene without
its friction tendons, plus their segment energies. Via point positions are
``P_t = W_t x`` with ``W_t`` from :func:`via_weights` (the one place that
says which nodes carry a via point).
"""

from __future__ import annotations

from dataclasses import replace

import casadi as ca
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from .hessian_layout import pair_blocks, segment_pairs
from .kernel_set import KernelSet
from ..base.linalg import Factorizer, LowRankHessian
from .model import Evaluation, Model, Mapped
from .tendon_law import U_DERIVS


def friction_tendons(scene, include_frictionless: bool = False) -> tuple[int, ...]:
    """Indices of the tendons the friction model splits into segments: friction
    > 0 (or any, with ``include_frictionless``) and an interior via point."""
    return tuple(i for i, t in enumerate(scene.tendons)
                 if len(t.path) >= 3 and (t.friction > 0 or include_frictionless))


def via_weights(model: Model, t: int) -> sp.csr_matrix:
    """W_t, (2 n_via, n_dofs): flat via point positions P_t = W_t x of tendon t,
    stopper end first, from the model's via point weights (n_via, n_nodes):
    a weighted average of nodes with a finite attachment, else the node."""
    return sp.kron(sp.csr_matrix(model.via_weights[t]), sp.identity(2), format="csr")


# --------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------

def segment_kernel() -> ca.Function:
    """fseg(v, K, eps), v = [xs (4 end coordinates), r, R]: one segment's
    energy phi U(G/phi), phi = r/R, and the derivatives the solvers need."""
    v, K, eps = ca.SX.sym("v", 6), ca.SX.sym("K"), ca.SX.sym("eps")
    xs, r, R = v[0:4], v[4], v[5]
    length = ca.norm_2(xs[2:4] - xs[0:2])
    phi = r / R
    z = (length - r) / phi
    U, T, _ = U_DERIVS(z, K, eps)
    e = phi * U
    ge = ca.gradient(e, xs)
    He = ca.densify(ca.jacobian(ge, xs))
    return ca.Function(
        "fseg", [v, K, eps],
        [e, ge, He, ca.gradient(e, r), ca.jacobian(ge, r), T, ca.gradient(T, xs), ca.gradient(T, r)],
        ["v", "K", "eps"],
        ["e", "grad", "hess", "de_dr", "dgrad_dr", "tension", "dtension_dx", "dtension_dr"])


def _compiled_kernels() -> tuple[ca.Function, ca.Function]:
    """Both kernels compiled (cached on disk), once per process: :data:`KERNELS` keeps them."""
    return KERNELS["fseg"], KERNELS["wrap"]


def wrap_kernel() -> ca.Function:
    """wrap(p): the unsigned angle in [0, pi] between segments P0->P1 and
    P1->P2 (p = [P0, P1, P2], 6 coordinates), and its gradient."""
    p = ca.SX.sym("p", 6)
    u, v = p[2:4] - p[0:2], p[4:6] - p[2:4]
    theta = ca.atan2(ca.fabs(u[0] * v[1] - u[1] * v[0]), ca.dot(u, v))
    return ca.Function("wrap", [p], [theta, ca.gradient(theta, p)], ["p"], ["theta", "grad"])


#: the friction law's kernels, compiled on first use (plush_opt.fem.kernel_set)
KERNELS = KernelSet(fseg=segment_kernel(), wrap=wrap_kernel())


# --------------------------------------------------------------------------
# The model
# --------------------------------------------------------------------------

class FrictionModel:
    """The scene's energy with its friction tendons split into segments.

    Attributes
    ----------
    model : the full :class:`Model` (every tendon one spring).
    base : the model of the scene without the friction tendons.
    tendons : scene indices of the friction tendons.
    n_segments : segments of the friction tendons, tendon by tendon.
    seg_tendon : (n_segments,) scene index of each segment's tendon.
    seg_first, seg_last : (n_friction,) first segment and winch-end segment.
    n_interior : interior via points; ``lo``, ``hi`` their stopper-side and
        winch-side segments; ``mu`` their tendon's friction; ``via_index``
        their position on the tendon's path (0 = stopper end).
    """

    def __init__(self, model: Model, include_frictionless: bool = False):
        self.model = model
        scene, mesh = model.scene, model.mesh
        self.tendons = friction_tendons(scene, include_frictionless)
        keep = [i for i in range(model.n_tendons) if i not in self.tendons]
        self.base = Model(replace(scene, tendons=tuple(scene.tendons[i] for i in keep)),
                          replace(mesh, tendon_nodes=tuple(mesh.tendon_nodes[i] for i in keep)))
        self.n_dofs, self.n_winches, self.X = model.n_dofs, model.n_winches, model.X
        self.K, self.eps = model.tendon_stiffness, model.tendon_smoothing
        # the Hessian's form follows the full model's: with large
        # attachment discs each segment's coupling of its two discs is kept
        # out as low rank (a segment here has no rank-one tendon term)
        self.split = model.split_segments
        self._build_segments()
        self._build_pattern()
        fseg, wrap = _compiled_kernels()
        self._fseg = Mapped(fseg, self.n_segments, {1: np.full(self.n_segments, self.K),
                                                     2: np.full(self.n_segments, self.eps)})
        self._wrap = Mapped(wrap, self.n_interior, {})
        self.factorizer = Factorizer()

    # the attributes the equilibrium Newton reads
    energy_roundoff_scale = property(lambda self: self.base.energy_roundoff_scale)
    has_gravity = property(lambda self: self.base.has_gravity)
    f_gravity = property(lambda self: self.base.f_gravity)
    rest_area = property(lambda self: self.base.rest_area)

    def _build_segments(self):
        model = self.model
        blocks, seg_p, seg_t, lo, hi, wrap_p, mu, via = [], [], [], [], [], [], [], []
        first, last, n_p, n_s = [], [], 0, 0
        for t in self.tendons:
            W = via_weights(model, t)
            n_via = W.shape[0] // 2
            blocks.append(W)
            p = n_p + 2 * np.arange(n_via)
            seg_p.append(np.stack([p[:-1], p[:-1] + 1, p[1:], p[1:] + 1], axis=1))
            seg_t.append(np.full(n_via - 1, t))
            first.append(n_s)
            last.append(n_s + n_via - 2)
            j = np.arange(1, n_via - 1)
            lo.append(n_s + j - 1)
            hi.append(n_s + j)
            wrap_p.append(np.stack([p[j - 1], p[j - 1] + 1, p[j], p[j] + 1, p[j + 1], p[j + 1] + 1], 1))
            mu.append(np.full(len(j), model.scene.tendons[t].friction))
            via.append(j)
            n_p += 2 * n_via
            n_s += n_via - 1
        cat = lambda a, shape: np.concatenate(a) if a else np.zeros(shape, np.int64)  # noqa: E731
        self.W = sp.vstack(blocks, format="csr") if blocks else sp.csr_matrix((0, self.n_dofs))
        self._WT = self.W.T.tocsr()      # W^T once: every gradient and Jacobian row goes through it
        self.n_segments = n_s
        self.seg_p = cat(seg_p, (0, 4))
        self.seg_tendon = cat(seg_t, 0)
        self.seg_first = np.asarray(first, np.int64)
        self.seg_last = np.asarray(last, np.int64)
        self.lo, self.hi = cat(lo, 0), cat(hi, 0)
        self.via_index = cat(via, 0)          # position of each interior point on its path
        self.wrap_p = cat(wrap_p, (0, 6))
        self.mu = np.concatenate(mu) if mu else np.zeros(0)
        self.n_interior = len(self.lo)
        # D: rest lengths moved by a slip delta_i (material through interior
        # via point i toward the winch): r_lo -= delta, r_hi += delta
        i = np.arange(self.n_interior)
        self.D = sp.csr_matrix((np.r_[-np.ones(len(i)), np.ones(len(i))],
                                (np.r_[self.lo, self.hi], np.r_[i, i])),
                               shape=(n_s, self.n_interior))
        self.assembly_length = model.assembly_length[self.seg_tendon] if n_s else np.zeros(0)
        self.seg_winch = model.tendon_winch[self.seg_tendon] if n_s else np.zeros(0, np.int64)

    def _build_pattern(self):
        """One CSC pattern for the base Hessian plus the segment blocks
        W^T H_P W, and where each contribution lands in its data array.
        In the low-rank form a segment's [[K, -K], [-K, K]] is 2 diag(K, K)
        (here) minus [I; I] K [I, I] (rows ``_pairs``, low rank)."""
        n = self.n_dofs
        Hb = _sparse_part(self.base.evaluate(self.X, np.zeros(self.n_winches), order=2).hessian_form)
        bcols = np.repeat(np.arange(n), np.diff(Hb.indptr))
        keys = [bcols * n + Hb.indices]
        rows, cols, entry, weight = [], [], [], []
        W = self.W
        blocks = ([(a, b) for a in (0, 1) for b in (0, 1)] + [(a, b) for a in (2, 3) for b in (2, 3)]
                  if self.split else [(a, b) for a in range(4) for b in range(4)])
        if self.split:
            self._pairs = segment_pairs(self.seg_p, W)
        for s in range(self.n_segments):
            for a, b in blocks:
                ra, rb = W.getrow(self.seg_p[s, a]), W.getrow(self.seg_p[s, b])
                rows.append(np.repeat(ra.indices, len(rb.indices)))
                cols.append(np.tile(rb.indices, len(ra.indices)))
                weight.append(np.outer(ra.data, rb.data).ravel())
                entry.append(np.full(len(ra.indices) * len(rb.indices), 16 * s + 4 * a + b))
        if rows:
            rows, cols = np.concatenate(rows), np.concatenate(cols)
            keys.append(cols * n + rows)
        unique, slot = np.unique(np.concatenate(keys), return_inverse=True)
        ucols, urows = np.divmod(unique, n)
        self._indptr = np.r_[0, np.cumsum(np.bincount(ucols, minlength=n))].astype(np.int32)
        self._indices = urows.astype(np.int32)
        self._nnz = len(unique)
        self._slot_base = slot[:Hb.nnz]
        self._expand = sp.csr_matrix(
            (np.concatenate(weight) if weight else [], (slot[Hb.nnz:], np.concatenate(entry) if entry else [])),
            shape=(self._nnz, 16 * self.n_segments))

    # -- rest lengths -------------------------------------------------------

    def rest_total(self, c) -> np.ndarray:
        """(n_segments,) a_t - c_w of each segment's tendon."""
        c = np.asarray(c, dtype=np.float64).reshape(-1)
        return self.assembly_length - c[self.seg_winch]

    def segment_lengths(self, x) -> np.ndarray:
        """(n_segments,) |P_{j+1} - P_j| at flat pose x."""
        P = self.W @ np.asarray(x, dtype=np.float64).reshape(-1)
        d = P[self.seg_p[:, 2:]] - P[self.seg_p[:, :2]]
        return np.hypot(d[:, 0], d[:, 1])

    def start_rest_lengths(self) -> np.ndarray:
        """Rest lengths of the start state: each tendon's a_t shared in
        proportion to its segments' lengths in X (all tensions equal)."""
        L = self.segment_lengths(self.X)
        total = np.bincount(self.seg_tendon, weights=L, minlength=self.model.n_tendons)[self.seg_tendon]
        return L * self.assembly_length / total

    # -- evaluation ---------------------------------------------------------

    def segments(self, x, r, c) -> dict[str, np.ndarray]:
        """Per segment at pose x, rest lengths r, contractions c: ``energy``,
        ``grad``/``hess`` in its 4 via point coordinates, ``de_dr``,
        ``dgrad_dr``, ``tension``, ``dtension_dx`` (4), ``dtension_dr``."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        n = self.n_segments
        P = self.W @ x
        v = np.hstack([P[self.seg_p], np.reshape(r, (n, 1)), self.rest_total(c).reshape(n, 1)])
        e, g, H, er, ger, T, gT, Tr = self._fseg(v, 8)
        return {"energy": e, "grad": g.reshape(n, 4), "hess": H.reshape(n, 4, 4),
                "de_dr": er, "dgrad_dr": ger.reshape(n, 4), "tension": T,
                "dtension_dx": gT.reshape(n, 4), "dtension_dr": Tr}

    def wraps(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Wrap angles (n_interior,) in [0, pi] at pose x, and their
        gradients in the three via points' coordinates (n_interior, 6)."""
        if not self.n_interior:
            return np.zeros(0), np.zeros((0, 6))
        P = self.W @ np.asarray(x, dtype=np.float64).reshape(-1)
        theta, g = self._wrap(P[self.wrap_p], 2)
        return theta, g.reshape(-1, 6)

    def to_x(self, values: np.ndarray, pdofs: np.ndarray) -> np.ndarray:
        """Rows of per-item derivatives in via point coordinates (k, m) at
        P dofs ``pdofs`` (k, m) -> dense (k, n_dofs) in pose coordinates."""
        k, m = values.shape
        n_p = self.W.shape[0]
        flat = (np.repeat(np.arange(k), m) * n_p + pdofs.ravel()).astype(np.int64)
        Gp = np.bincount(flat, weights=values.ravel(), minlength=k * n_p).reshape(k, n_p)
        return np.asarray((self._WT @ Gp.T).T)

    def evaluate(self, x, c, r, order: int = 2, seg: dict | None = None) -> Evaluation:
        """E(x; c, r) (order 0), grad_x (1), and the Hessian (2); ``seg``:
        :meth:`segments` at the same point, if the caller has it."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        ev = self.base.evaluate(x, c, order)
        if not ev.admissible:
            return ev
        seg = self.segments(x, r, c) if seg is None else seg
        energy = ev.energy + float(seg["energy"].sum())
        if order == 0:
            return Evaluation(energy, None, None, ev.force_scale, True)
        gP = np.bincount(self.seg_p.ravel(), weights=seg["grad"].ravel(), minlength=self.W.shape[0])
        f = self._WT @ gP
        g = ev.gradient + f
        scale = max(ev.force_scale, float(np.linalg.norm(f)))
        if order == 1:
            return Evaluation(energy, g, None, scale, True)
        # the base model's Hessian always has the pattern seen at build time
        base = ev.hessian_form
        data = np.bincount(self._slot_base, weights=_sparse_part(base).data, minlength=self._nnz)
        hess = seg["hess"]
        data += self._expand @ (2 * hess if self.split else hess).ravel()
        H = sp.csc_matrix((data, self._indices, self._indptr), shape=(self.n_dofs, self.n_dofs))
        if self.split:
            Q, M = self._pairs, pair_blocks(hess[:, :2, :2])
            if isinstance(base, LowRankHessian):
                Q, M = sp.vstack([base.Q, Q], format="csr"), sla.block_diag(base.M, M)
            H = LowRankHessian(H, Q, M)
        elif isinstance(base, LowRankHessian):
            H = LowRankHessian(H, base.Q, base.M)
        return Evaluation(energy, g, H, scale, True)

    def mixed_r(self, x, r, c, seg: dict | None = None) -> np.ndarray:
        """d2E/dx dr, dense (n_dofs, n_segments)."""
        seg = self.segments(x, r, c) if seg is None else seg
        return self.to_x(seg["dgrad_dr"], self.seg_p).T

    def fixed(self, r) -> "FixedRest":
        """This model with the rest lengths held at r: what the equilibrium
        Newton minimises."""
        return FixedRest(self, np.asarray(r, dtype=np.float64).copy())


def _sparse_part(H) -> sp.csc_matrix:
    return H.body if isinstance(H, LowRankHessian) else H


class FixedRest:
    """A :class:`FrictionModel` at fixed segment rest lengths: the interface
    :func:`~plush_opt.solve.equilibrium.solve_equilibrium` expects of a model."""

    def __init__(self, fm: FrictionModel, r: np.ndarray):
        self.fm, self.r = fm, r
        self.n_dofs, self.n_winches, self.X = fm.n_dofs, fm.n_winches, fm.X
        self.factorizer = fm.factorizer
        self.energy_roundoff_scale = fm.energy_roundoff_scale
        self.has_gravity, self.f_gravity, self.rest_area = fm.has_gravity, fm.f_gravity, fm.rest_area

    def evaluate(self, x, c, order: int = 2) -> Evaluation:
        return self.fm.evaluate(x, c, self.r, order)
