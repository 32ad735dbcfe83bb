"""Refuse a scene whose pins leave part of the body free to move rigidly."""

from __future__ import annotations

import numpy as np

from ..base.errors import SceneError
from .mesh import Mesh
from ..io.scene import Scene


def check_pins(scene: Scene, mesh: Mesh) -> None:
    """Refuse a scene with free rigid modes before anything is solved.

    Pieces of the mesh that share an edge move as one elastic body;
    pieces that share only a node hinge about it. A piece is held when
    it has at least two anchored nodes: its own pins, or nodes it shares
    with a piece already held. Every piece must end up held; otherwise
    the Hessian is singular whatever the pose.

    A scene with contact is not refused: the floor and obstacles may hold
    what the pins do not (the solver reports the rigid motions they leave
    free, and fails honestly where nothing holds the body).
    """
    if scene.contact is not None:
        return
    tri = mesh.triangles
    n_elems = tri.shape[0]
    # edge-connected pieces: union-find over elements sharing an edge
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(n_elems), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    same = np.all(edges[1:] == edges[:-1], axis=1)
    parent = np.arange(n_elems)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in zip(owner[:-1][same], owner[1:][same]):
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    piece_of_elem = np.array([find(e) for e in range(n_elems)])
    pieces = np.unique(piece_of_elem)
    nodes_of = {p: set(np.unique(tri[piece_of_elem == p]).tolist()) for p in pieces}
    anchored = set(np.unique(mesh.pin_nodes).tolist())
    held: set[int] = set()
    changed = True
    while changed:
        changed = False
        for p in pieces:
            if p not in held and len(nodes_of[p] & anchored) >= 2:
                held.add(p)
                anchored |= nodes_of[p]
                changed = True
    free = [p for p in pieces if p not in held]
    if free:
        p = free[0]
        count = len(nodes_of[p] & anchored)
        if len(pieces) == 1:
            raise SceneError(
                f"{scene.source}: pins: {count} distinct pinned node(s) leave the body free "
                f"to move rigidly (a singular Hessian); {2 - count} more pin(s) at distinct "
                "points are needed")
        node = min(nodes_of[p])
        raise SceneError(
            f"{scene.source}: pins: the mesh piece of {int(np.sum(piece_of_elem == p))} "
            f"element(s) around node {node} (rest position "
            f"{tuple(np.round(mesh.X[node], 6).tolist())}) is held at {count} distinct "
            f"point(s) (its pins, or nodes shared with a held piece), which leaves it free to "
            f"move rigidly (a singular Hessian); {2 - count} more pin(s) at distinct points "
            "are needed")
