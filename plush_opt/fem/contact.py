"""Contact with the floor, rigid obstacles and the body itself, as one
energy term (docs/terms.md, docs/model.md "Contact").

E_contact = kappa * sum over gap pairs of w * b(d^2), the IPC barrier on
squared distances (:func:`~plush_opt.fem.contact_geometry.barrier`): zero
beyond d_hat, growing without bound as a gap closes. The pairs
(docs/problem-format.md, "Contact"):

* ``ground``: every boundary node to the floor line (a signed gap: the
  body stays on its upper side);
* an obstacle: every boundary node to every obstacle edge, and every
  obstacle vertex to every boundary segment (unsigned point-segment
  distances);
* ``self``: every boundary node to every boundary segment that neither
  holds it nor a neighbour of it along the boundary.

Only pairs closer than d_hat carry energy; a broad phase finds them in
near-linear time. A pose is admissible when every gap is positive, no
boundary node is inside an obstacle and no boundary segment crosses an
obstacle edge (or, with ``self``, another boundary segment):
:meth:`ContactTerm.max_step` bounds each solver step by continuous
collision detection so that no step passes through anything.
"""

from __future__ import annotations

import functools

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from ..base.errors import SceneError, format_point
from . import contact_geometry as geo
from .contact_boundary import Boundary, build_boundary
from .contact_symbolic import obstacle_energy
from .mesh import Mesh
from .terms import Term, TermEvaluation, node_dofs
from ..io.scene import Scene

#: a step may close at most this fraction of a gap in one go (IPC's CCD keeps
#: a share of the distance: a line search never starts at a touching pose)
CLOSING_FRACTION = 0.8
#: kappa when the file leaves it out: mu * thickness / d_hat^3 times this. The
#: barrier's stiffness at d = d_hat / 2 is then that of an elastic layer about
#: d_hat / 10 deep: stiff enough to hold the loads of a soft body within a
#: fraction of d_hat, soft enough to keep Newton's steps large.
KAPPA_SCALE = 1.0


@dataclass(frozen=True)
class Pairs:
    """The active point-segment pairs at one pose (k pairs).

    dofs : (k, 6) the pose dofs of (p, a, b), -1 where the point is fixed
        (an obstacle's); P, A, B : (k, 2) their positions; weight : (k,);
    label : (k,) int, which thing the pair touches (1 + obstacle index, or
        0 for self)."""

    dofs: np.ndarray
    P: np.ndarray
    A: np.ndarray
    B: np.ndarray
    weight: np.ndarray
    label: np.ndarray

    @staticmethod
    def empty() -> "Pairs":
        z = np.zeros((0, 2))
        return Pairs(np.zeros((0, 6), dtype=np.int64), z, z, z, np.zeros(0), np.zeros(0, dtype=np.int64))


@dataclass(frozen=True)
class Entries:
    """A term's sparse Hessian as COO entries (duplicates add), handed to
    :meth:`~plush_opt.fem.hessian_layout.HessianLayout.assemble` without
    building a scipy matrix each evaluation: ``row``, ``col`` (k,) int,
    ``data`` (k,), ``shape`` (n_dofs, n_dofs)."""

    row: np.ndarray
    col: np.ndarray
    data: np.ndarray
    shape: tuple[int, int]

    @property
    def nnz(self) -> int:
        return len(self.data)

    def tocoo(self) -> sp.coo_matrix:
        return sp.coo_matrix((self.data, (self.row, self.col)), shape=self.shape)

    def tocsr(self) -> sp.csr_matrix:
        return self.tocoo().tocsr()


#: the pairs of a term with neither obstacles nor self-contact (read-only, shared)
_NO_PAIRS = Pairs.empty()
for _array in vars(_NO_PAIRS).values():
    _array.setflags(write=False)


def default_stiffness(scene: Scene, distance: float) -> float:
    """kappa for a file that leaves ``contact.stiffness`` out (energy units
    per length^5): :data:`KAPPA_SCALE` mu thickness / d_hat^3."""
    return KAPPA_SCALE * scene.material.mu * scene.material.thickness / distance ** 3


class ContactTerm(Term):
    """The contact barrier of a scene with a ``contact`` section.

    Attributes
    ----------
    boundary : the body's :class:`~plush_opt.fem.contact_boundary.Boundary`.
    distance, dhat2 : d_hat and its square (length units).
    stiffness : kappa; ``stiffness_chosen`` True when the model chose it.
    friction : the Coulomb coefficient of the section (0: frictionless).
    ground : the scene's floor or None; obstacles : the scene's obstacles;
    self_contact : whether the body's boundary may touch itself.
    """

    name = "contact"

    def __init__(self, scene: Scene, mesh: Mesh, X: np.ndarray):
        section = scene.contact
        self.source = scene.source
        self.boundary: Boundary = build_boundary(mesh)
        self.distance = section.distance
        self.dhat2 = section.distance ** 2
        self.stiffness_chosen = section.stiffness is None
        self.stiffness = default_stiffness(scene, section.distance) if self.stiffness_chosen else section.stiffness
        self.friction = section.friction
        self.ground = section.ground
        self.obstacles = section.obstacles
        self.self_contact = section.self_contact
        self.n_dofs = X.size
        self.node_dofs = node_dofs(self.boundary.nodes[:, None])          # (b, 2)
        self._seg_dofs = node_dofs(self.boundary.segments)                # (m, 4)
        if self.ground is not None:
            self._normal = self.ground.normal
            self._offset = float(self._normal @ np.array([0.0, self.ground.height]))
            # where a node's floor Hessian curv n n^T has entries (one for a level floor)
            nn = np.outer(self._normal, self._normal)
            i, j = np.nonzero(nn)
            self._ground_rows, self._ground_cols = self.node_dofs[:, i], self.node_dofs[:, j]
            self._ground_nn = nn[i, j]
        self._obstacle_edges = [(o.outline, np.roll(o.outline, -1, axis=0)) for o in self.obstacles]
        self._obstacle_weight = [0.5 * (np.linalg.norm(b - a, axis=1)
                                        + np.roll(np.linalg.norm(b - a, axis=1), 1))
                                 for a, b in self._obstacle_edges]
        self._last_pairs = None            # (radius, boundary positions, Pairs) of the last pose asked
        self._check_rest(X)

    # -- geometry at a pose ---------------------------------------------------

    def points(self, x: np.ndarray) -> np.ndarray:
        """(b, 2) the boundary nodes' positions at flat pose ``x``."""
        return x[self.node_dofs]

    def ground_gaps(self, x: np.ndarray) -> np.ndarray:
        """(b,) signed distance of each boundary node above the floor."""
        return self.points(x) @ self._normal - self._offset

    def _segment_ends(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        P = self.points(x)
        return P[self.boundary.local[:, 0]], P[self.boundary.local[:, 1]]

    def pairs(self, x: np.ndarray, radius: float | None = None) -> Pairs:
        """The point-segment pairs (obstacles, self) closer than ``radius``
        (default d_hat) at flat pose ``x``. The last pose's pairs are kept
        (an evaluation asks at the same pose for admissibility and then
        for the energy); its arrays are read-only."""
        radius = self.distance if radius is None else radius
        if not (self.obstacles or self.self_contact):
            return _NO_PAIRS
        P = self.points(x)
        last = self._last_pairs
        if last is not None and last[0] == radius and np.array_equal(last[1], P):
            return last[2]
        pairs = self._find_pairs(P, radius)
        for array in vars(pairs).values():
            array.setflags(write=False)
        self._last_pairs = (radius, P, pairs)
        return pairs

    def _find_pairs(self, P: np.ndarray, radius: float) -> Pairs:
        """The broad and narrow phase of :meth:`pairs` at boundary positions ``P``."""
        A, B = P[self.boundary.local[:, 0]], P[self.boundary.local[:, 1]]
        bd, sd = self.node_dofs, self._seg_dofs
        parts = []
        for k, ((oa, ob), ow) in enumerate(zip(self._obstacle_edges, self._obstacle_weight)):
            i, e = geo.candidate_pairs(P, oa, ob, radius)          # body node - obstacle edge
            parts.append((np.c_[bd[i], np.full((len(i), 4), -1)], P[i], oa[e], ob[e],
                          self.boundary.weight[i], k + 1))
            v, s = geo.candidate_pairs(oa, A, B, radius)           # obstacle vertex - body segment
            parts.append((np.c_[np.full((len(v), 2), -1), sd[s]], oa[v], A[s], B[s], ow[v], k + 1))
        if self.self_contact:
            i, s = geo.candidate_pairs(P, A, B, radius, exclude=self.boundary.near)
            parts.append((np.c_[bd[i], sd[s]], P[i], A[s], B[s], self.boundary.weight[i], 0))
        if not parts:
            return Pairs.empty()
        return Pairs(np.concatenate([p[0] for p in parts]).astype(np.int64),
                     np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts]),
                     np.concatenate([p[3] for p in parts]), np.concatenate([p[4] for p in parts]),
                     np.concatenate([np.full(len(p[0]), p[5], dtype=np.int64) for p in parts]))

    # -- the Term interface ---------------------------------------------------

    def admissible(self, x):
        return self.violation(x) is None

    def violation(self, x: np.ndarray) -> str | None:
        """Why ``x`` is not admissible for contact, in words, or None."""
        if self.ground is not None:
            d = self.ground_gaps(x)
            if np.any(d <= 0):
                k = int(np.argmin(d))
                return f"boundary node {int(self.boundary.nodes[k])} is on or below the ground (gap {d[k]:.3g})"
        if not (self.obstacles or self.self_contact):
            return None
        P = self.points(x)
        A, B = self._segment_ends(x)
        for o, (oa, ob) in zip(self.obstacles, self._obstacle_edges):
            inside = geo.points_in_polygon(P, o.outline)
            if inside.any():
                k = int(np.flatnonzero(inside)[0])
                return f"boundary node {int(self.boundary.nodes[k])} is inside obstacle {o.name!r}"
            i, _ = geo.crossing_pairs(A, B, oa, ob)
            if len(i):
                s = self.boundary.segments[i[0]]
                return f"boundary segment {int(s[0])}-{int(s[1])} crosses obstacle {o.name!r}"
        if self.self_contact:
            i, j = geo.crossing_pairs(A, B, shared=self.boundary.local)
            if len(i):
                s, t = self.boundary.segments[i[0]], self.boundary.segments[j[0]]
                return f"boundary segments {int(s[0])}-{int(s[1])} and {int(t[0])}-{int(t[1])} cross"
        pairs = self.pairs(x)
        if len(pairs.weight):
            s, _, _ = geo.point_segment_sq(pairs.P, pairs.A, pairs.B, order=0)
            if np.any(s <= 0):
                return "a boundary node touches a segment (gap 0)"
        return None

    def evaluate(self, x, c, order):
        energy = 0.0
        g = np.zeros(self.n_dofs) if order >= 1 else None
        rows, cols, vals = [], [], []
        if self.ground is not None:
            e, parts = self.ground_part(x, order)
            energy += e
            if order >= 1:
                dofs, grad, hess = parts
                g[dofs.ravel()] = grad.ravel()          # (each boundary node once)
                if order == 2:
                    for a, b in zip((rows, cols, vals), hess):
                        a.append(b)
        pairs = self.pairs(x)
        if len(pairs.weight):
            e, grad, hess = self.pair_part(pairs, order)
            energy += e
            if order >= 1:
                ok = pairs.dofs >= 0
                g += np.bincount(pairs.dofs[ok], weights=grad[ok], minlength=self.n_dofs)
                if order == 2:
                    _collect(rows, cols, vals, pairs.dofs, hess)
        if order == 0:
            return TermEvaluation(float(energy))
        hessian = {}
        if order == 2:
            rows, cols, vals = (_joined(a, dtype) for a, dtype in ((rows, np.int64), (cols, np.int64),
                                                                   (vals, np.float64)))
            hessian = {"contact_hess": Entries(rows, cols, vals, (self.n_dofs, self.n_dofs))}
        # the contact forces in balance (0 where nothing touches: the other terms set the scale)
        return TermEvaluation(float(energy), g, hessian, float(np.linalg.norm(g)))

    def ground_part(self, x, order):
        """The floor's energy and, per active node, its dofs (k, 2) and
        gradient (k, 2), and the Hessian's nonzero entries as COO (rows,
        cols, data)."""
        d = self.ground_gaps(x)
        act = np.flatnonzero(d < self.distance)
        da = d[act]
        s = da * da
        b, db, d2b = geo.barrier(s, self.dhat2, order)
        kw = self.stiffness * self.boundary.weight[act]
        energy = float(np.sum(kw * b))
        if order == 0:
            return energy, None
        n = self._normal
        grad = (kw * db * 2 * da)[:, None] * n[None, :]
        hess = None
        if order == 2:
            curv = kw * (d2b * 4 * s + db * 2)
            hess = (self._ground_rows[act].ravel(), self._ground_cols[act].ravel(),
                    (curv[:, None] * self._ground_nn[None, :]).ravel())
        return energy, (self.node_dofs[act], grad, hess)

    def translation_slope(self, x: np.ndarray, u: np.ndarray):
        """d/dt of the energy at ``x`` translated rigidly by t ``u`` ((2,),
        unit) as a function of t; None with obstacles or self-contact (their
        pairs change on the way). A floor's gaps move by t (n . u): each
        call costs a few array operations on the boundary."""
        if self.obstacles or self.self_contact:
            return None
        if self.ground is None:
            return lambda t: 0.0
        return functools.partial(_floor_slope, self.ground_gaps(x), float(self._normal @ u),
                                 self.stiffness * self.boundary.weight, self.distance, self.dhat2)

    def pair_part(self, pairs: Pairs, order):
        s, ds, d2s = geo.point_segment_sq(pairs.P, pairs.A, pairs.B, order=order)
        b, db, d2b = geo.barrier(s, self.dhat2)
        kw = self.stiffness * pairs.weight
        energy = float(np.sum(kw * b))
        if order == 0:
            return energy, None, None
        grad = (kw * db)[:, None] * ds
        hess = None
        if order == 2:
            hess = (kw * d2b)[:, None, None] * ds[:, :, None] * ds[:, None, :] + (kw * db)[:, None, None] * d2s
        return energy, grad, hess

    def max_step(self, x, dx):
        """The first time of impact along ``dx`` over every pair, times
        :data:`CLOSING_FRACTION` (1 where nothing comes close)."""
        t = 1.0
        if self.ground is not None:
            d = self.ground_gaps(x)
            closing = -(dx[self.node_dofs] @ self._normal)
            hit = closing > 0
            if hit.any():
                t = min(t, CLOSING_FRACTION * float(np.min(d[hit] / closing[hit])))
        if self.obstacles or self.self_contact:
            t = min(t, self._ccd(x, dx))
        return max(t, 0.0)

    def _ccd(self, x, dx) -> float:
        P, dP = self.points(x), dx[self.node_dofs]
        A, B = self._segment_ends(x)
        dA, dB = dP[self.boundary.local[:, 0]], dP[self.boundary.local[:, 1]]
        t = 1.0
        for oa, ob in self._obstacle_edges:
            still = np.zeros_like(oa)
            i, e = geo.motion_candidates(P, dP, oa, ob, still, still, 0.0)
            if len(i):
                t = min(t, float(np.min(geo.ccd_point_segment(P[i], oa[e], ob[e], dP[i], still[e], still[e],
                                                              min_fraction=1 - CLOSING_FRACTION))))
            v, s = geo.motion_candidates(oa, still, A, B, dA, dB, 0.0)
            if len(v):
                t = min(t, float(np.min(geo.ccd_point_segment(oa[v], A[s], B[s], still[v], dA[s], dB[s],
                                                              min_fraction=1 - CLOSING_FRACTION))))
        if self.self_contact:
            i, s = geo.motion_candidates(P, dP, A, B, dA, dB, 0.0, exclude=self.boundary.near)
            if len(i):
                t = min(t, float(np.min(geo.ccd_point_segment(P[i], A[s], B[s], dP[i], dA[s], dB[s],
                                                              min_fraction=1 - CLOSING_FRACTION))))
        return t

    def expression(self, x, c):
        if self.self_contact:
            raise SceneError(f"{self.source}: contact.self: the IPOPT backends (--equilibrium ipopt, "
                             "BilevelOptions(formulation='full')) take the floor and obstacles, not "
                             "self-contact (its pairs grow with the square of the boundary); use Newton")
        P = ca.reshape(x, 2, self.n_dofs // 2)[:, self.boundary.nodes.tolist()]
        energy = ca.MX(0)
        if self.ground is not None:
            n = self._normal
            d = n[0] * P[0, :] + n[1] * P[1, :] - self._offset
            u = d * d - self.dhat2
            # log(d / d_hat) (not of d^2): a pose below the floor evaluates to NaN,
            # which IPOPT's line search backs off from
            b = ca.if_else(d < self.distance, -u * u * 2 * ca.log(d / self.distance), 0)
            energy += self.stiffness * ca.dot(ca.DM(self.boundary.weight), b.T)
        if self.obstacles:
            energy += obstacle_energy(P, self.boundary.local, self.boundary.weight, self._obstacle_edges,
                                      self._obstacle_weight, self.stiffness, self.dhat2)
        return energy

    # -- the rest pose --------------------------------------------------------

    def _check_rest(self, X: np.ndarray) -> None:
        """Refuse a scene whose rest pose is not admissible, naming the key."""
        where = f"{self.source}: contact"
        if self.ground is not None:
            d = self.ground_gaps(X)
            if np.any(d <= 0):
                k = int(np.argmin(d))
                node = int(self.boundary.nodes[k])
                raise SceneError(f"{where}.ground: the body starts on or below the ground: boundary node "
                                 f"{node} at {format_point(X[2 * node:2 * node + 2])} is "
                                 f"{-d[k]:.4g} below it (the rest pose must be above the floor)")
        for i, o in enumerate(self.obstacles):
            P = self.points(X)
            A, B = self._segment_ends(X)
            inside = geo.points_in_polygon(P, o.outline)
            crossing = len(geo.crossing_pairs(A, B, *self._obstacle_edges[i])[0]) > 0
            enclosed = bool(geo.points_inside(o.outline[:1], A, B).any())   # inside the body (its holes out)
            if inside.any() or crossing or enclosed:
                raise SceneError(f"{where}.obstacles[{i}]: obstacle {o.name!r} overlaps the body's rest "
                                 "pose (the rest pose must be clear of every obstacle)")
        if self.self_contact:
            A, B = self._segment_ends(X)
            i, j = geo.crossing_pairs(A, B, shared=self.boundary.local)
            if len(i):
                raise SceneError(f"{where}.self: the body's boundary crosses itself in the rest pose")
        bad = self.violation(X)
        if bad is not None:
            raise SceneError(f"{where}: the rest pose is not admissible: {bad}")


def rest_pushes(term: ContactTerm | None, X: np.ndarray) -> str | None:
    """Where ``term``'s self-contact already pushes in the rest pose ``X``,
    in words (the closest pair within d_hat), or None (also for no contact
    term, a model's ``contact`` without a section). The format pairs a
    node with every boundary segment but its own and its neighbours': on a boundary
    cut into segments shorter than about d_hat / 2 (a fine mesh of any
    outline), or at a tight bend, the same stretch of boundary is then
    within reach of itself, and the unloaded body is pushed apart."""
    if term is None or not term.self_contact:
        return None
    P = term.points(X)
    A, B = P[term.boundary.local[:, 0]], P[term.boundary.local[:, 1]]
    i, k = geo.candidate_pairs(P, A, B, term.distance, exclude=term.boundary.near)
    if not len(i):
        return None
    gap = np.sqrt(geo.point_segment_sq(P[i], A[k], B[k], order=0)[0])
    if not np.any(gap < term.distance):
        return None
    j = int(np.argmin(gap))
    node, (a, b) = int(term.boundary.nodes[i[j]]), term.boundary.segments[k[j]]
    return (f"boundary node {node} at {format_point(P[i[j]])} is {gap[j]:.3g} from boundary segment "
            f"{int(a)}-{int(b)} in the rest pose, within contact.distance {term.distance:g} "
            f"(segments {term.boundary.rest_length[k[j]]:.3g} long there): self-contact pushes the "
            "unloaded body apart")


def _floor_slope(d0: np.ndarray, rate: float, kw: np.ndarray, distance: float, dhat2: float, t: float) -> float:
    """d/dt of the floor's barrier energy where the gaps ``d0`` (b,) move by
    t ``rate`` (``kw`` (b,) the nodes' stiffness x weight)."""
    d = d0 + t * rate
    act = np.flatnonzero(d < distance)
    db = geo.barrier_slope(d[act] ** 2, dhat2)
    return float(np.sum(kw[act] * db * 2 * d[act])) * rate


def _joined(parts: list, dtype) -> np.ndarray:
    """The arrays of ``parts`` end to end (the one itself where there is one)."""
    if len(parts) == 1:
        return parts[0]
    return np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)


def _collect(rows, cols, vals, dofs: np.ndarray, hess: np.ndarray) -> None:
    """Append the entries of local Hessians ``hess`` (k, q, q) on ``dofs``
    (k, q) to a COO triple, skipping fixed points (dof -1)."""
    q = dofs.shape[1]
    r = np.repeat(dofs, q, axis=1)
    c = np.tile(dofs, (1, q))
    ok = (r >= 0) & (c >= 0)
    rows.append(r[ok])
    cols.append(c[ok])
    vals.append(hess.reshape(len(dofs), q * q)[ok])

