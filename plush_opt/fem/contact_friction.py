"""Coulomb friction at contacts with the floor and obstacles: IPC's lagged,
smoothed static friction (docs/model.md, "Contact", "Friction").

A boundary node pressed on the floor or on an obstacle edge with normal
force lambda resists moving along that surface, away from its anchor, with
the potential

    D = sum over pairs of mu * lambda * f0(|u|),   u = t . (p - anchor),

t the surface's tangent there and f0 the smoothed absolute value with slip
threshold eps: f0(y) = -y^3 / (3 eps^2) + y^2 / eps + eps / 3 for y < eps,
y beyond. Below eps a node sticks (a spring of stiffness 2 mu lambda / eps);
beyond, it slides against the constant force mu lambda. lambda and t are
*lagged*: taken at a pose and held while the step is solved, then updated
and the step solved again until they agree (:class:`Lag`, the plant's
consistency loop). Self-contact is frictionless, and so are the pairs of an
obstacle's corner with a body segment (friction acts at body nodes).

The anchor is where the node touched down, carried along as it slides so
that it trails the node by at most eps (:func:`carried_anchor`): the
friction force a committed state holds is still there when the next step
starts. (IPC's anchor is the previous time step's position: in a
quasi-static path that drops every held force at each step and lets the
body creep by up to eps / 2 per step.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..base.errors import SceneError
from ..base.reprs import compact_repr
from .contact import ContactTerm, Entries
from .terms import Term, TermEvaluation

#: the slip threshold eps as a fraction of d_hat: the tangential play a
#: sticking node has, far below the gaps the barrier keeps
SLIP_FRACTION = 1e-2


@dataclass(frozen=True)
class Lag:
    """The friction's lagged data: what a step holds fixed.

    anchor : (b, 2) the boundary nodes' anchors (:func:`carried_anchor`).
    node : (k,) the boundary node (index into ``ContactTerm.boundary.nodes``)
        of each frictional pair; label : (k,) what it touches (0 the
        ground, 1 + i obstacle i).
    tangent : (k, 2) unit tangent of the surface at the pair.
    normal : (k,) the normal force magnitude lambda (force units).
    """

    anchor: np.ndarray
    node: np.ndarray
    label: np.ndarray
    tangent: np.ndarray
    normal: np.ndarray

    __repr__ = compact_repr

    def close_to(self, other: "Lag", rtol: float) -> bool:
        """Whether ``other`` has the same pairs with normal forces within
        ``rtol`` of the largest and tangents within ``rtol``."""
        if not (np.array_equal(self.node, other.node) and np.array_equal(self.label, other.label)):
            return False
        scale = max(float(np.max(self.normal, initial=0.0)), float(np.max(other.normal, initial=0.0)), 1e-300)
        return bool(np.all(np.abs(self.normal - other.normal) <= rtol * scale)
                    and np.all(np.abs(self.tangent - other.tangent) <= rtol))


def lag_at(term: ContactTerm, anchor: np.ndarray, x: np.ndarray) -> Lag:
    """The lagged data at flat pose ``x`` for a step whose boundary nodes
    are anchored at ``anchor`` (b, 2): every boundary node the floor or an
    obstacle edge pushes, with the push's size and the surface's tangent."""
    nodes, labels, tangents, normals = [], [], [], []
    if term.ground is not None:
        _, parts = term.ground_part(x, 1)
        dofs, grad, _ = parts
        nodes.append(np.searchsorted(term.boundary.nodes, dofs[:, 0] // 2))
        labels.append(np.zeros(len(dofs), dtype=np.int64))
        tangents.append(np.tile(term.ground.tangent, (len(dofs), 1)))
        normals.append(np.linalg.norm(grad, axis=1))
    pairs = term.pairs(x)
    body = (pairs.dofs[:, 0] >= 0) & (pairs.label > 0)          # a body node on an obstacle edge
    if body.any():
        _, grad, _ = term.pair_part(pairs, 1)
        push = grad[body, :2]
        size = np.linalg.norm(push, axis=1)
        keep = size > 0
        n = push[keep] / size[keep, None]
        nodes.append(np.searchsorted(term.boundary.nodes, pairs.dofs[body, 0][keep] // 2))
        labels.append(pairs.label[body][keep])
        tangents.append(np.stack([-n[:, 1], n[:, 0]], axis=1))
        normals.append(size[keep])
    cat = (lambda parts, shape, dtype=np.float64:
           np.concatenate(parts) if parts else np.zeros(shape, dtype=dtype))
    return Lag(anchor=np.asarray(anchor, dtype=np.float64), node=cat(nodes, 0, np.int64), label=cat(labels, 0, np.int64),
               tangent=cat(tangents, (0, 2)), normal=cat(normals, 0))


def carried_anchor(term: ContactTerm, lag: Lag, x: np.ndarray) -> np.ndarray:
    """(b, 2) the anchors a state at flat pose ``x``, reached holding
    ``lag``, hands to the next step: a node that touches keeps its slip u
    clipped to [-eps, eps] (so its friction force is unchanged: the smoothed
    force is mu * lambda beyond eps), a node that does not is anchored where
    it is. A node with pairs on two things keeps the last pair's slip."""
    p = term.points(x)
    anchor = p.copy()
    if len(lag.node):
        eps = SLIP_FRACTION * term.distance
        u = np.einsum("ij,ij->i", p[lag.node] - lag.anchor[lag.node], lag.tangent)
        anchor[lag.node] = p[lag.node] - np.clip(u, -eps, eps)[:, None] * lag.tangent
    return anchor


class ContactFrictionTerm(Term):
    """The friction potential D of one step, lagged at ``lag``
    (see the module docstring); ``term`` is the scene's contact term."""

    name = "contact_friction"

    def __init__(self, term: ContactTerm, lag: Lag):
        self.contact, self.lag = term, lag
        self.mu = term.friction
        self.eps = SLIP_FRACTION * term.distance
        self.n_dofs = term.n_dofs
        self._dofs = term.node_dofs[lag.node]                       # (k, 2)

    def slip(self, x: np.ndarray) -> np.ndarray:
        """(k,) the tangential displacement u of every pair from its anchor."""
        p = x[self._dofs]
        return np.einsum("ij,ij->i", p - self.lag.anchor[self.lag.node], self.lag.tangent)

    def forces(self, x: np.ndarray) -> np.ndarray:
        """(k, 2) the friction force on each pair's node (minus D's gradient)."""
        u = self.slip(x)
        y = np.abs(u)
        f1 = np.where(y < self.eps, 2 * y / self.eps - y * y / self.eps ** 2, 1.0)
        return -(self.mu * self.lag.normal * f1 * np.sign(u))[:, None] * self.lag.tangent

    def evaluate(self, x, c, order):
        u = self.slip(x)
        y = np.abs(u)
        stick = y < self.eps
        f0 = np.where(stick, -y ** 3 / (3 * self.eps ** 2) + y * y / self.eps + self.eps / 3, y)
        weight = self.mu * self.lag.normal
        energy = float(np.sum(weight * f0))
        if order == 0:
            return TermEvaluation(energy)
        g = np.zeros(self.n_dofs)
        force = self.forces(x)
        np.add.at(g, self._dofs.ravel(), -force.ravel())
        hessian = {}
        if order == 2:
            f2 = np.where(stick, 2 / self.eps - 2 * y / self.eps ** 2, 0.0)
            local = (weight * f2)[:, None, None] * self.lag.tangent[:, :, None] * self.lag.tangent[:, None, :]
            q = 2
            rows = np.repeat(self._dofs, q, axis=1).ravel()
            cols = np.tile(self._dofs, (1, q)).ravel()
            hessian = {"friction_hess": Entries(rows, cols, local.ravel(), (self.n_dofs, self.n_dofs))}
        return TermEvaluation(energy, g, hessian, float(np.linalg.norm(g)))

    def expression(self, x, c):
        raise SceneError(f"{self.contact.source}: contact.friction: the IPOPT backends solve for the pose at "
                         "the final contractions alone, but with friction at contacts the pose depends on the "
                         "path; use Newton and the gradient loop")
