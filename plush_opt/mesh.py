"""Scene -> Mesh: triangulation (the ``triangle`` package), node lookup of
pins, via points and extra points, and point location for targets."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh with everything the model needs indexed by node.

    Attributes
    ----------
    X : (n_nodes, 2) float64, rest positions.
    triangles : (n_elems, 3) int64, counter-clockwise in ``X``.
    pin_nodes : (n_pins,) int64, sorted unique nodes pinned at rest position
        (``pins.at`` and every node in ``pins.box``).
    tendon_nodes : tuple of (n_via,) int64 arrays, one per scene tendon, in
        scene order, stopper end first.
    target_triangles : (n_targets,) int64, rest triangle holding each target.
    target_beta : (n_targets, 3) float64, barycentric weights in that
        triangle (order of ``triangles[target_triangles[k]]``), summing to 1.
    point_nodes : (n_points,) int64, node of each scene ``points`` entry.
    """

    X: np.ndarray
    triangles: np.ndarray
    pin_nodes: np.ndarray
    tendon_nodes: tuple
    target_triangles: np.ndarray
    target_beta: np.ndarray
    point_nodes: np.ndarray

    @property
    def n_nodes(self) -> int:
        return self.X.shape[0]

    @property
    def n_elems(self) -> int:
        return self.triangles.shape[0]


def build_mesh(scene, max_area: float | None = None) -> Mesh:
    """Mesh a scene. ``max_area`` overrides the scene's (mesh-resolution sweeps)."""
    raise NotImplementedError("mesher under construction")
