"""Scene + Mesh -> Model: the total energy E(x; c) and its derivatives.

Each energy term is defined once, as a small CasADi kernel:

* ``psi``  Neo-Hookean energy of one triangle from its 6 node coordinates
  (``psi2``: a 6-node P2 triangle, 12 coordinates; both in
  plush_opt/fem/elements.py);
* ``seg``  length of one tendon segment from its 4 end coordinates, and
* ``U``    the C2 unilateral tendon energy of one tendon from its stretch
  (both in plush_opt/fem/tendon_law.py).

Two evaluators are built from those kernels, and tests check they agree:

* the CasADi expression ``E(x, c)`` (MX graph of ``map``-ped kernels, so it
  does not grow with the mesh), with CasADi's gradient, exact sparse
  Hessian and mixed derivative. IPOPT (equilibrium cross-check, bilevel
  control) works on this expression;
* the fast path :meth:`Model.evaluate`: the kernels' own gradients and
  Hessians (derived by CasADi per element / per segment), mapped over all
  elements at once, then scattered into a CSC matrix whose pattern and
  scatter indices are computed once per mesh. Newton uses this.

Flat vectors interleave coordinates: ``[x0, y0, x1, y1, ...]``.
A term the scene does not have (gravity, tendons) is not built.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from . import elements
from .attachments import TendonPoints
from ..base.kernels import compiled
from .hessian_layout import FORMS, HessianLayout
from ..base.linalg import Factorizer, LowRankHessian, assembled
from .mesh import Mesh
from .pins import check_pins
from ..io.scene import Scene
from .tendon_law import SEG, SEG_DERIVS, U_DERIVS
from .tendon_law import U as U_FN

log = logging.getLogger(__name__)


@functools.lru_cache(maxsize=None)
def _tendon_kernels() -> dict[str, ca.Function]:
    """The tendon kernels the fast path evaluates, compiled (cached on
    disk) once per process."""
    return {fn.name(): compiled(fn) for fn in (SEG_DERIVS, U_DERIVS)}


def _dofs(nodes: np.ndarray) -> np.ndarray:
    """Interleaved dof indices of node indices: (..., k) -> (..., 2k)."""
    nodes = np.asarray(nodes, dtype=np.int64)
    return np.stack([2 * nodes, 2 * nodes + 1], axis=-1).reshape(*nodes.shape[:-1], -1)


class Mapped:
    """A CasADi Function mapped over ``count`` columns, evaluated into numpy
    arrays through its buffer interface (no DM conversion per call)."""

    def __init__(self, fn: ca.Function, count: int, constants: dict[int, np.ndarray]):
        self.fn = fn.map(count, "serial")
        self.count = count
        self.buf, self._eval = self.fn.buffer()
        self._sizes = [self.fn.nnz_out(i) for i in range(self.fn.n_out())]
        self._keep = []
        for i, value in constants.items():
            arr = np.ascontiguousarray(value, dtype=np.float64)
            self._keep.append(arr)
            self.buf.set_arg(i, memoryview(arr))

    def __call__(self, arg0: np.ndarray, n_out: int) -> list[np.ndarray]:
        arg0 = np.ascontiguousarray(arg0, dtype=np.float64)
        outs = [np.empty(self._sizes[i]) for i in range(n_out)]
        self.buf.set_arg(0, memoryview(arg0))
        for i, out in enumerate(outs):
            self.buf.set_res(i, memoryview(out))
        self._eval()
        return outs


@dataclass(frozen=True)
class Evaluation:
    """E, grad_x E and the sparse Hessian at one pose.

    ``hessian_form`` is the Hessian as the model built it: a CSC matrix, or
    a :class:`~plush_opt.base.linalg.LowRankHessian` (finite attachments); factor
    that. ``hessian`` is always the assembled CSC matrix (built on first
    use in the low-rank case).
    ``force_scale`` is the size of the forces in balance (norm of the
    tendon, pin and gravity forces, at least the elastic force of a unit
    strain on one element): residuals are judged relative to it.
    """

    energy: float
    gradient: np.ndarray | None
    hessian_form: sp.csc_matrix | LowRankHessian | None
    force_scale: float
    admissible: bool

    @functools.cached_property
    def hessian(self) -> sp.csc_matrix | None:
        return assembled(self.hessian_form)


class Model:
    """The energy of one scene on one mesh. Built once; evaluations at any
    pose and contraction leave it unchanged.

    Attributes
    ----------
    scene, mesh : what it was built from.
    low_rank : True when each tendon's U'' l' l'^T is kept out of the
        sparse Hessian as a low-rank term (:class:`~plush_opt.base.linalg.LowRankHessian`);
    split_segments : True when each segment's coupling of its two ends is too.
    n_nodes, n_dofs, n_elems, n_tendons, n_winches : sizes.
    X : (n_dofs,) rest positions, flat.
    E, grad_E, hess_E, mixed_E : CasADi Functions of (x, c):
        energy, gradient (n_dofs), exact sparse Hessian (n_dofs x n_dofs)
        and d2E/dx dc (n_dofs x n_winches).
    """

    def __init__(self, scene: Scene, mesh: Mesh, hessian: str = "auto"):
        """``hessian``: the Hessian's form, one of :data:`HESSIAN_FORMS`:
        "assembled" (one sparse matrix); "rank_one" (each tendon's
        U'' l' l'^T apart: with attachment discs it couples every disc of
        the tendon with every other, densely); "split" (also each segment's
        coupling of its two ends' discs); "auto": "assembled" where the
        attachment discs are small (:data:`SPLIT_MIN_DISC_NODES`), else
        "split", or "rank_one" where splitting would make the update's rank
        larger than :data:`SPLIT_MAX_RANK`."""
        if hessian not in HESSIAN_FORMS:
            raise ValueError(f"hessian={hessian!r}: expected one of {', '.join(HESSIAN_FORMS)}")
        self.scene = scene
        self.mesh = mesh
        self.n_nodes = mesh.n_nodes
        self.n_dofs = 2 * mesh.n_nodes
        self.n_elems = mesh.n_elems
        self.n_winches = len(scene.winches)
        self.n_tendons = len(scene.tendons)
        self.winch_names = scene.winch_names
        self.X = np.ascontiguousarray(mesh.X, dtype=np.float64).reshape(-1)
        self.lower = scene.lower
        self.upper = scene.upper
        check_pins(scene, mesh)

        mat = scene.material
        self.mu, self.lam, self.thickness = mat.mu, mat.lam, mat.thickness
        self.element = mesh.element
        tri = mesh.triangles                              # corner triangles
        XN = mesh.X
        Dm = np.stack([XN[tri[:, 1]] - XN[tri[:, 0]], XN[tri[:, 2]] - XN[tri[:, 0]]], axis=2)
        self.rest_area = np.linalg.det(Dm) / 2
        Dinv = np.linalg.inv(Dm)
        # column-major 2x2 per element, one element per row
        self._Dinv = np.ascontiguousarray(Dinv.transpose(0, 2, 1).reshape(-1, 4))
        self._elem_dofs = _dofs(mesh.elements)            # (n_elems, 6 P1 | 12 P2)
        self._n_elem_dofs = self._elem_dofs.shape[1]
        if self.element == "P2":
            self._quad_grads = elements.quadrature_gradients(Dinv)
        self._elem_weight = mat.thickness * self.rest_area
        # energy of a unit strain over the body: sets the absolute round-off
        # of E (the solvers compare energies against it)
        self.energy_roundoff_scale = float((mat.mu + mat.lam) * self._elem_weight.sum())
        # mapped kernels take one element per column; a C-ordered
        # (n_elems, k) array is exactly that column-major (k, n_elems) buffer
        consts = {1: self._Dinv, 2: self._elem_weight,
                  3: np.full(self.n_elems, mat.mu), 4: np.full(self.n_elems, mat.lam)}
        kernels = elements.fast_kernels(self.element)
        self._psi = Mapped(kernels["psi_derivs"], self.n_elems, consts)
        self._psi_energy = Mapped(kernels["psi"], self.n_elems, consts)
        self._psi_grad = Mapped(kernels["psi_grad"], self.n_elems, consts)

        # pins
        self.pin_stiffness = scene.pin_stiffness
        self.pin_nodes = np.asarray(mesh.pin_nodes, dtype=np.int64)
        self._pin_dofs = _dofs(self.pin_nodes[:, None]).reshape(-1)

        # gravity: E_grav = -f_grav . x with nodal weights m_i g
        self.has_gravity = scene.gravity is not None
        if self.has_gravity:
            if self.element == "P2":
                mass = np.outer(mat.density * self._elem_weight, elements.GRAVITY_SHARE["P2"])
                nodal = np.bincount(mesh.elements.ravel(), weights=mass.ravel(),
                                    minlength=self.n_nodes)
            else:
                mass = mat.density * self._elem_weight / 3
                nodal = np.bincount(tri.ravel(), weights=np.repeat(mass, 3), minlength=self.n_nodes)
            self.f_gravity = (nodal[:, None] * np.asarray(scene.gravity)[None, :]).reshape(-1)
        else:
            self.f_gravity = None

        self._build_tendons()
        self._layout = HessianLayout(self.n_dofs, self._elem_dofs, self._pin_dofs, self._points,
                                     self._seg_dofs, self._tendon_dofs, self._auto_form(hessian))
        self.low_rank, self.split_segments = self._layout.low_rank, self._layout.split
        self.hessian_nnz = self._layout.nnz
        # symbolic Cholesky analysis, computed on the first factorisation
        # and reused for every Hessian of this model (fixed pattern)
        self.factorizer = Factorizer()

    # -- construction -------------------------------------------------------

    def _auto_form(self, hessian: str) -> str:
        if hessian != "auto":
            return hessian
        if self._points.mean_disc_nodes() < SPLIT_MIN_DISC_NODES:
            return "assembled"
        return "split" if 2 * self.n_segments + self.n_tendons <= SPLIT_MAX_RANK else "rank_one"

    def _build_tendons(self):
        """Segments between consecutive via points. A via point with an
        attachment radius is a weighted average of nodes: the tendon terms
        live on z = [x; those points] (plush_opt/fem/attachments.py) and are
        pulled back to the nodes; with every radius 0, z is x itself."""
        scene, mesh = self.scene, self.mesh
        self.has_tendons = self.n_tendons > 0
        self.tendon_stiffness = scene.tendon_stiffness
        self.tendon_smoothing = scene.tendon_smoothing
        widx = {name: i for i, name in enumerate(self.winch_names)}
        self.tendon_winch = np.array([widx[t.winch] for t in scene.tendons], dtype=np.int64)
        self.tendon_paths = [np.asarray(p, dtype=np.int64) for p in mesh.tendon_nodes]
        self._points = TendonPoints(mesh, scene.tendons)
        # the via point weights: via_weights[t] is (n_via, n_nodes) sparse,
        # tendon t's points as weighted nodes (a selection where r = 0)
        self.via_weights = self._points.weights
        self.n_z = self._points.n_z
        paths = self._points.paths
        seg_a = np.concatenate([p[:-1] for p in paths]) if paths else np.zeros(0, np.int64)
        seg_b = np.concatenate([p[1:] for p in paths]) if paths else np.zeros(0, np.int64)
        self._seg_tendon = np.concatenate(
            [np.full(len(p) - 1, t) for t, p in enumerate(paths)]) if paths else np.zeros(0, np.int64)
        # z-space dofs of each segment's two ends
        self._seg_dofs = np.concatenate([_dofs(seg_a[:, None]), _dofs(seg_b[:, None])], axis=1) \
            if paths else np.zeros((0, 4), np.int64)
        self.n_segments = len(seg_a)
        # assembly length a_t = l_t(X) + d_t (d_t the tendon's assembly_offset),
        # l_t at the rest positions of the (weighted) via points
        self.assembly_offset = np.array([t.assembly_offset for t in scene.tendons], dtype=np.float64)
        if self.has_tendons:
            Z = self._points.points(self.X)
            seglen = np.linalg.norm(Z[self._seg_dofs[:, 2:]] - Z[self._seg_dofs[:, :2]], axis=1)
            self.assembly_length = np.bincount(self._seg_tendon, weights=seglen,
                                               minlength=self.n_tendons) + self.assembly_offset
            kernels = _tendon_kernels()
            self._seg = Mapped(kernels["seg_derivs"], self.n_segments, {})
            self._U = Mapped(kernels["U_derivs"], self.n_tendons,
                              {1: np.full(self.n_tendons, scene.tendon_stiffness),
                               2: np.full(self.n_tendons, scene.tendon_smoothing)})
            # each tendon's local dof list (padded with -1) and where each
            # segment's 4 dofs sit in it, for the dense l' l'^T block
            self._tendon_local = max(2 * len(p) for p in paths)
            local = np.full((self.n_tendons, self._tendon_local), -1, dtype=np.int64)
            for t, p in enumerate(paths):
                local[t, : 2 * len(p)] = _dofs(p[None, :])[0]
            self._tendon_dofs = local
            seg_local = np.concatenate([2 * (np.arange(len(p) - 1)) for p in paths])
            self._seg_local_flat = (self._seg_tendon[:, None] * self._tendon_local
                                    + seg_local[:, None] + np.arange(4)[None, :])
        else:
            self.assembly_length = np.zeros(0)
            self._tendon_dofs = np.zeros((0, 0), dtype=np.int64)

    @functools.cached_property
    def _casadi(self) -> dict:
        """The energy as one CasADi expression of (x, c), and its derivatives.

        Built on first use: Newton and the gradient loop never need it, IPOPT
        (equilibrium cross-check, bilevel control) and the tests do."""
        x = ca.MX.sym("x", self.n_dofs)
        c = ca.MX.sym("c", self.n_winches)
        xe = ca.reshape(x[self._elem_dofs.ravel().tolist()], self._n_elem_dofs, self.n_elems)
        psi = elements.KERNELS[self.element][0].map(self.n_elems, "serial")(
            xe, ca.DM(self._Dinv.T), ca.DM(self._elem_weight).T,
            ca.DM.ones(1, self.n_elems) * self.mu, ca.DM.ones(1, self.n_elems) * self.lam)
        E = ca.sum2(psi)
        dp = x[self._pin_dofs.tolist()] - ca.DM(self.X[self._pin_dofs])
        E += self.pin_stiffness / 2 * ca.sumsqr(dp)
        if self.has_tendons:
            z = x if self._points.n_extra == 0 else \
                ca.vertcat(x, ca.DM(self._points.extra_dofs) @ x)
            xs = ca.reshape(z[self._seg_dofs.ravel().tolist()], 4, self.n_segments)
            seglen = SEG.map(self.n_segments, "serial")(xs)
            S = ca.DM(sp.csr_matrix((np.ones(self.n_segments),
                                     (self._seg_tendon, np.arange(self.n_segments))),
                                    shape=(self.n_tendons, self.n_segments)))
            length = S @ seglen.T
            W = ca.DM(sp.csr_matrix((np.ones(self.n_tendons),
                                     (np.arange(self.n_tendons), self.tendon_winch)),
                                    shape=(self.n_tendons, self.n_winches)))
            G = length - ca.DM(self.assembly_length) + W @ c
            U = U_FN.map(self.n_tendons, "serial")(G.T, self.tendon_stiffness, self.tendon_smoothing)
            E += ca.sum2(U)
        if self.has_gravity:
            E -= ca.dot(ca.DM(self.f_gravity), x)
        g = ca.gradient(E, x)
        H = ca.jacobian(g, x)
        M = ca.jacobian(g, c)
        return {
            "x": x, "c": c, "E_sym": E,
            "E": ca.Function("E", [x, c], [E], ["x", "c"], ["E"]),
            "grad_E": ca.Function("grad_E", [x, c], [g], ["x", "c"], ["grad"]),
            "hess_E": ca.Function("hess_E", [x, c], [H], ["x", "c"], ["hess"]),
            "mixed_E": ca.Function("mixed_E", [x, c], [M], ["x", "c"], ["d2E_dxdc"]),
        }

    x_sym = property(lambda self: self._casadi["x"], doc="MX symbol of the flat pose")
    c_sym = property(lambda self: self._casadi["c"], doc="MX symbol of the contractions")
    E_sym = property(lambda self: self._casadi["E_sym"], doc="E as an MX expression")
    E = property(lambda self: self._casadi["E"], doc="CasADi Function E(x, c)")
    grad_E = property(lambda self: self._casadi["grad_E"], doc="CasADi Function grad_x E(x, c)")
    hess_E = property(lambda self: self._casadi["hess_E"], doc="CasADi Function: sparse Hessian")
    mixed_E = property(lambda self: self._casadi["mixed_E"], doc="CasADi Function d2E/dx dc")

    # -- evaluation ----------------------------------------------------------

    def _c(self, c) -> np.ndarray:
        c = np.asarray(c, dtype=np.float64).reshape(-1)
        if c.shape != (self.n_winches,):
            raise ValueError(f"contraction has {c.size} entries, the scene has {self.n_winches} winches")
        return c

    def jacobians(self, x) -> np.ndarray:
        """J = det F of every element at flat pose ``x``, (n_elems,); for P2
        the smallest J over the element's quadrature points."""
        xe = np.asarray(x, dtype=np.float64).reshape(-1)[self._elem_dofs]
        if self.element == "P2":
            return elements.p2_jacobians(xe, self._quad_grads).min(axis=1)
        d1 = xe[:, 2:4] - xe[:, 0:2]
        d2 = xe[:, 4:6] - xe[:, 0:2]
        return (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / (2 * self.rest_area)

    def admissible(self, x) -> bool:
        """No element inverted or degenerate (J > 0 everywhere) and x finite."""
        x = np.asarray(x, dtype=np.float64)
        return bool(np.all(np.isfinite(x)) and np.all(self.jacobians(x) > 0))

    def tendon_state(self, x, c) -> dict[str, np.ndarray]:
        """Per tendon: ``length`` l_t, ``stretch`` G = l_t - (a_t - c_w),
        ``tension`` U'(G), ``dtension`` U''(G), and per segment the length
        gradient (for assembly). Arrays (n_tendons,)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        c = self._c(c)
        if not self.has_tendons:
            z = np.zeros(0)
            return {"length": z, "stretch": z, "tension": z, "dtension": z}
        seglen, seggrad, seghess = self._seg(self._points.points(x)[self._seg_dofs], 3)
        length = np.bincount(self._seg_tendon, weights=seglen, minlength=self.n_tendons)
        G = length - self.assembly_length + c[self.tendon_winch]
        U, dU, d2U = self._U(G, 3)
        return {"length": length, "stretch": G, "energy": U, "tension": dU, "dtension": d2U,
                "seg_grad": seggrad.reshape(-1, 4), "seg_hess": seghess.reshape(-1, 16)}

    def energy(self, x, c) -> float:
        """E(x; c), +inf where the pose is not admissible."""
        return self.evaluate(x, c, order=0).energy

    def evaluate(self, x, c, order: int = 2) -> Evaluation:
        """E (order 0), plus grad_x E (order 1), plus the Hessian (order 2).

        The pose is admissible when every element has J > 0; otherwise the
        energy is +inf and no derivatives are returned.
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        c = self._c(c)
        if not self.admissible(x):
            return Evaluation(np.inf, None, None, np.nan, False)
        n = self.n_dofs
        xe = x[self._elem_dofs]                          # (n_elems, 6 | 12)
        if order == 0:
            (psi,) = self._psi_energy(xe, 1)
            energy = psi.sum()
        elif order == 1:
            psi, ge = self._psi_grad(xe, 2)
            energy = psi.sum()
        else:
            psi, ge, He = self._psi(xe, 3)
            energy = psi.sum()
        dp = x[self._pin_dofs] - self.X[self._pin_dofs]
        energy += 0.5 * self.pin_stiffness * dp @ dp
        if self.has_gravity:
            energy -= self.f_gravity @ x
        if self.has_tendons:
            ts = self.tendon_state(x, c)
            energy += ts["energy"].sum()
        energy = float(energy)
        if order == 0 or not np.isfinite(energy):
            return Evaluation(energy, None, None, np.nan, np.isfinite(energy))

        # forces, term by term (their sizes give the residual's scale)
        g = np.bincount(self._elem_dofs.ravel(), weights=ge, minlength=n)
        f_pin = np.zeros(n)
        f_pin[self._pin_dofs] = self.pin_stiffness * dp
        g += f_pin
        scales = [np.linalg.norm(f_pin), self.mu * self.thickness * np.sqrt(np.mean(self.rest_area))]
        if self.has_gravity:
            g -= self.f_gravity
            scales.append(np.linalg.norm(self.f_gravity))
        if self.has_tendons:
            tension = ts["tension"]
            seg_g = ts["seg_grad"] * tension[self._seg_tendon][:, None]
            f_t = self._points.to_nodes(
                np.bincount(self._seg_dofs.ravel(), weights=seg_g.ravel(), minlength=self.n_z))
            g += f_t
            scales.append(np.linalg.norm(f_t))
        force_scale = float(max(scales))
        if order == 1:
            return Evaluation(energy, g, None, force_scale, True)

        if not self.has_tendons:
            H = self._layout.assemble(He.ravel(), self.pin_stiffness)
        else:
            # U' l'' per segment, U'' l' l'^T per tendon (z-space)
            seg_h = ts["seg_hess"] * tension[self._seg_tendon][:, None]
            H = self._layout.assemble(He.ravel(), self.pin_stiffness, seg_h,
                                      self.length_gradient_local(ts["seg_grad"]), ts["dtension"])
        return Evaluation(energy, g, H, force_scale, True)

    def length_gradient_local(self, seg_grad: np.ndarray) -> np.ndarray:
        """dl_t/dx on each tendon's local dof list, (n_tendons, local)."""
        flat = np.bincount(self._seg_local_flat.ravel(), weights=seg_grad.ravel(),
                           minlength=self.n_tendons * self._tendon_local)
        return flat.reshape(self.n_tendons, self._tendon_local)

    def length_gradient(self, x) -> np.ndarray:
        """dl_t/dx for every tendon, dense (n_dofs, n_tendons) (the routing
        matrix A of the paper, at pose x)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        out = np.zeros((self.n_z, self.n_tendons))
        if self.has_tendons:
            (_, seggrad, _) = self._seg(self._points.points(x)[self._seg_dofs], 3)
            for k in range(4):
                np.add.at(out, (self._seg_dofs[:, k], self._seg_tendon), seggrad.reshape(-1, 4)[:, k])
        return self._points.to_nodes(out)

    def mixed(self, x, c) -> np.ndarray:
        """d2E/dx dc, dense (n_dofs, n_winches): column w is
        sum over tendons t of winch w of U''(G_t) dl_t/dx."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        out = np.zeros((self.n_z, self.n_winches))
        if not self.has_tendons:
            return out
        ts = self.tendon_state(x, c)
        weight = ts["dtension"][self._seg_tendon][:, None] * ts["seg_grad"]
        winch = self.tendon_winch[self._seg_tendon]
        for k in range(4):
            np.add.at(out, (self._seg_dofs[:, k], winch), weight[:, k])
        return self._points.to_nodes(out)

    def parameter_mixed(self, x, c) -> dict[str, np.ndarray]:
        """d2E/dx dp for the scene parameters p, exact, at pose x, contraction c.

        ``mu``, ``lambda`` (n_dofs,): E is linear in them, so each is the
        elastic force with that parameter 1 and the other 0.
        ``tendon_stiffness`` (n_dofs,): U is linear in K: the tendon force / K.
        ``assembly_offset`` (n_dofs, n_tendons): G = l - (a + d) + c, so
        column t is -U''(G_t) dl_t/dx (minus tendon t's share of d2E/dx dc).
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        xe, n = x[self._elem_dofs], self.n_dofs
        out = {name: np.bincount(self._elem_dofs.ravel(), weights=fn(xe, 2)[1], minlength=n)
               for name, fn in self._unit_material.items()}
        out["tendon_stiffness"] = np.zeros((self.n_z, self.n_tendons))
        out["assembly_offset"] = np.zeros((self.n_z, self.n_tendons))
        if self.has_tendons:
            ts = self.tendon_state(x, c)
            for k in range(4):
                np.add.at(out["tendon_stiffness"], (self._seg_dofs[:, k], self._seg_tendon),
                          (ts["tension"][self._seg_tendon] / self.tendon_stiffness) * ts["seg_grad"][:, k])
                np.add.at(out["assembly_offset"], (self._seg_dofs[:, k], self._seg_tendon),
                          -ts["dtension"][self._seg_tendon] * ts["seg_grad"][:, k])
        for key in ("tendon_stiffness", "assembly_offset"):
            out[key] = self._points.to_nodes(out[key])
        out["tendon_stiffness"] = out["tendon_stiffness"].sum(axis=1)
        return out

    @functools.cached_property
    def _unit_material(self) -> dict[str, Mapped]:
        """The elastic kernels at (mu, lambda) = (1, 0) and (0, 1)."""
        ones, zeros = np.ones(self.n_elems), np.zeros(self.n_elems)
        base = {1: self._Dinv, 2: self._elem_weight}
        fn = elements.fast_kernels(self.element)["psi_grad"]
        return {"mu": Mapped(fn, self.n_elems, {**base, 3: ones, 4: zeros}),
                "lambda": Mapped(fn, self.n_elems, {**base, 3: zeros, 4: ones})}


#: the Hessian forms a Model can build (Model's ``hessian`` argument)
HESSIAN_FORMS = ("auto",) + FORMS
# "auto" splits where attachment discs hold at least this many nodes on
# average: the dense disc blocks then fill the factor more than the update's
# solves cost (2 per segment, 1 per tendon, each factorisation); below it
# the assembled factor is as fast or faster (docs/benchmarks.md, "Finite
# attachments and the factor")
SPLIT_MIN_DISC_NODES = 10
# ... and only up to this rank of the update (2 per segment + 1 per tendon),
# above which its solves cost more than the segments' fill: "rank_one" then
# (the hexapod's 84 against the gripper's 36; same table)
SPLIT_MAX_RANK = 48


def build_model(scene: Scene, mesh: Mesh) -> Model:
    """Build the energy model of ``scene`` on ``mesh`` (once per scene)."""
    return Model(scene, mesh)
