"""The tendons' energy term: one C2 unilateral spring per tendon, stretched
by the length of its path through the via points less its assembly length
and the contraction of its winch (plush_opt/fem/tendon_law.py).

A via point with an attachment radius is a weighted average of nodes: the
tendon terms live on z = [x; those points] (plush_opt/fem/attachments.py)
and are pulled back to the nodes; with every radius 0, z is x itself.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from .attachments import TendonPoints
from .mesh import Mesh
from .tendon_law import KERNELS, SEG
from .tendon_law import U as U_FN
from .terms import Mapped, Term, TermEvaluation, node_dofs
from ..io.scene import Scene


class TendonTerm(Term):
    """The tendons of a scene on a mesh (built with no tendon too: the
    Hessian's layout and the routing accessors read its empty arrays; the
    model sums it only when the scene has tendons).

    Attributes
    ----------
    count : number of tendons; ``n_segments`` of segments.
    stiffness, smoothing : the tendon law's K and eps.
    winch : (count,) int64, each tendon's winch.
    paths : each tendon's via nodes (``mesh.tendon_nodes``).
    points : the :class:`~plush_opt.fem.attachments.TendonPoints` (z-space).
    seg_dofs : (n_segments, 4) z-space dofs of each segment's two ends.
    local_dofs : (count, local) each tendon's z-space dofs, padded with -1.
    assembly_offset, assembly_length : (count,) d_t and a_t = l_t(X) + d_t.
    """

    name = "tendons"
    translation_invariant = True           # (lengths between points on the body)

    def __init__(self, scene: Scene, mesh: Mesh, X: np.ndarray):
        self.count = len(scene.tendons)
        self.n_winches = len(scene.winches)
        self.stiffness = scene.tendon_stiffness
        self.smoothing = scene.tendon_smoothing
        widx = {name: i for i, name in enumerate(scene.winch_names)}
        self.winch = np.array([widx[t.winch] for t in scene.tendons], dtype=np.int64)
        self.paths = [np.asarray(p, dtype=np.int64) for p in mesh.tendon_nodes]
        self.points = TendonPoints(mesh, scene.tendons)
        self.n_z = self.points.n_z
        paths = self.points.paths
        seg_a = np.concatenate([p[:-1] for p in paths]) if paths else np.zeros(0, np.int64)
        seg_b = np.concatenate([p[1:] for p in paths]) if paths else np.zeros(0, np.int64)
        self.seg_tendon = np.concatenate(
            [np.full(len(p) - 1, t) for t, p in enumerate(paths)]) if paths else np.zeros(0, np.int64)
        self.seg_dofs = np.concatenate([node_dofs(seg_a[:, None]), node_dofs(seg_b[:, None])], axis=1) \
            if paths else np.zeros((0, 4), np.int64)
        self.n_segments = len(seg_a)
        self.assembly_offset = np.array([t.assembly_offset for t in scene.tendons], dtype=np.float64)
        if self.count:
            self._build_kernels(X, paths)
        else:
            self.assembly_length = np.zeros(0)
            self.local_dofs = np.zeros((0, 0), dtype=np.int64)

    def _build_kernels(self, X: np.ndarray, paths: list[np.ndarray]) -> None:
        Z = self.points.points(X)
        seglen = np.linalg.norm(Z[self.seg_dofs[:, 2:]] - Z[self.seg_dofs[:, :2]], axis=1)
        self.assembly_length = np.bincount(self.seg_tendon, weights=seglen,
                                           minlength=self.count) + self.assembly_offset
        self._seg = Mapped(KERNELS["seg_derivs"], self.n_segments, {})
        self._U = Mapped(KERNELS["U_derivs"], self.count,
                         {1: np.full(self.count, self.stiffness), 2: np.full(self.count, self.smoothing)})
        # each tendon's local dof list (padded with -1) and where each
        # segment's 4 dofs sit in it, for the dense l' l'^T block
        self._local = max(2 * len(p) for p in paths)
        local = np.full((self.count, self._local), -1, dtype=np.int64)
        for t, p in enumerate(paths):
            local[t, : 2 * len(p)] = node_dofs(p[None, :])[0]
        self.local_dofs = local
        seg_local = np.concatenate([2 * (np.arange(len(p) - 1)) for p in paths])
        self._seg_local_flat = (self.seg_tendon[:, None] * self._local
                                + seg_local[:, None] + np.arange(4)[None, :])

    @property
    def via_weights(self) -> list[sp.csr_matrix]:
        """via_weights[t] : (n_via, n_nodes) sparse, tendon t's points as
        weighted nodes (a selection where r = 0)."""
        return self.points.weights

    def state(self, x: np.ndarray, c: np.ndarray) -> dict[str, np.ndarray]:
        """Per tendon: ``length`` l_t, ``stretch`` G = l_t - (a_t - c_w),
        ``tension`` U'(G), ``dtension`` U''(G), and per segment the length
        gradient (for assembly). Arrays (count,)."""
        if not self.count:
            z = np.zeros(0)
            return {"length": z, "stretch": z, "tension": z, "dtension": z}
        seglen, seggrad, seghess = self._seg(self.points.points(x)[self.seg_dofs], 3)
        length = np.bincount(self.seg_tendon, weights=seglen, minlength=self.count)
        G = length - self.assembly_length + c[self.winch]
        U, dU, d2U = self._U(G, 3)
        return {"length": length, "stretch": G, "energy": U, "tension": dU, "dtension": d2U,
                "seg_grad": seggrad.reshape(-1, 4), "seg_hess": seghess.reshape(-1, 16)}

    def evaluate(self, x, c, order):
        ts = self.state(x, c)
        energy = ts["energy"].sum()
        if order == 0:
            return TermEvaluation(energy)
        tension = ts["tension"]
        seg_g = ts["seg_grad"] * tension[self.seg_tendon][:, None]
        f_t = self.points.to_nodes(
            np.bincount(self.seg_dofs.ravel(), weights=seg_g.ravel(), minlength=self.n_z))
        hessian = {}
        if order == 2:
            # U' l'' per segment, U'' l' l'^T per tendon (z-space)
            hessian = {"seg_hess": ts["seg_hess"] * tension[self.seg_tendon][:, None],
                       "length_grad": self.length_gradient_local(ts["seg_grad"]),
                       "dtension": ts["dtension"]}
        return TermEvaluation(energy, f_t, hessian, np.linalg.norm(f_t))

    def length_gradient_local(self, seg_grad: np.ndarray) -> np.ndarray:
        """dl_t/dx on each tendon's local dof list, (count, local)."""
        flat = np.bincount(self._seg_local_flat.ravel(), weights=seg_grad.ravel(),
                           minlength=self.count * self._local)
        return flat.reshape(self.count, self._local)

    def length_gradient(self, x: np.ndarray) -> np.ndarray:
        """dl_t/dx for every tendon, dense (n_dofs, count)."""
        out = np.zeros((self.n_z, self.count))
        if self.count:
            (_, seggrad, _) = self._seg(self.points.points(x)[self.seg_dofs], 3)
            for k in range(4):
                np.add.at(out, (self.seg_dofs[:, k], self.seg_tendon), seggrad.reshape(-1, 4)[:, k])
        return self.points.to_nodes(out)

    def mixed(self, x, c):
        """Column w is the sum over tendons t of winch w of U''(G_t) dl_t/dx."""
        out = np.zeros((self.n_z, self.n_winches))
        ts = self.state(x, c)
        weight = ts["dtension"][self.seg_tendon][:, None] * ts["seg_grad"]
        winch = self.winch[self.seg_tendon]
        for k in range(4):
            np.add.at(out, (self.seg_dofs[:, k], winch), weight[:, k])
        return self.points.to_nodes(out)

    def parameter_mixed(self, x, c):
        """``tendon_stiffness`` (n_dofs,): U is linear in K: the tendon force / K.
        ``assembly_offset`` (n_dofs, count): G = l - (a + d) + c, so column t
        is -U''(G_t) dl_t/dx (minus tendon t's share of d2E/dx dc)."""
        out = {"tendon_stiffness": np.zeros((self.n_z, self.count)),
               "assembly_offset": np.zeros((self.n_z, self.count))}
        if self.count:
            ts = self.state(x, c)
            for k in range(4):
                np.add.at(out["tendon_stiffness"], (self.seg_dofs[:, k], self.seg_tendon),
                          (ts["tension"][self.seg_tendon] / self.stiffness) * ts["seg_grad"][:, k])
                np.add.at(out["assembly_offset"], (self.seg_dofs[:, k], self.seg_tendon),
                          -ts["dtension"][self.seg_tendon] * ts["seg_grad"][:, k])
        for key in ("tendon_stiffness", "assembly_offset"):
            out[key] = self.points.to_nodes(out[key])
        out["tendon_stiffness"] = out["tendon_stiffness"].sum(axis=1)
        return out

    def expression(self, x, c):
        n_seg, count = self.n_segments, self.count
        z = x if self.points.n_extra == 0 else ca.vertcat(x, ca.DM(self.points.extra_dofs) @ x)
        xs = ca.reshape(z[self.seg_dofs.ravel().tolist()], 4, n_seg)
        seglen = SEG.map(n_seg, "serial")(xs)
        S = ca.DM(sp.csr_matrix((np.ones(n_seg), (self.seg_tendon, np.arange(n_seg))),
                                shape=(count, n_seg)))
        length = S @ seglen.T
        W = ca.DM(sp.csr_matrix((np.ones(count), (np.arange(count), self.winch)),
                                shape=(count, self.n_winches)))
        G = length - ca.DM(self.assembly_length) + W @ c
        U = U_FN.map(count, "serial")(G.T, self.stiffness, self.smoothing)
        return ca.sum2(U)
