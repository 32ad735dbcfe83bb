"""The control objective O(x) = 1/2 sum_k w_k |y_k(x) - q_k|^2.

A target is a body point given in rest coordinates: it lives in a rest
triangle with barycentric weights beta, so y_k(x) = sum_i beta_k,i x_{e_k,i}
does not depend on where the mesh happens to have nodes. On a P2 mesh the
weights are the six quadratic shape functions at beta (plush_opt/fem/elements.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .elements import with_nodes
from ..base.errors import SceneError
from ..base.reprs import compact_repr


@dataclass(frozen=True)
class Targets:
    """Targets located in a mesh.

    Attributes
    ----------
    triangles : (n_targets,) int, rest triangle of each target.
    nodes : (n_targets, 3) int, that triangle's nodes; (n_targets, 6) on a P2
        mesh (the element's nodes, ``Mesh.elements``).
    beta : (n_targets, 3) barycentric weights in the corner triangle (sum to 1).
    weights : (n_targets, 3 or 6) the nodes' interpolation weights: beta
        itself for P1, the shape functions at beta for P2 (derived).
    to : (n_targets, 2) where each point should go (length units).
    weight : (n_targets,) w_k > 0.
    """

    triangles: np.ndarray
    nodes: np.ndarray
    beta: np.ndarray
    to: np.ndarray
    weight: np.ndarray

    __repr__ = compact_repr      # arrays by shape once there are more than a few targets

    def __post_init__(self):
        width = np.shape(self.nodes)[-1] if np.size(self.nodes) else 3
        for name, dtype, shape in (("triangles", np.int64, (-1,)), ("nodes", np.int64, (-1, width)),
                                   ("beta", np.float64, (-1, 3)), ("to", np.float64, (-1, 2)),
                                   ("weight", np.float64, (-1,))):
            arr = np.ascontiguousarray(np.asarray(getattr(self, name), dtype=dtype).reshape(shape))
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if np.any(self.weight <= 0):
            raise SceneError("targets: every weight must be > 0")
        weights = with_nodes(width).interpolation_weights(self.beta)
        weights.setflags(write=False)
        object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "_selections", {})   # B per n_dofs, built on first use

    @property
    def n_targets(self) -> int:
        return self.triangles.shape[0]

    @classmethod
    def from_mesh(cls, mesh, scene) -> "Targets":
        """The scene's targets, located by the mesher."""
        tri = np.asarray(mesh.target_triangles, dtype=np.int64)
        return cls(tri, mesh.elements[tri], mesh.target_beta,
                   [t.to for t in scene.targets] or np.zeros((0, 2)),
                   [t.weight for t in scene.targets])

    @classmethod
    def at_points(cls, mesh, at, to, weight=None) -> "Targets":
        """Targets for body points ``at`` (rest coordinates, (k, 2)) going
        to ``to`` ((k, 2)); raises SceneError for a point off the body."""
        at = np.asarray(at, dtype=np.float64).reshape(-1, 2)
        tri, beta = mesh.locate(at)
        bad = np.flatnonzero(tri < 0)
        if bad.size:
            k = int(bad[0])
            raise SceneError(f"targets[{k}].at: point ({at[k, 0]:g}, {at[k, 1]:g}) lies outside the body")
        weight = np.ones(len(at)) if weight is None else weight
        return cls(tri, mesh.elements[tri], beta, to, weight)

    @classmethod
    def empty(cls) -> "Targets":
        return cls(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0))

    def replace_to(self, to) -> "Targets":
        return Targets(self.triangles, self.nodes, self.beta, to, self.weight)

    def selection(self, n_dofs: int) -> sp.csr_matrix:
        """B = dy/dx, sparse (2 n_targets, n_dofs): y.ravel() = B x."""
        if n_dofs not in self._selections:
            self._selections[n_dofs] = self._build_selection(n_dofs)
        return self._selections[n_dofs]

    def _build_selection(self, n_dofs: int) -> sp.csr_matrix:
        k, width = self.nodes.shape
        rows = np.stack([np.repeat(2 * np.arange(k), width),
                         np.repeat(2 * np.arange(k) + 1, width)], 1)
        cols = np.stack([2 * self.nodes.ravel(), 2 * self.nodes.ravel() + 1], 1)
        vals = np.stack([self.weights.ravel(), self.weights.ravel()], 1)
        return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(2 * k, n_dofs))

    def y(self, x) -> np.ndarray:
        """Current positions of the target points, (n_targets, 2)."""
        nodes = np.asarray(x, dtype=np.float64).reshape(-1, 2)
        return np.einsum("kj,kjd->kd", self.weights, nodes[self.nodes])

    def residual(self, x) -> np.ndarray:
        """sqrt(w_k) (y_k - q_k), flat (2 n_targets,)."""
        return (np.sqrt(self.weight)[:, None] * (self.y(x) - self.to)).reshape(-1)

    def value(self, x) -> float:
        r = self.residual(x)
        return 0.5 * float(r @ r)

    def roundoff(self, x) -> float:
        """How far from O(x) a float64 evaluation may land (length^2): each
        coordinate of y_k - q_k carries eps (|y_k| + |q_k|) of round-off (the
        points are held in absolute coordinates), to first order
        sum_k w_k |y_k - q_k| . eps (|y_k| + |q_k|), and the sum of the
        2 n_targets squares eps (2 n_targets + 1) O. Two values of O closer
        than this cannot say which pose is nearer the targets."""
        y = self.y(x)
        d = self.weight[:, None] * np.abs(y - self.to) * (np.abs(y) + np.abs(self.to))
        return float(np.finfo(np.float64).eps * (d.sum() + (2 * self.n_targets + 1) * self.value(x)))

    def gradient(self, x) -> np.ndarray:
        """dO/dx, flat (n_dofs,)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        d = self.weight[:, None] * (self.y(x) - self.to)          # (k, 2)
        g = np.zeros(x.size)
        contrib = self.weights[:, :, None] * d[:, None, :]         # (k, 3 | 6, 2)
        np.add.at(g.reshape(-1, 2), self.nodes, contrib)
        return g

    def errors(self, x) -> np.ndarray:
        """|y_k - q_k| per target, (n_targets,)."""
        return np.linalg.norm(self.y(x) - self.to, axis=1)

    def rms_error(self, x) -> float:
        e = self.errors(x)
        return float(np.sqrt(np.mean(e**2))) if e.size else 0.0
