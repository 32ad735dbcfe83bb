"""Scene + Mesh -> Model: the total energy E(x; c) as the sum of its terms,
and its derivatives.

Each term (plush_opt/fem/terms.py: elastic P1/P2, pins, gravity;
plush_opt/fem/tendons.py: the tendons) is defined once, on small CasADi
kernels:

* ``psi``  Neo-Hookean energy of one element (its element type's kernel,
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
  scatter indices are computed once per mesh
  (plush_opt/fem/hessian_layout.py). Newton uses this.

Flat vectors interleave coordinates: ``[x0, y0, x1, y1, ...]``.
A term the scene does not have (gravity, tendons) is not summed.
:func:`sum_terms` is the sum for any terms and layout: the friction model
(plush_opt/fem/friction.py) sums its terms with it too.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np
import scipy.sparse as sp

from ..base.linalg import Factorizer
from ..base.low_rank import LowRankHessian, assembled
from . import free_motion
from .contact import ContactTerm
from .hessian_layout import FORMS, HessianLayout
from .mesh import Mesh
from .pins import check_pins
from .tendons import TendonTerm
from .terms import ElasticTerm, GravityTerm, PinTerm, Term
from ..io.scene import Scene

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Evaluation:
    """E, grad_x E and the sparse Hessian at one pose.

    ``hessian_form`` is the Hessian as the model built it: a CSC matrix, or
    a :class:`~plush_opt.base.low_rank.LowRankHessian` (finite attachments); factor
    that. ``hessian`` is always the assembled CSC matrix (built on first
    use in the low-rank case).
    ``force_scale`` is the size of the forces in balance (norm of the
    tendon, pin and gravity forces, at least the elastic force of a unit
    strain on one element): residuals are judged relative to it.
    ``unbalanced`` (a gauged evaluation of a body without pins, order 2):
    (n_dofs, k) orthonormal rigid motions along which the Hessian is flat
    but a net force acts (the body falls or slides), or None.
    ``parts`` (only where ``unbalanced`` is set): the terms' own
    evaluations, which a rigid translation of the pose leaves unchanged for
    its translation-invariant terms (``sum_terms``' ``moved_from``).
    """

    energy: float
    gradient: np.ndarray | None
    hessian_form: sp.csc_matrix | LowRankHessian | None
    force_scale: float
    admissible: bool
    unbalanced: np.ndarray | None = None
    parts: tuple | None = field(default=None, repr=False, compare=False)

    @functools.cached_property
    def hessian(self) -> sp.csc_matrix | None:
        return assembled(self.hessian_form)


def sum_terms(terms, layout: HessianLayout, x: np.ndarray, c: np.ndarray, order: int,
              gauge: bool = False, moved_from: Evaluation | None = None) -> Evaluation:
    """The sum of ``terms`` at flat pose ``x`` (n_dofs,) and contractions
    ``c`` (n_winches,): E (order 0), plus grad_x E (order 1), plus the
    Hessian (order 2), every term's parts assembled once by ``layout``.
    Energies and gradients are added in the order of ``terms``. ``gauge``
    (a body without pins): the Hessian gets the gauge of :func:`gauged`.
    ``moved_from``: an evaluation of the same ``terms`` and ``c`` at a
    pose of which ``x`` is a rigid translation, holding ``parts`` and of
    ``order``: its translation-invariant terms' parts are taken as they are.

    Where x is not finite or a term finds it inadmissible (or the energy is
    not finite), E = +inf and no derivatives are returned."""
    kept = moved_from.parts if moved_from is not None else None
    kept = kept if kept is not None and len(kept) == len(terms) else (None,) * len(terms)
    reused = [part if term.translation_invariant else None for term, part in zip(terms, kept)]
    if not (np.all(np.isfinite(x)) and all(term.admissible(x) for term, part in zip(terms, reused) if part is None)):
        return Evaluation(np.inf, None, None, np.nan, False)
    parts = [term.evaluate(x, c, order) if part is None else part for term, part in zip(terms, reused)]
    energy = 0.0
    for part in parts:
        energy += part.energy
    energy = float(energy)
    if order == 0 or not np.isfinite(energy):
        return Evaluation(energy, None, None, np.nan, np.isfinite(energy))
    g = np.zeros(layout.n)
    for part in parts:
        g += part.gradient
    # residuals are judged against the largest term's forces
    force_scale = float(max(part.force_scale for part in parts))
    if order == 1:
        return Evaluation(energy, g, None, force_scale, True)
    hessian = {}
    for part in parts:
        hessian.update(part.hessian)
    ev = Evaluation(energy, g, layout.assemble(**hessian), force_scale, True)
    if not gauge:
        return ev
    ev = gauged(ev, x, layout)
    # a body that falls is moved rigidly next (plush_opt/solve/free_fall.py): keep what it reuses
    return ev if ev.unbalanced is None else replace(ev, parts=tuple(parts))


def gauged(ev: Evaluation, x: np.ndarray, layout: HessianLayout | None = None) -> Evaluation:
    """``ev`` (order 2, of a body without pins; its Hessian a fresh
    assembly, by ``layout`` if given, that nothing else holds: it takes the
    gauge in place) with the gauge of :mod:`~plush_opt.fem.free_motion` on
    the rigid motions it leaves free, and the flat ones with a net force
    along them (``unbalanced``)."""
    if ev.hessian_form is None:
        return ev
    H = ev.hessian
    # the layout's own assembly (not one widened by entries outside its
    # pattern, nor a low-rank form's sum): its diagonal is read off its slots
    slots = layout.diagonal_slots if layout is not None and H.indptr is layout.indptr else None
    if slots is not None and np.all(slots >= 0):
        diagonal = H.data[slots]
    else:
        diagonal, slots = H.diagonal(), None
    R, U = free_motion.split_motions(H, x, ev.gradient, ev.force_scale, diagonal)
    if R.shape[1] == 0 and U.shape[1] == 0:
        return ev
    G = free_motion.gauge(H, R, diagonal, owned=True, diagonal_slots=slots) if R.shape[1] else ev.hessian_form
    return Evaluation(ev.energy, ev.gradient, G, ev.force_scale, True, U if U.shape[1] else None)


def free_motions_at(ev: Evaluation, x: np.ndarray) -> list[str]:
    """The free rigid motions at an ungauged evaluation ``ev`` (order 2), in words."""
    if ev.hessian_form is None:
        return []
    return free_motion.describe(free_motion.free_motions(ev.hessian, x, ev.gradient, ev.force_scale), x)


def unbalanced_at(ev: Evaluation, x: np.ndarray) -> str | None:
    """Why there is no equilibrium near ``x`` (ungauged evaluation ``ev``,
    order 2): a net force along a flat rigid motion; or None."""
    if ev.hessian_form is None:
        return None
    return free_motion.unbalanced(ev.hessian, x, ev.gradient, ev.force_scale)


def violation_of(terms, x) -> str | None:
    """Why ``x`` (flat) is not admissible for ``terms``, in words (the first
    term that refuses it: an inverted element, a gap <= 0, a crossing), or
    None."""
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(x)):
        return "the pose is not finite"
    return next((why for why in (term.violation(x) for term in terms) if why), None)


class HeldTerms:
    """What :func:`~plush_opt.solve.equilibrium.solve_equilibrium` needs of
    a model, for ``terms`` (a model's terms with some held at a state: the
    segment term at its rest lengths, the friction of a contact step)
    summed in ``layout``; sizes and scales are ``model``'s, the
    factorisations ``factorizer``'s."""

    def __init__(self, model, terms: tuple[Term, ...], layout: HessianLayout, factorizer):
        self.terms, self.layout, self.factorizer = tuple(terms), layout, factorizer
        self.n_dofs, self.n_winches, self.X = model.n_dofs, model.n_winches, model.X
        self.unpinned = model.unpinned
        self.energy_roundoff_scale = model.energy_roundoff_scale
        self.has_gravity, self.f_gravity, self.rest_area = model.has_gravity, model.f_gravity, model.rest_area

    def evaluate(self, x, c, order: int = 2) -> Evaluation:
        return sum_terms(self.terms, self.layout, np.asarray(x, dtype=np.float64).reshape(-1),
                         np.asarray(c, dtype=np.float64).reshape(-1), order, gauge=self.unpinned)

    def evaluate_moved(self, x, c, moved_from: Evaluation) -> Evaluation:
        """:meth:`evaluate` (order 2) at ``x``, a rigid translation of the pose of ``moved_from``."""
        return sum_terms(self.terms, self.layout, np.asarray(x, dtype=np.float64).reshape(-1),
                         np.asarray(c, dtype=np.float64).reshape(-1), 2, gauge=self.unpinned,
                         moved_from=moved_from)

    def violation(self, x) -> str | None:
        """Why ``x`` is not admissible (see :meth:`Model.violation`), or None."""
        return violation_of(self.terms, x)

    def max_step(self, x, dx) -> float:
        """The smallest of the terms' (see :meth:`Model.max_step`)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        dx = np.asarray(dx, dtype=np.float64).reshape(-1)
        return float(min((term.max_step(x, dx) for term in self.terms), default=1.0))

    def unbalanced(self, x, c) -> str | None:
        """Why there is no equilibrium near ``x`` (see :meth:`Model.unbalanced`)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        return unbalanced_at(sum_terms(self.terms, self.layout, x, np.asarray(c, dtype=np.float64).reshape(-1),
                                       2), x)


class Model:
    """The energy of one scene on one mesh: the sum of its :attr:`terms`.
    Built once; evaluations at any pose and contraction leave it unchanged.

    Attributes
    ----------
    scene, mesh : what it was built from.
    terms : the energy terms summed, in this order: elastic, pins, gravity
        (when the scene has it), tendons (when it has any), contact (when
        it has a contact section).
    contact : the :class:`~plush_opt.fem.contact.ContactTerm`, or None.
    elastic, pins, tendons : the elastic, pin and tendon terms
        (``tendons`` exists without tendons too, empty, for its routing).
    element : the mesh's element type (``str(model.element)`` is "P1"/"P2").
    elem_dofs : (n_elems, 6 | 12) int64, each element's dofs, interleaved
        (``x[elem_dofs]`` are the element coordinates).
    pin_dofs : (2 n_pins,) int64, the pinned nodes' dofs.
    tendon_points : the tendons' via points (z-space, attachments).
    hessian_layout : the Hessian's pattern and scatter slots.
    low_rank : True when each tendon's U'' l' l'^T is kept out of the
        sparse Hessian as a low-rank term (:class:`~plush_opt.base.low_rank.LowRankHessian`);
    split_segments : True when each segment's coupling of its two ends is too.
    n_nodes, n_dofs, n_elems, n_tendons, n_winches : sizes.
    X : (n_dofs,) rest positions, flat.
    E, grad_E, hess_E, mixed_E : CasADi Functions of (x, c):
        energy, gradient (n_dofs), exact sparse Hessian (n_dofs x n_dofs)
        and d2E/dx dc (n_dofs x n_winches).
    factorizer : the :class:`~plush_opt.base.linalg.Factorizer` of this
        model's Hessians (its symbolic analysis is computed on the first
        factorisation and reused: the pattern is fixed).
    """

    def __init__(self, scene: Scene, mesh: Mesh, hessian: str = "auto"):
        """``hessian``: the Hessian's form, one of :data:`HESSIAN_FORMS`:
        "assembled" (one sparse matrix); "rank_one" (each tendon's
        U'' l' l'^T apart: with attachment discs it couples every disc of
        the tendon with every other, densely); "split" (also each segment's
        coupling of its two ends' discs); "auto": "assembled" where the
        attachment discs are small (:data:`SPLIT_MIN_DISC_NODES`) and the
        tendons' dense blocks too (:data:`DENSE_TENDON_MAX`), else
        "split" ("rank_one" above :data:`DENSE_TENDON_MAX`). A split
        update of rank above :data:`SPLIT_MAX_RANK` is factored through its
        augmented matrix (``factorizer.low_rank``: "augmented"; else
        "woodbury", :class:`~plush_opt.base.linalg.Factorizer`)."""
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

        self.elastic = ElasticTerm(scene, mesh)
        self.pins = PinTerm(scene, mesh, self.X)
        self.tendons = TendonTerm(scene, mesh, self.X)
        self.has_gravity = scene.gravity is not None
        self.has_tendons = self.tendons.count > 0
        gravity = GravityTerm(scene, mesh, self.elastic.elem_weight) if self.has_gravity else None
        self.f_gravity = gravity.force if gravity else None
        self.contact = ContactTerm(scene, mesh, self.X) if scene.contact is not None else None
        self.terms: tuple[Term, ...] = tuple(t for t in (self.elastic, self.pins, gravity,
                                                         self.tendons if self.has_tendons else None,
                                                         self.contact)
                                             if t is not None)
        self._describe_terms(scene)
        # a body only contact holds may keep rigid motions free: its Hessians get a gauge
        self.unpinned = self.contact is not None and len(self.pin_nodes) == 0
        self.hessian_layout = HessianLayout(
            self.n_dofs, self.elem_dofs, self.pin_dofs, self.tendon_points, self.tendons.seg_dofs,
            self.tendons.local_dofs, self._auto_form(hessian))
        self.low_rank, self.split_segments = self.hessian_layout.low_rank, self.hessian_layout.split
        self.hessian_nnz = self.hessian_layout.nnz
        # a split update of high rank: one LDL^T of its augmented matrix beats Woodbury's solves
        low_rank = "augmented" if self.split_segments and self.split_rank > SPLIT_MAX_RANK else "woodbury"
        self.factorizer = (free_motion.GaugedFactorizer if self.unpinned else Factorizer)(low_rank=low_rank)

    def _describe_terms(self, scene: Scene) -> None:
        """The terms' data under the names the solvers and apps read."""
        el, tendons = self.elastic, self.tendons
        self.element, self.elem_dofs, self.rest_area = el.element, el.elem_dofs, el.rest_area
        self.mu, self.lam, self.thickness = el.mu, el.lam, el.thickness
        self.energy_roundoff_scale = el.energy_roundoff_scale
        self.pin_stiffness, self.pin_nodes, self.pin_dofs = self.pins.stiffness, self.pins.nodes, self.pins.dofs
        self.tendon_stiffness, self.tendon_smoothing = scene.tendon_stiffness, scene.tendon_smoothing
        self.tendon_winch, self.tendon_paths = tendons.winch, tendons.paths
        self.tendon_points, self.via_weights, self.n_z = tendons.points, tendons.via_weights, tendons.n_z
        self.n_segments = tendons.n_segments
        self.assembly_offset = tendons.assembly_offset

    @property
    def assembly_length(self) -> np.ndarray:
        """(n_tendons,) each tendon's assembly length a_t = l_t(X) + d_t (the
        tendon term's; assigning it changes the energy, as a calibration
        perturbation does)."""
        return self.tendons.assembly_length

    @assembly_length.setter
    def assembly_length(self, value: np.ndarray) -> None:
        self.tendons.assembly_length = value

    def _auto_form(self, hessian: str) -> str:
        if hessian != "auto":
            return hessian
        if sum((2 * len(p)) ** 2 for p in self.tendon_paths) > DENSE_TENDON_MAX:
            return "rank_one"
        if self.tendon_points.mean_disc_nodes() < SPLIT_MIN_DISC_NODES:
            return "assembled"
        return "split"

    @property
    def split_rank(self) -> int:
        """The rank of the split form's low-rank update (2 per segment, 1
        per tendon, before round-off is dropped)."""
        return 2 * self.n_segments + self.n_tendons

    @functools.cached_property
    def _casadi(self) -> dict:
        """The energy as one CasADi expression of (x, c), and its derivatives.

        Built on first use: Newton and the gradient loop never need it, IPOPT
        (equilibrium cross-check, bilevel control) and the tests do. The
        terms linear in x (gravity) are added last, after the others: the
        order of the sum, and so its round-off, that IPOPT's iterates have
        always seen."""
        x = ca.MX.sym("x", self.n_dofs)
        c = ca.MX.sym("c", self.n_winches)
        ordered = sorted(self.terms, key=lambda term: term.linear)      # stable
        E = ordered[0].expression(x, c)
        for term in ordered[1:]:
            E += term.expression(x, c)
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
        return self.elastic.jacobians(np.asarray(x, dtype=np.float64).reshape(-1))

    def jacobian_expression(self, x: ca.MX) -> ca.MX:
        """J = det F as a CasADi expression of the flat pose ``x``: per
        element (P1), per quadrature point of every element (P2)."""
        return self.elastic.jacobian_expression(x)

    def admissible(self, x) -> bool:
        """x finite and admissible for every term (no element inverted or
        degenerate: J > 0 everywhere)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        return bool(np.all(np.isfinite(x)) and all(term.admissible(x) for term in self.terms))

    def violation(self, x) -> str | None:
        """Why ``x`` is not admissible, in words (the first term that
        refuses it: an inverted element, a gap <= 0, a crossing), or None."""
        return violation_of(self.terms, x)

    def max_step(self, x, dx) -> float:
        """The largest fraction in (0, 1] of the step ``dx`` from the
        admissible pose ``x`` that no term forbids (the smallest over the
        terms' :meth:`~plush_opt.fem.terms.Term.max_step`): a line search
        starts there, so that it never steps through anything."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        dx = np.asarray(dx, dtype=np.float64).reshape(-1)
        return float(min((term.max_step(x, dx) for term in self.terms), default=1.0))

    def tendon_state(self, x, c) -> dict[str, np.ndarray]:
        """Per tendon: ``length`` l_t, ``stretch`` G = l_t - (a_t - c_w),
        ``tension`` U'(G), ``dtension`` U''(G), and per segment the length
        gradient (for assembly). Arrays (n_tendons,)."""
        return self.tendons.state(np.asarray(x, dtype=np.float64).reshape(-1), self._c(c))

    def energy(self, x, c) -> float:
        """E(x; c), +inf where the pose is not admissible."""
        return self.evaluate(x, c, order=0).energy

    def evaluate(self, x, c, order: int = 2) -> Evaluation:
        """E (order 0), plus grad_x E (order 1), plus the Hessian (order 2):
        the sums of the terms' (in the order of :attr:`terms`).

        The pose is admissible when every element has J > 0 (and, with
        contact, every gap is positive); otherwise the energy is +inf and
        no derivatives are returned. A body without pins gets the gauge of
        :mod:`~plush_opt.fem.free_motion` on the rigid motions the contact
        leaves free (``hessian_form``; ``hessian`` too).
        """
        return sum_terms(self.terms, self.hessian_layout, np.asarray(x, dtype=np.float64).reshape(-1),
                         self._c(c), order, gauge=self.unpinned)

    def evaluate_moved(self, x, c, moved_from: Evaluation) -> Evaluation:
        """:meth:`evaluate` (order 2) at ``x``, a rigid translation of the
        pose of ``moved_from`` (:func:`sum_terms`): the elastic and tendon
        parts are taken from it."""
        return sum_terms(self.terms, self.hessian_layout, np.asarray(x, dtype=np.float64).reshape(-1),
                         self._c(c), 2, gauge=self.unpinned, moved_from=moved_from)

    def free_motions(self, x, c, extra: tuple[Term, ...] = ()) -> list[str]:
        """The rigid motions the contact leaves free at flat pose ``x`` (an
        unpinned body), in words; [] for a held body. ``extra``: terms
        summed with the model's (the friction of a step)."""
        if not self.unpinned:
            return []
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        return free_motions_at(sum_terms(self.terms + tuple(extra), self.hessian_layout, x, self._c(c), 2), x)

    def unbalanced(self, x, c) -> str | None:
        """For an unpinned body: why there is no equilibrium near ``x`` (a
        net force along a free rigid motion), or None."""
        if not self.unpinned:
            return None
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        return unbalanced_at(sum_terms(self.terms, self.hessian_layout, x, self._c(c), 2), x)

    def length_gradient_local(self, seg_grad: np.ndarray) -> np.ndarray:
        """dl_t/dx on each tendon's local dof list, (n_tendons, local)."""
        return self.tendons.length_gradient_local(seg_grad)

    def length_gradient(self, x) -> np.ndarray:
        """dl_t/dx for every tendon, dense (n_dofs, n_tendons) (the routing
        matrix A of the paper, at pose x)."""
        return self.tendons.length_gradient(np.asarray(x, dtype=np.float64).reshape(-1))

    def mixed(self, x, c) -> np.ndarray:
        """d2E/dx dc, dense (n_dofs, n_winches): the sum of the terms'
        (column w: sum over tendons t of winch w of U''(G_t) dl_t/dx)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        c = self._c(c)
        out = np.zeros((self.n_dofs, self.n_winches))
        for term in self.terms:
            m = term.mixed(x, c)
            if m is not None:
                out += m
        return out

    def parameter_mixed(self, x, c) -> dict[str, np.ndarray]:
        """d2E/dx dp for the scene parameters p, exact, at pose x, contraction c.

        ``mu``, ``lambda`` (n_dofs,): E is linear in them, so each is the
        elastic force with that parameter 1 and the other 0.
        ``tendon_stiffness`` (n_dofs,): U is linear in K: the tendon force / K.
        ``assembly_offset`` (n_dofs, n_tendons): G = l - (a + d) + c, so
        column t is -U''(G_t) dl_t/dx (minus tendon t's share of d2E/dx dc).
        A parameter of a term the scene does not have has derivative zero.
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        c = self._c(c)
        out = {}
        for term in self.terms:
            out.update(term.parameter_mixed(x, c))
        out.setdefault("tendon_stiffness", np.zeros(self.n_dofs))
        out.setdefault("assembly_offset", np.zeros((self.n_dofs, 0)))
        return out

    def commit(self, x, c) -> None:
        """Take (x, c) as the accepted equilibrium: every term with history
        commits it (none of the current terms carries any)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        c = self._c(c)
        for term in self.terms:
            term.commit(x, c)


#: the Hessian forms a Model can build (Model's ``hessian`` argument)
HESSIAN_FORMS = ("auto",) + FORMS
# "auto" splits where attachment discs hold at least this many nodes on
# average: the dense disc blocks then fill the factor more than the update's
# solves cost (2 per segment, 1 per tendon, each factorisation); below it
# the assembled factor is as fast or faster (docs/benchmarks.md, "Finite
# attachments and the factor")
SPLIT_MIN_DISC_NODES = 10
# Up to this rank of the split update (2 per segment + 1 per tendon) it is
# factored by Woodbury (the sparse part, then k solves), above it through
# its augmented matrix, whose one LDL^T then costs less (0.7 x on the
# hexapod's rank 84: docs/benchmarks.md, "Finite attachments and the factor")
SPLIT_MAX_RANK = 48
# "auto" keeps the tendons' dense l' l'^T blocks (2 dofs per via point
# squared, summed over tendons) apart above this many entries: assembled,
# they would make the Hessian's memory grow with the square of the via points
DENSE_TENDON_MAX = 40_000


def build_model(scene: Scene, mesh: Mesh) -> Model:
    """Build the energy model of ``scene`` on ``mesh`` (once per scene)."""
    return Model(scene, mesh)
