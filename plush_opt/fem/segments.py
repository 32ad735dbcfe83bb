"""The segmented tendons of via-point friction as one energy term, whose
history is the segments' rest lengths (docs/terms.md, "The segment term";
docs/model.md, "Friction at via points").

A tendon t split at its interior via points is no longer one spring:
segment j (between via points j and j+1, stopper end first) has rest length
r_j, sum_j r_j = a_t - c_w, share phi_j = r_j / (a_t - c_w) and energy
phi_j U(G_j / phi_j) with G_j = |P_{j+1} - P_j| - r_j; its tension is
T_j = U'(G_j / phi_j). With the rest lengths held this is an ordinary
energy term in the pose (:class:`SegmentTerm`); which rest lengths hold is
decided by the path-following solver (plush_opt/solve/friction_path.py),
which commits them to the term once a step is accepted.

Via point positions are ``P = W x`` (flat, 2 per via point, tendon by
tendon) with ``W`` from :func:`via_weights` (the one place that says which
nodes carry a via point).
"""

from __future__ import annotations

import copy

import casadi as ca
import numpy as np
import scipy.sparse as sp

from .kernel_set import KernelSet
from .tendon_law import U_DERIVS
from .terms import Mapped, Term, TermEvaluation


def via_weights(model, t: int) -> sp.csr_matrix:
    """W_t, (2 n_via, n_dofs): flat via point positions P_t = W_t x of tendon t,
    stopper end first, from the model's via point weights (n_via, n_nodes):
    a weighted average of nodes with a finite attachment, else the node."""
    return sp.kron(sp.csr_matrix(model.via_weights[t]), sp.identity(2), format="csr")


# --------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------

def _segment_energy(v: ca.SX, K: ca.SX, eps: ca.SX):
    """(e, T, xs, r, R) of one segment, v = [xs (4 end coordinates), r, R]:
    its energy phi U(G/phi) (phi = r/R) and tension U'(G/phi)."""
    xs, r, R = v[0:4], v[4], v[5]
    length = ca.norm_2(xs[2:4] - xs[0:2])
    phi = r / R
    z = (length - r) / phi
    U, T, _ = U_DERIVS(z, K, eps)
    return phi * U, T, xs, r, R


def segment_kernel() -> ca.Function:
    """fseg(v, K, eps), v = [xs (4 end coordinates), r, R]: one segment's
    energy phi U(G/phi), phi = r/R, and the derivatives the solvers need."""
    v, K, eps = ca.SX.sym("v", 6), ca.SX.sym("K"), ca.SX.sym("eps")
    e, T, xs, r, _ = _segment_energy(v, K, eps)
    ge = ca.gradient(e, xs)
    He = ca.densify(ca.jacobian(ge, xs))
    return ca.Function(
        "fseg", [v, K, eps],
        [e, ge, He, ca.gradient(e, r), ca.jacobian(ge, r), T, ca.gradient(T, xs), ca.gradient(T, r)],
        ["v", "K", "eps"],
        ["e", "grad", "hess", "de_dr", "dgrad_dr", "tension", "dtension_dx", "dtension_dr"])


def segment_dR_kernel() -> ca.Function:
    """fseg_dR(v, K, eps): one segment's energy and d(grad_xs e)/dR (4),
    R = a_t - c_w its tendon's total rest length (d2E/dx dc is minus it)."""
    v, K, eps = ca.SX.sym("v", 6), ca.SX.sym("K"), ca.SX.sym("eps")
    e, _, xs, _, R = _segment_energy(v, K, eps)
    return ca.Function("fseg_dR", [v, K, eps], [e, ca.jacobian(ca.gradient(e, xs), R)],
                       ["v", "K", "eps"], ["e", "dgrad_dR"])


def segment_energy_kernel() -> ca.Function:
    """fseg_energy(v, K, eps): one segment's energy alone (for expressions)."""
    v, K, eps = ca.SX.sym("v", 6), ca.SX.sym("K"), ca.SX.sym("eps")
    return ca.Function("fseg_energy", [v, K, eps], [_segment_energy(v, K, eps)[0]], ["v", "K", "eps"], ["e"])


def wrap_kernel() -> ca.Function:
    """wrap(p): the unsigned angle in [0, pi] between segments P0->P1 and
    P1->P2 (p = [P0, P1, P2], 6 coordinates), and its gradient."""
    p = ca.SX.sym("p", 6)
    u, v = p[2:4] - p[0:2], p[4:6] - p[2:4]
    theta = ca.atan2(ca.fabs(u[0] * v[1] - u[1] * v[0]), ca.dot(u, v))
    return ca.Function("wrap", [p], [theta, ca.gradient(theta, p)], ["p"], ["theta", "grad"])


#: the friction law's kernels, compiled on first use (plush_opt.fem.kernel_set)
KERNELS = KernelSet(fseg=segment_kernel(), fseg_dR=segment_dR_kernel(),
                    fseg_energy=segment_energy_kernel(), wrap=wrap_kernel())


# --------------------------------------------------------------------------
# The term
# --------------------------------------------------------------------------

class SegmentTerm(Term):
    """The segments of the tendons ``tendons`` (scene indices) of ``model``'s
    scene, at held rest lengths: an energy term whose history is the rest
    lengths.

    Attributes
    ----------
    rest : (n_segments,) the held (committed) rest lengths: what
        :meth:`evaluate`, :meth:`mixed` and :meth:`expression` use.
    tendons : scene indices of the segmented tendons.
    n_segments : their segments, tendon by tendon.
    W : (2 n_via, n_dofs) sparse, flat via point positions P = W x.
    seg_p : (n_segments, 4) each segment's two ends' coordinates in P.
    seg_tendon, seg_winch : (n_segments,) each segment's tendon (scene
        index) and winch.
    seg_first, seg_last : (n_tendons here,) first and winch-end segment.
    assembly_length : (n_segments,) a_t of each segment's tendon.
    n_interior : interior via points; ``lo``, ``hi`` their stopper-side and
        winch-side segments; ``mu`` their tendon's friction; ``via_index``
        their position on the tendon's path (0 = stopper end); ``wrap_p``
        (n_interior, 6) their three via points' coordinates in P.
    D : (n_segments, n_interior) sparse, rest lengths moved by a slip
        delta_i (material through interior via point i toward the winch):
        r_lo -= delta, r_hi += delta.
    K, eps : the tendon law's stiffness and smoothing.
    """

    name = "segments"

    def __init__(self, model, tendons: tuple[int, ...]):
        self.tendons = tuple(tendons)
        self.n_dofs, self.n_winches, self.X = model.n_dofs, model.n_winches, model.X
        self.n_tendons = model.n_tendons
        self.K, self.eps = model.tendon_stiffness, model.tendon_smoothing
        self._build(model)
        self._fseg = Mapped(KERNELS["fseg"], self.n_segments, self._law())
        self._fseg_dR = None
        self._wrap = Mapped(KERNELS["wrap"], self.n_interior, {})
        self.rest = self.start_rest_lengths()
        self._seg = None          # segments() at the pose of the next evaluation (held copies)

    def _law(self) -> dict[int, np.ndarray]:
        return {1: np.full(self.n_segments, self.K), 2: np.full(self.n_segments, self.eps)}

    def _build(self, model):
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
        self.via_index = cat(via, 0)
        self.wrap_p = cat(wrap_p, (0, 6))
        self.mu = np.concatenate(mu) if mu else np.zeros(0)
        self.n_interior = len(self.lo)
        i = np.arange(self.n_interior)
        self.D = sp.csr_matrix((np.r_[-np.ones(len(i)), np.ones(len(i))],
                                (np.r_[self.lo, self.hi], np.r_[i, i])),
                               shape=(n_s, self.n_interior))
        self.assembly_length = model.assembly_length[self.seg_tendon] if n_s else np.zeros(0)
        self.seg_winch = model.tendon_winch[self.seg_tendon] if n_s else np.zeros(0, np.int64)

    # -- history --------------------------------------------------------------

    @property
    def state(self) -> np.ndarray:
        """The held rest lengths (n_segments,), the term's history."""
        return self.rest

    def commit(self, x, c, rest=None) -> None:
        """Take ``rest`` (n_segments,), the rest lengths of an accepted
        state, as the held ones; None keeps them (the rest lengths follow
        from the path the solver took, not from (x, c) alone)."""
        if rest is not None:
            self.rest = self._checked(rest)

    def reset(self) -> None:
        """Back to the start state's rest lengths (:meth:`start_rest_lengths`)."""
        self.rest = self.start_rest_lengths()

    def held(self, rest, seg: dict | None = None) -> "SegmentTerm":
        """This term at rest lengths ``rest`` (a copy sharing everything but
        the held rest lengths). ``seg``: :meth:`segments` at the pose, rest
        lengths and contractions of its next evaluation, if the caller has
        them (used once)."""
        out = copy.copy(self)
        out.rest, out._seg = self._checked(rest), seg
        return out

    def _checked(self, rest) -> np.ndarray:
        rest = np.asarray(rest, dtype=np.float64).reshape(-1)
        if rest.shape != (self.n_segments,):
            raise ValueError(f"rest lengths: {rest.size} entries, the term has {self.n_segments} segments")
        return rest

    # -- rest lengths ---------------------------------------------------------

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
        total = np.bincount(self.seg_tendon, weights=L, minlength=self.n_tendons)[self.seg_tendon]
        return L * self.assembly_length / total

    # -- per segment ----------------------------------------------------------

    def _kernel_input(self, x, r, c) -> np.ndarray:
        n = self.n_segments
        P = self.W @ np.asarray(x, dtype=np.float64).reshape(-1)
        return np.hstack([P[self.seg_p], np.reshape(r, (n, 1)), self.rest_total(c).reshape(n, 1)])

    def segments(self, x, r, c) -> dict[str, np.ndarray]:
        """Per segment at pose x, rest lengths r, contractions c: ``energy``,
        ``grad``/``hess`` in its 4 via point coordinates, ``de_dr``,
        ``dgrad_dr``, ``tension``, ``dtension_dx`` (4), ``dtension_dr``."""
        n = self.n_segments
        e, g, H, er, ger, T, gT, Tr = self._fseg(self._kernel_input(x, r, c), 8)
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

    # -- the term -------------------------------------------------------------

    def admissible(self, x) -> bool:
        """Every held rest length positive (phi = r / R > 0); any pose."""
        return bool(np.all(self.rest > 0))

    def evaluate(self, x, c, order):
        """At the held rest lengths: energy, gradient (n_dofs,) and the
        Hessian part ``via_hess`` (n_segments, 4, 4), each segment's Hessian
        in its ends' via point coordinates (the layout maps it through W)."""
        seg, self._seg = self._seg, None
        return self.evaluate_at(x, c, self.rest, order, seg)

    def evaluate_at(self, x, c, r, order: int, seg: dict | None = None) -> TermEvaluation:
        """:meth:`evaluate` at rest lengths r; ``seg``: :meth:`segments` at
        the same point, if the caller has it."""
        seg = self.segments(x, r, c) if seg is None else seg
        energy = float(seg["energy"].sum())
        if order == 0:
            return TermEvaluation(energy)
        gP = np.bincount(self.seg_p.ravel(), weights=seg["grad"].ravel(), minlength=self.W.shape[0])
        f = self._WT @ gP
        hessian = {"via_hess": seg["hess"]} if order == 2 else {}
        return TermEvaluation(energy, f, hessian, float(np.linalg.norm(f)))

    def mixed_r(self, x, r, c, seg: dict | None = None) -> np.ndarray:
        """d2E/dx dr at rest lengths r, dense (n_dofs, n_segments)."""
        seg = self.segments(x, r, c) if seg is None else seg
        return self.to_x(seg["dgrad_dr"], self.seg_p).T

    def mixed(self, x, c):
        """d2E/dx dc at the held rest lengths, (n_dofs, n_winches): c moves
        only each segment's share phi = r / (a_t - c_w), so column w is
        minus the sum over winch w's segments of d grad / d(a_t - c_w).
        (The path solver's rate in c also shortens the winch-end rest
        length: plush_opt/solve/friction_solve.py.)"""
        if self._fseg_dR is None:
            self._fseg_dR = Mapped(KERNELS["fseg_dR"], self.n_segments, self._law())
        _, dg = self._fseg_dR(self._kernel_input(x, self.rest, c), 2)
        rows = self.to_x(dg.reshape(-1, 4), self.seg_p)           # (n_segments, n_dofs)
        S = sp.csr_matrix((-np.ones(self.n_segments), (self.seg_winch, np.arange(self.n_segments))),
                          shape=(self.n_winches, self.n_segments))
        return np.asarray((S @ rows).T)

    def expression(self, x, c):
        """The energy at the held rest lengths as an MX expression of (x, c).
        No IPOPT backend takes it today: the bilevel method and the IPOPT
        equilibrium solve for a pose at given contractions alone, which a
        path-dependent plant refuses (docs/terms.md)."""
        n = self.n_segments
        P = ca.DM(self.W) @ x
        xs = ca.reshape(P[self.seg_p.ravel().tolist()], 4, n)
        S = ca.DM(sp.csr_matrix((np.ones(n), (np.arange(n), self.seg_winch)), shape=(n, self.n_winches)))
        R = ca.DM(self.assembly_length) - S @ c
        v = ca.vertcat(xs, ca.DM(self.rest).T, R.T)
        e = KERNELS.symbolic["fseg_energy"].map(n, "serial")(v, self.K, self.eps)
        return ca.sum2(e)
