"""Carrying a pose from one mesh level to another, and following its
branch of equilibria there (the levels of ``--accuracy``, docs/accuracy.md).

:func:`transfer_pose` carries a pose from one mesh of a scene to another
(interpolation of the displacement); :func:`carried_start` makes that an
admissible start; :func:`solve_on_branch` solves from it without leaving
its branch: a level that has no equilibrium near the branch there says so
after a few dozen Newton steps instead of reaching another branch by
continuation; :func:`relieved_equilibrium` reaches the equilibrium of a
start's state by a Newton homotopy where Newton alone walks into another.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..base.geometry import locate_in_triangles
from ..fem.mesh import Mesh
from ..fem.model import HeldTerms, Model
from ..fem.terms import ForceTerm
from .equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium

#: Newton iterations a level's solve at a returned contraction may take
#: from a pose of the answer's branch carried to its mesh: such a start is
#: within Newton's local reach of the level's equilibrium on that branch,
#: which it reaches in a few dozen steps where it exists; a level whose
#: branch ends before that contraction (a coarse or locking level folding
#: earlier) would otherwise run to the 500-iteration limit and then to a
#: pose of another branch by continuation, which measures nothing.
BRANCH_ITERATIONS = 60


#: ... unless by then it has cut its residual by this factor: then it is on
#: its way to that equilibrium, slowly (a fine level near a fold, from a
#: coarser pose), and goes on to the options' own iteration limit. Newton
#: that has left the branch wanders at a residual of the order of its
#: start's (the hexapod's P2 levels: 0.9 of the force scale after 60 steps).
BRANCH_PROGRESS = 0.1


#: ... or if the median node has moved at most this fraction of the mesh's
#: diameter from the start: a fine level converging slowly from a coarser
#: pose, a few nodes at a contact still settling (gripper_object's 67,313
#: P2 nodes at its answer for TOL 0.05: the median node 0.012% of the
#: diameter after 60 steps, converged after 67). Newton that has left the
#: branch moves the body (the hexapod's folding legs above: about 1%).
#: docs/notes/accuracy-measurements.md, 2026-12-06.
BRANCH_DRIFT = 0.001


#: The status of a solve on a branch stopped where its pose creases
#: (:func:`solve_on_branch`'s ``creases``; then ": " and where).
CREASED_ON_THE_WAY = "creased on the way"


#: Equal steps in which :func:`relieved_equilibrium` relieves its start's
#: residual, and how often a step that fails may be halved.
RELIEF_STEPS = 8
RELIEF_HALVINGS = 4


def branch_options(options: EquilibriumOptions, iterations: int | None = None) -> EquilibriumOptions:
    """``options`` for following a branch from a pose on it: at most
    ``iterations`` (default :data:`BRANCH_ITERATIONS`) Newton iterations,
    no continuation."""
    cap = BRANCH_ITERATIONS if iterations is None else iterations
    return dataclasses.replace(options, continuation=0, max_iterations=max(min(options.max_iterations, cap), 1))


def solve_on_branch(model: Model, contraction, x0, options: EquilibriumOptions, creases=None) -> Equilibrium:
    """The equilibrium at ``contraction`` on the branch of the admissible
    start ``x0`` (a pose of that branch carried over): Newton, no
    continuation, :data:`BRANCH_ITERATIONS` iterations and, where those cut
    the residual by :data:`BRANCH_PROGRESS` or moved the median node by at
    most :data:`BRANCH_DRIFT` of the mesh's diameter, on from there up to
    ``options.max_iterations`` in all. Not converged: the model has no
    equilibrium near that branch there. ``creases(x)``, if given (where
    the flat pose x creases, in words, or None): Newton from an ``x0``
    that does not crease does not go on where its pose after those
    iterations creases (status :data:`CREASED_ON_THE_WAY`, then where): it
    is on its way to a pose folded through itself (the crescent's P2 level
    of 79,625 nodes from a 20,517-node answer: 84 iterations, 288 s, to a
    crease), where the path from rest decides instead."""
    first = solve_equilibrium(model, contraction, x0, branch_options(options))
    if first.converged or first.iterations < BRANCH_ITERATIONS:
        return first
    cut = first.residual_norm <= BRANCH_PROGRESS * np.linalg.norm(model.evaluate(x0, contraction, 1).gradient)
    moved = np.linalg.norm((first.x - np.asarray(x0, dtype=np.float64).reshape(-1)).reshape(-1, 2), axis=1)
    if not (cut or float(np.median(moved)) <= BRANCH_DRIFT * model.mesh.diameter):
        return first
    where = None if creases is None or creases(np.asarray(x0, dtype=np.float64).reshape(-1)) else creases(first.x)
    if where is not None:
        return dataclasses.replace(first, status=f"{CREASED_ON_THE_WAY}: {where}")
    rest = dataclasses.replace(options, continuation=0, max_iterations=max(options.max_iterations - first.iterations, 1))
    then = solve_equilibrium(model, contraction, first.x, rest)
    return dataclasses.replace(then, iterations=first.iterations + then.iterations)


def transfer_pose(mesh_from: Mesh, x_from, mesh_to: Mesh) -> np.ndarray:
    """The pose ``x_from`` (flat, on ``mesh_from``) carried to ``mesh_to``:
    each rest node of ``mesh_to`` moves with the displacement interpolated
    in the rest triangle of ``mesh_from`` that holds it. Nodes outside
    ``mesh_from`` (round-off at curved boundaries) take the nearest node's
    displacement. Returns a flat (2 n_nodes,) pose on ``mesh_to``."""
    u = np.asarray(x_from, dtype=np.float64).reshape(-1, 2) - mesh_from.X
    tri, beta = mesh_from.locate(mesh_to.X, tol=1e-6 * mesh_from.diameter)
    out = np.empty_like(mesh_to.X)
    inside = tri >= 0
    nodes = mesh_from.elements[tri[inside]]          # P2: through the six shape functions
    weights = mesh_from.element.interpolation_weights(beta[inside])
    out[inside] = np.einsum("kj,kjd->kd", weights, u[nodes])
    if not inside.all():
        from scipy.spatial import cKDTree
        _, near = cKDTree(mesh_from.X).query(mesh_to.X[~inside])
        out[~inside] = u[near]
    return (mesh_to.X + out).reshape(-1)


def transfer_pose_piecewise_linear(mesh_from: Mesh, x_from, mesh_to: Mesh) -> np.ndarray:
    """:func:`transfer_pose` with the displacement interpolated linearly in
    the triangles of ``mesh_from``'s nodes (a P2 element split in four at
    its midside nodes): a strongly curved quadratic map can invert the
    triangles of a finer mesh inside it, and its edges bulge beyond the
    straight segments between boundary nodes that contact sees (into an
    obstacle they keep clear of), where linear pieces through the same
    nodes do neither. The same as :func:`transfer_pose` for a P1
    ``mesh_from``. Returns a flat (2 n_nodes,) pose on ``mesh_to``."""
    e = mesh_from.elements
    if e.shape[1] == 3:
        return transfer_pose(mesh_from, x_from, mesh_to)
    a, b, c, ab, bc, ca = e.T
    pieces = np.concatenate([np.c_[a, ab, ca], np.c_[ab, b, bc], np.c_[ca, bc, c], np.c_[ab, bc, ca]])
    u = np.asarray(x_from, dtype=np.float64).reshape(-1, 2) - mesh_from.X
    tri, beta = locate_in_triangles(mesh_from.X[pieces], mesh_to.X, 1e-6 * mesh_from.diameter)
    out = np.empty_like(mesh_to.X)
    inside = tri >= 0
    out[inside] = np.einsum("kj,kjd->kd", beta[inside], u[pieces[tri[inside]]])
    if not inside.all():
        from scipy.spatial import cKDTree
        _, near = cKDTree(mesh_from.X).query(mesh_to.X[~inside])
        out[~inside] = u[near]
    return (mesh_to.X + out).reshape(-1)


def carried_start(model: Model, sources) -> np.ndarray | None:
    """An admissible start on ``model``'s mesh from poses of the same
    branch: ``sources``, (mesh, flat pose) pairs, tried in order (the
    finest first), each by :func:`transfer_pose` and, where that is not
    admissible (an element inverted, or an edge across a contact), with
    the displacement interpolated linearly
    (:func:`transfer_pose_piecewise_linear`); None if none is admissible
    (a strongly curved P2 element near a contact can have inverted pieces:
    a coarser or P1 pose then serves)."""
    for mesh_from, x_from in sources:
        for carry in (transfer_pose, transfer_pose_piecewise_linear):
            x0 = carry(mesh_from, x_from, model.mesh)
            if model.admissible(x0):
                return x0
    return None


class WithForce(HeldTerms):
    """``model``'s terms plus a constant ``force`` (a :class:`ForceTerm`)."""

    def __init__(self, model: Model, force: np.ndarray):
        super().__init__(model, model.terms + (ForceTerm(force),), model.hessian_layout, model.factorizer)


def relieved_equilibrium(model: Model, contraction, x0, options: EquilibriumOptions,
                         steps: int = RELIEF_STEPS) -> Equilibrium:
    """The equilibrium at ``contraction`` in the state of the admissible
    pose ``x0`` (one carried from another mesh), by a Newton homotopy:
    ``x0`` balances the model plus the force r0 = grad E(x0) held fixed;
    that force is taken away in ``steps`` equal steps (a step Newton does
    not converge in is halved, at most :data:`RELIEF_HALVINGS` times),
    each equilibrium solved from the one before (Newton, ``options``
    without continuation: the first step can take over a hundred
    iterations, the others a few), the last the model's own.
    Newton from a start out of balance can walk from one stable state into
    another (several can hold an object at the same contractions:
    docs/notes/accuracy-measurements.md, gripper_object's two states);
    here the pose moves with the force, continuously while the state
    lasts. Where a step fails (the state ends on the way: a limit point)
    the result is that step's, not converged, its status saying how much
    of the residual was still held."""
    c = np.asarray(contraction, dtype=np.float64)
    held = dataclasses.replace(options, continuation=0)
    x = np.asarray(x0, dtype=np.float64).reshape(-1)
    r0 = model.evaluate(x, c, 1).gradient
    share, step, halvings, iterations = 1.0, 1.0 / steps, 0, 0
    while True:
        trial = max(share - step, 0.0)
        eq = solve_equilibrium(model if trial == 0.0 else WithForce(model, trial * r0), c, x, held)
        iterations += eq.iterations
        if eq.converged:
            share, x = trial, eq.x
            if share == 0.0:
                return dataclasses.replace(eq, iterations=iterations)
            continue
        if halvings == RELIEF_HALVINGS:
            why = f"homotopy stopped with {share:.3g} of the start's residual held: {eq.status}"
            return dataclasses.replace(eq, converged=False, status=why, iterations=iterations)
        step, halvings = step / 2.0, halvings + 1
