"""What a result reports of contact (docs/problem-format.md, "Contact"):
the section as used, and at a pose the smallest gap, the total force and
the force at every node that feels one."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from . import contact_geometry as geo
from .contact import ContactTerm
from .contact_friction import SLIP_FRACTION, ContactFrictionTerm


def section(term: ContactTerm) -> dict:
    """The result's ``model.contact``: the section as used (kappa as
    chosen, with ``stiffness_chosen`` saying so)."""
    g = term.ground
    return {
        "ground": None if g is None else {"height": float(g.height), "slope": float(g.slope)},
        "obstacles": [{"name": o.name, "outline": o.outline.tolist()} for o in term.obstacles],
        "self": bool(term.self_contact), "distance": float(term.distance),
        "stiffness": float(term.stiffness), "stiffness_chosen": bool(term.stiffness_chosen),
        "friction": float(term.friction),
        # (an extra) the smoothed static friction's slip threshold eps (length)
        **({"slip_threshold": SLIP_FRACTION * float(term.distance)} if term.friction > 0 else {}),
    }


def report(term: ContactTerm, x: np.ndarray, friction: ContactFrictionTerm | None = None) -> dict:
    """The result's top-level ``contact`` block at flat pose ``x``:
    ``min_gap``, ``total_force`` (the sum of every contact force on the
    body), ``total_by`` (that sum per thing touched: "ground", an
    obstacle's name, "self"), ``patches`` (:func:`patches`: per finger)
    and ``nodes`` (:func:`node_forces`; with ``friction``, the lagged
    friction of the step that reached ``x``)."""
    nodes = node_forces(term, x, friction)
    total = np.zeros(2)
    by: dict[str, np.ndarray] = {}
    for entry in nodes:
        force = np.asarray(entry["normal_force"]) + np.asarray(entry["friction_force"])
        total += force
        by[entry["with"]] = by.get(entry["with"], np.zeros(2)) + force
    gap = min_gap(term, x)
    return {"min_gap": gap if np.isfinite(gap) else None,
            "total_force": [float(total[0]), float(total[1])],
            # (an extra) the same sum per thing touched: the grip on an object
            "total_by": {name: [float(f[0]), float(f[1])] for name, f in sorted(by.items())},
            "patches": patches(term, x, nodes),
            "nodes": nodes}


def patches(term: ContactTerm, x: np.ndarray, nodes: list[dict]) -> list[dict]:
    """The contact forces per patch: each connected stretch of the body's
    boundary whose nodes all touch one thing, as a finger holding an
    object is one patch. Per patch: ``with``, ``nodes`` (its mesh nodes in
    order of index), ``force`` [fx, fy] (normal plus friction, summed) and
    ``at`` [x, y] (the force-weighted mean position of its nodes at ``x``).
    ``nodes`` is :func:`node_forces` at ``x``; patches are sorted by thing,
    then by their first node."""
    pos = x.reshape(-1, 2)
    segments = term.boundary.segments
    found = []
    for label in sorted({e["with"] for e in nodes}):
        touched = np.array(sorted(e["node"] for e in nodes if e["with"] == label))
        force = np.zeros((len(touched), 2))
        for e in nodes:
            if e["with"] == label:
                force[np.searchsorted(touched, e["node"])] += np.add(e["normal_force"], e["friction_force"])
        # the boundary segments whose both ends touch this thing join them into patches
        ends = np.isin(segments, touched).all(axis=1)
        a, b = np.searchsorted(touched, segments[ends].T)
        graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(len(touched),) * 2)
        _, patch = connected_components(graph, directed=False)
        for k in np.unique(patch):
            members = np.flatnonzero(patch == k)
            f = force[members].sum(axis=0)
            size = np.linalg.norm(force[members], axis=1)
            where = pos[touched[members]]
            at = (size @ where) / size.sum() if size.sum() > 0 else where.mean(axis=0)
            found.append({"with": label, "nodes": [int(n) for n in touched[members]],
                          "force": [float(f[0]), float(f[1])], "at": [float(at[0]), float(at[1])]})
    return sorted(found, key=lambda p: (p["with"], p["nodes"][0]))


def node_forces(term: ContactTerm, x: np.ndarray, friction: ContactFrictionTerm | None = None) -> list[dict]:
    """The contact forces at flat pose ``x``, per (node, thing touched):
    ``node``, ``gap`` (the smallest gap of its pairs with that thing),
    ``with`` ("ground", an obstacle's name or "self"), ``normal_force``
    [fx, fy] (minus the barrier's gradient at the node) and
    ``friction_force`` [fx, fy] (minus the gradient of ``friction``, the
    lagged friction potential; [0, 0] without it)."""
    out: dict[tuple[int, str], list] = {}
    names = ["self"] + [o.name for o in term.obstacles]

    def add(node, label, force, gap, kind=0):
        entry = out.setdefault((int(node), label), [np.zeros(2), np.inf, np.zeros(2)])
        entry[2 * kind] += force
        if kind == 0:
            entry[1] = min(entry[1], gap)

    if term.ground is not None:
        _, parts = term.ground_part(x, 1)
        dofs, grad, _ = parts
        gaps = term.ground_gaps(x)
        for dof, gr in zip(dofs, grad):
            k = int(np.searchsorted(term.boundary.nodes, dof[0] // 2))
            add(dof[0] // 2, "ground", -gr, gaps[k])
    pairs = term.pairs(x)
    if len(pairs.weight):
        s, _, _ = geo.point_segment_sq(pairs.P, pairs.A, pairs.B, order=0)
        _, grad, _ = term.pair_part(pairs, 1)
        for dofs, gr, label, sk in zip(pairs.dofs, grad, pairs.label, s):
            for q in range(3):
                if dofs[2 * q] >= 0:
                    add(dofs[2 * q] // 2, names[label], -gr[2 * q:2 * q + 2], float(np.sqrt(sk)))
    if friction is not None:
        ground_or = ["ground"] + [o.name for o in term.obstacles]
        for k, force in enumerate(friction.forces(x)):
            add(term.boundary.nodes[friction.lag.node[k]], ground_or[friction.lag.label[k]], force, np.inf, 1)
    return [{"node": node, "gap": float(gap) if np.isfinite(gap) else None, "with": label,
             "normal_force": [float(f[0]), float(f[1])], "friction_force": [float(t[0]), float(t[1])]}
            for (node, label), (f, gap, t) in sorted(out.items()) if np.any(f != 0) or np.any(t != 0)]

#: how far (in d_hat) :func:`min_gap` looks for the nearest pair when no floor bounds it
GAP_SEARCH = 4.0


def min_gap(term: ContactTerm, x: np.ndarray) -> float:
    """The smallest gap of any pair at flat pose ``x``: the floor's, or a
    closer obstacle or self pair (searched within the floor's gap, or
    :data:`GAP_SEARCH` d_hat without a floor); inf when nothing is that near."""
    floor = float(np.min(term.ground_gaps(x))) if term.ground is not None else np.inf
    gap = floor
    if term.obstacles or term.self_contact:
        reach = max(floor, term.distance) if np.isfinite(floor) else GAP_SEARCH * term.distance
        pairs = term.pairs(x, radius=reach)
        if len(pairs.weight):
            s, _, _ = geo.point_segment_sq(pairs.P, pairs.A, pairs.B, order=0)
            gap = min(gap, float(np.sqrt(np.min(s))))
    return float(gap)
