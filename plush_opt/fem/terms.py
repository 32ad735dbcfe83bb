"""The energy terms a :class:`~plush_opt.fem.model.Model` sums, behind one interface.

The total energy of a scene is E(x; c) = sum of its terms, each a
:class:`Term`: the elastic energy of the elements (:class:`ElasticTerm`,
P1 or P2 through the mesh's element object), the pin springs
(:class:`PinTerm`), gravity (:class:`GravityTerm`, only when the scene has
gravity) and the tendons (:class:`~plush_opt.fem.tendons.TendonTerm`). A
term gives, at a flat pose ``x`` (n_dofs,) and contractions ``c``
(n_winches,):

* its energy, gradient and Hessian contribution (:meth:`Term.evaluate`);
* d2E/dx dc (:meth:`Term.mixed`) and d2E/dx dp for the scene parameters
  it depends on (:meth:`Term.parameter_mixed`);
* its energy as a CasADi expression of symbolic (x, c) (:meth:`Term.expression`);
* whether a pose is admissible for it (:meth:`Term.admissible`), and
* :meth:`Term.commit`: the history it carries, committed once a step is
  accepted (none of these terms carries any; the segment term of
  via-point friction, plush_opt/fem/segments.py, carries its rest lengths).

docs/terms.md describes the interface and how a new term plugs in.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .mapped import Mapped
from .mesh import Mesh
from ..io.scene import Scene


def node_dofs(nodes: np.ndarray) -> np.ndarray:
    """Interleaved dof indices of node indices: (..., k) -> (..., 2k)."""
    nodes = np.asarray(nodes, dtype=np.int64)
    return np.stack([2 * nodes, 2 * nodes + 1], axis=-1).reshape(*nodes.shape[:-1], 2 * nodes.shape[-1])


@dataclass(frozen=True)
class TermEvaluation:
    """One term at one pose.

    ``energy`` : the term's energy (order >= 0).
    ``gradient`` : (n_dofs,) its gradient in x (order >= 1), else None.
    ``hessian`` : its Hessian contribution (order 2), as keyword arguments
        of :meth:`~plush_opt.fem.hessian_layout.HessianLayout.assemble`
        (the model assembles every term's parts into one sparse or low-rank
        Hessian in one pass); empty for a term linear in x.
    ``force_scale`` : the size of the term's forces (order >= 1): the
        model judges residuals relative to the largest.
    """

    energy: float
    gradient: np.ndarray | None = None
    hessian: dict = field(default_factory=dict)
    force_scale: float = 0.0


class Term:
    """One energy term of a model (the interface; see the module docstring).

    ``linear`` : True for a term linear in x (no Hessian contribution);
    the CasADi expression adds such terms after the others.
    ``translation_invariant`` : True for a term whose energy a rigid
    translation of the whole body leaves unchanged (the elastic energy,
    the tendons): a body's fall (plush_opt/solve/free_fall.py) evaluates
    only the others along it.
    """

    name = "term"
    linear = False
    translation_invariant = False

    def admissible(self, x: np.ndarray) -> bool:
        """Whether the term is defined at the finite flat pose ``x``."""
        return True

    def violation(self, x: np.ndarray) -> str | None:
        """Why ``x`` is not admissible for this term, in words, or None."""
        return None if self.admissible(x) else f"the {self.name} term is not defined there"

    def evaluate(self, x: np.ndarray, c: np.ndarray, order: int) -> TermEvaluation:
        """Energy (order 0), plus gradient (1), plus Hessian parts (2)."""
        raise NotImplementedError

    def mixed(self, x: np.ndarray, c: np.ndarray) -> np.ndarray | None:
        """d2E/dx dc, (n_dofs, n_winches); None where E does not depend on c."""
        return None

    def parameter_mixed(self, x: np.ndarray, c: np.ndarray) -> dict[str, np.ndarray]:
        """d2E/dx dp for the scene parameters p this term depends on, by name."""
        return {}

    def expression(self, x: ca.MX, c: ca.MX) -> ca.MX:
        """The term's energy as a CasADi expression of (x, c)."""
        raise NotImplementedError

    def max_step(self, x: np.ndarray, dx: np.ndarray) -> float:
        """The largest fraction t in (0, 1] of the step ``dx`` from the
        admissible pose ``x`` along which the term stays admissible
        (continuous collision detection for contact); 1 for a term whose
        admissibility the line search's checks at the trial poses suffice for."""
        return 1.0

    def commit(self, x: np.ndarray, c: np.ndarray) -> None:
        """Take (x, c) as the accepted state: a term with history (stick and
        slip, contact) updates it here, once a step has converged. These
        terms carry none."""


class ElasticTerm(Term):
    """The hyperelastic (compressible Neo-Hookean) energy of every element,
    through the mesh's element type (P1 or P2).

    Attributes
    ----------
    element : the element type (``mesh.element``).
    elem_dofs : (n_elems, 2 * nodes) int64, each element's dofs, interleaved.
    rest_area : (n_elems,) rest area of each corner triangle.
    jacobian_data : what ``element.jacobians`` needs of the rest geometry.
    energy_roundoff_scale : energy of a unit strain over the body: the
        absolute round-off of E (the solvers compare energies against it).
    """

    name = "elastic"
    translation_invariant = True

    def __init__(self, scene: Scene, mesh: Mesh):
        mat = scene.material
        self.mu, self.lam, self.thickness = mat.mu, mat.lam, mat.thickness
        self.element = mesh.element
        self.n_dofs = 2 * mesh.n_nodes
        self.n_elems = mesh.n_elems
        tri = mesh.triangles                              # corner triangles
        XN = mesh.X
        Dm = np.stack([XN[tri[:, 1]] - XN[tri[:, 0]], XN[tri[:, 2]] - XN[tri[:, 0]]], axis=2)
        self.rest_area = np.linalg.det(Dm) / 2
        self._rest_centre = XN[tri].mean(axis=1)         # (where a violation is, in words)
        Dinv = np.linalg.inv(Dm)
        # column-major 2x2 per element, one element per row
        self._Dinv = np.ascontiguousarray(Dinv.transpose(0, 2, 1).reshape(-1, 4))
        self.elem_dofs = node_dofs(mesh.elements)
        self.jacobian_data = self.element.jacobian_data(Dinv, self.rest_area)
        self.elem_weight = mat.thickness * self.rest_area
        self.energy_roundoff_scale = float((mat.mu + mat.lam) * self.elem_weight.sum())
        # the elastic force of a unit strain on one element of mean size
        self._force_scale = self.mu * self.thickness * np.sqrt(np.mean(self.rest_area))
        # mapped kernels take one element per column; a C-ordered
        # (n_elems, k) array is exactly that column-major (k, n_elems) buffer
        consts = {1: self._Dinv, 2: self.elem_weight,
                  3: np.full(self.n_elems, mat.mu), 4: np.full(self.n_elems, mat.lam)}
        kernels = self.element.kernels
        self._by_order = [Mapped(kernels[name], self.n_elems, consts, kernels.symbolic[name])
                          for name in ("psi", "psi_grad", "psi_derivs")]
        self._unit_material = None

    def jacobians(self, x: np.ndarray) -> np.ndarray:
        """J = det F of every element, (n_elems,) (P2: the smallest over its
        quadrature points)."""
        return self.element.jacobians(x[self.elem_dofs], self.jacobian_data)

    def admissible(self, x):
        return bool(np.all(self.jacobians(x) > 0))

    def violation(self, x):
        J = self.jacobians(x)
        k = int(np.argmin(J))
        if J[k] > 0:
            return None
        at = ", ".join(f"{v:.4g}" for v in self._rest_centre[k])
        return f"element {k} (at rest near ({at})) is inverted or degenerate (J = {J[k]:.3g} <= 0)"

    def evaluate(self, x, c, order):
        outs = self._by_order[order](x[self.elem_dofs], order + 1)
        energy = outs[0].sum()
        if order == 0:
            return TermEvaluation(energy)
        g = np.bincount(self.elem_dofs.ravel(), weights=outs[1], minlength=self.n_dofs)
        hessian = {"elem_hess": outs[2].ravel()} if order == 2 else {}
        return TermEvaluation(energy, g, hessian, self._force_scale)

    def parameter_mixed(self, x, c):
        """``mu``, ``lambda`` (n_dofs,): E is linear in them, so each is the
        elastic force with that parameter 1 and the other 0."""
        xe = x[self.elem_dofs]
        return {name: np.bincount(self.elem_dofs.ravel(), weights=fn(xe, 2)[1], minlength=self.n_dofs)
                for name, fn in self._unit_kernels().items()}

    def _unit_kernels(self) -> dict[str, Mapped]:
        """The elastic kernels at (mu, lambda) = (1, 0) and (0, 1), built on first use."""
        if self._unit_material is None:
            ones, zeros = np.ones(self.n_elems), np.zeros(self.n_elems)
            base = {1: self._Dinv, 2: self.elem_weight}
            fn = self.element.kernels["psi_grad"]
            self._unit_material = {"mu": Mapped(fn, self.n_elems, {**base, 3: ones, 4: zeros}),
                                   "lambda": Mapped(fn, self.n_elems, {**base, 3: zeros, 4: ones})}
        return self._unit_material

    def expression(self, x, c):
        n = self.n_elems
        xe = ca.reshape(x[self.elem_dofs.ravel().tolist()], self.elem_dofs.shape[1], n)
        psi = self.element.kernels.symbolic["psi"].map(n, "serial")(
            xe, ca.DM(self._Dinv.T), ca.DM(self.elem_weight).T,
            ca.DM.ones(1, n) * self.mu, ca.DM.ones(1, n) * self.lam)
        return ca.sum2(psi)

    def jacobian_expression(self, x: ca.MX) -> ca.MX:
        """J = det F as a CasADi expression of x (see ``Element.jacobian_expression``)."""
        return self.element.jacobian_expression(x, self.elem_dofs, self.jacobian_data)


class PinTerm(Term):
    """Stiff springs holding the pinned nodes at their rest positions:
    k/2 |x_p - X_p|^2 (``scene.pin_stiffness`` k)."""

    name = "pins"

    def __init__(self, scene: Scene, mesh: Mesh, X: np.ndarray):
        self.stiffness = scene.pin_stiffness
        self.nodes = np.asarray(mesh.pin_nodes, dtype=np.int64)
        self.dofs = node_dofs(self.nodes[:, None]).reshape(-1)
        self.n_dofs = 2 * mesh.n_nodes
        self._rest = X[self.dofs]

    def evaluate(self, x, c, order):
        dp = x[self.dofs] - self._rest
        energy = 0.5 * self.stiffness * dp @ dp
        if order == 0:
            return TermEvaluation(energy)
        f_pin = np.zeros(self.n_dofs)
        f_pin[self.dofs] = self.stiffness * dp
        hessian = {"pin_stiffness": self.stiffness} if order == 2 else {}
        return TermEvaluation(energy, f_pin, hessian, np.linalg.norm(f_pin))

    def translation_slope(self, x, u):
        """d/dt of E at the pose ``x`` translated rigidly by t ``u`` ((2,),
        unit): k (sum of (x_p - X_p) . u + t n_pins), as a function of t."""
        pull = float(np.sum((x[self.dofs] - self._rest).reshape(-1, 2) @ u))
        return lambda t: self.stiffness * (pull + t * len(self.nodes))

    def expression(self, x, c):
        dp = x[self.dofs.tolist()] - ca.DM(self._rest)
        return self.stiffness / 2 * ca.sumsqr(dp)


class ForceTerm(Term):
    """E = -f . x for a constant nodal force ``force`` f (n_dofs,): a
    load, or a residual held fixed (a Newton homotopy,
    plush_opt/solve/accuracy_carry.py)."""

    name = "force"
    linear = True

    def __init__(self, force: np.ndarray):
        self.force = np.asarray(force, dtype=np.float64).reshape(-1)
        self._minus_force = -self.force
        self._scale = float(np.linalg.norm(self.force))

    def evaluate(self, x, c, order):
        energy = self._minus_force @ x
        if order == 0:
            return TermEvaluation(energy)
        return TermEvaluation(energy, self._minus_force, {}, self._scale)

    def expression(self, x, c):
        return ca.dot(ca.DM(self._minus_force), x)


class GravityTerm(ForceTerm):
    """The weight: a :class:`ForceTerm` whose ``force`` is the nodal
    weights (n_dofs,), each element's weight (density * thickness * area *
    g) shared among its nodes by ``element.nodal_shares``."""

    name = "gravity"

    def __init__(self, scene: Scene, mesh: Mesh, elem_weight: np.ndarray):
        mass = mesh.element.nodal_shares(scene.material.density * elem_weight)
        nodal = np.bincount(mesh.elements.ravel(), weights=mass.ravel(), minlength=mesh.n_nodes)
        super().__init__((nodal[:, None] * np.asarray(scene.gravity)[None, :]).reshape(-1))
