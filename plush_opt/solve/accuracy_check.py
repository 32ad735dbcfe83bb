"""The error estimate of ``--accuracy`` at other contractions than the
sweep's: at the pose a solve or a control run returns.

:func:`~plush_opt.solve.accuracy.choose_levels` estimates each mesh level's
error at a few probe contractions (the file's, each free winch alone at
mid-range). The pose a control run returns is at other contractions, where
the error can be larger. :func:`bounds_at` solves every level of the sweep
once more at those contractions (each from its own pose at the nearest probe
contraction) and estimates again, with the same rule
(:func:`~plush_opt.solve.accuracy.estimate_levels`, then the bounds through
other levels); :func:`cheapest_meeting` is the level to move to when the
mesh used does not meet the tolerance there. A P1 answer is checked against
P2 levels solved there (:func:`seed_level` starts them from the answer,
:func:`bound_through` bounds the answer through their estimates): P1
levels can agree with each other far from the converged answer.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ..base.errors import SceneError
from ..fem.contact_boundary import boundary_of, crossings, self_crossing
from ..fem.model import build_model
from ..fem.objective import Targets
from ..io.scene import Scene
from .accuracy import (LEVEL_OPTIONS, Level, Resolution, _solve_level, carried_start, equilibrium_at,
                       estimate_each_element, one_pose, solve_on_branch)
from .accuracy_carry import CREASED_ON_THE_WAY
from .equilibrium import EquilibriumOptions, continuation
from .result_file import crossing_of

#: Continuation steps from rest to a returned contraction where the pose
#: carried from the answer creases (:func:`_unfolded`).
UNFOLD_STEPS = 4


def bounds_at(scene: Scene, levels: list[Level], probes, contraction, points,
              options: EquilibriumOptions | None = None, start=None, progress=None,
              used: int | None = None) -> list[Level]:
    """The sweep's ``levels`` (solved at the contractions ``probes``, (m,
    n_winches)) solved at ``contraction`` ((n_winches,)) and estimated
    there: new :class:`Level` objects (same meshes, one pose each, ``y`` of
    shape (1, k, 2) at ``points``, (k, 2) rest coordinates), in the same
    order, with their ``estimate`` and ``bound`` at that contraction.

    With ``start`` (a (mesh, flat pose) at ``contraction``, e.g. the
    solve's answer) each level follows the answer's branch (:func:`follow`):
    Newton from the finest pose solved there so far (the answer first),
    carried to the level's mesh, so every level on the same branch. A level
    that has no equilibrium near that branch there (its Newton does not
    converge within :data:`~plush_opt.solve.accuracy_carry.BRANCH_ITERATIONS`: a coarse level, or one that
    locks, whose branch ends earlier) is not on the branch
    (:attr:`~plush_opt.solve.accuracy_estimate.Level.on_branch`: ``y``
    NaN, its pose None) and takes no part in the estimates. Without
    ``start`` each level is solved from its pose at the nearest probe
    contraction, by continuation where that fails, and a level whose
    equilibrium cannot be certified is a :class:`SceneError`. At a probe
    contraction itself the sweep's poses are used (nothing solved) unless
    ``start`` is another pose than the sweep's on its mesh there. ``used``
    (an index in ``levels``: the level the answer is on): the levels are
    solved cheapest first (:attr:`Level.cost`), and once a level :func:`finer`
    than it is not on the branch, the answer's branch is one of the
    coarser levels alone, and the dearer levels are not solved (off the
    branch too); nor are they once the pose of that level, or of one finer,
    crosses itself there (:func:`fold_at`: no level resolves a fold).
    ``progress(line)``, if given, hears of each level solved (its nodes,
    wall seconds, Newton iterations and how it was started)."""
    options = options or LEVEL_OPTIONS
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    probes = np.asarray(probes, dtype=np.float64).reshape(-1, c.size)
    gap = np.max(np.abs(probes - c), axis=1)
    near = int(np.argmin(gap))
    here = [] if start is None else [start]
    refuted = None                    # a level finer than the one in use that cannot follow the answer
    folded = False                    # ... or one (or the one in use) whose pose crosses itself
    # a probe contraction: the sweep's poses serve, unless the answer is another pose than the sweep's
    # on its own level (solved again from elsewhere, e.g. from rest: possibly another branch)
    if gap[near] == 0.0 and (start is None or _sweep_has(levels, start, near)):
        return estimate_each_element([one_pose(lv, lv.poses[near], lv.y[near:near + 1]) for lv in levels])
    out = [None] * len(levels)
    for i in sorted(range(len(levels)), key=lambda i: levels[i].cost):
        lv = levels[i]
        if refuted is not None or folded:   # the coarse level's branch alone, or a fold: nothing to estimate
            out[i] = one_pose(lv, None, np.full((1, len(points), 2), np.nan))
            continue
        t0 = time.perf_counter()
        model = lv.model if lv.model is not None else \
            build_model(dataclasses.replace(scene, element=lv.element), lv.mesh)
        if here:                      # follow the answer's branch: Newton from the finest pose there
            sources = sorted(here, key=lambda m: -m[0].n_nodes)
            if start is not None and start[0] is lv.mesh:
                sources.insert(0, start)
            src = sources[0]
            how = "from the answer" if src is start else f"from the {src[0].n_nodes:,}-node pose there"
            eq = follow(model, c, sources, options, _crease_watch(scene, model))
        carried = here and eq is not None and src[0] is not lv.mesh     # (not the answer on its own mesh)
        if not here or eq is None:    # nothing to follow: from the probe's pose, by continuation where that fails
            eq, how = equilibrium_at(model, c, lv.poses[near], options), "from the nearest probe's pose"
            if not eq.converged:
                raise SceneError(f"{scene.source}: accuracy: no certified equilibrium at contraction {c.tolist()} "
                                 f"on the {lv.element} mesh of {lv.mesh.n_nodes} nodes: {eq.status}")
        crossing = crossings(model, [eq.x], creases_only=True) if eq.converged else ()     # (fold_at reads it)
        eq, how, crossing = _unfolded(model, eq, how, crossing, options) if carried else (eq, how, crossing)
        refuted = lv if not eq.converged and used is not None and finer(lv, levels[used]) else refuted
        if progress is not None:
            progress(f"accuracy: {lv.element} level of {lv.mesh.n_nodes:,} nodes at the returned contractions "
                     + _said(eq, how, time.perf_counter() - t0, refuted is not None))
        if eq.converged:
            here.append((lv.mesh, eq.x))
            folded = used is not None and (i == used or finer(lv, levels[used])) and \
                any(where is not None for where in crossing)
        y = Targets.at_points(lv.mesh, points, points).y(eq.x)[None] if eq.converged else \
            np.full((1, len(points), 2), np.nan)
        out[i] = dataclasses.replace(one_pose(lv, eq.x if eq.converged else None, y), crossing=crossing)
    return estimate_each_element(out)


def _crease_watch(scene: Scene, model):
    """``creases(x)`` for :func:`follow` on ``model`` (where the flat pose
    x creases, or None), or None in a scene with self-contact (its poses
    never cross)."""
    if scene.contact is not None and scene.contact.self_contact:
        return None
    return lambda x: crossing_of(model, x, creases_only=True)


def _unfolded(model, eq, how: str, crossing, options):
    """A level's pose at the answer's contractions that creases where it was
    carried from a pose that does not (Newton from a carried start can jump
    to a creased branch: the body may pass through itself, and a pose
    folded through itself is an equilibrium too), or whose Newton stopped
    creased on the way there (:data:`~plush_opt.solve.accuracy_carry.CREASED_ON_THE_WAY`):
    the pose reached from rest by continuation in the contraction instead,
    as the answer was reached through the control run's iterates, where it
    does not crease. Returns (pose, how it was solved, its crossings): those
    given where they do not crease (where Newton stopped on the way, the
    path's creased pose: the fold is real)."""
    on_the_way = not eq.converged and eq.status.startswith(CREASED_ON_THE_WAY)
    if not (on_the_way or any(where is not None for where in crossing)):
        return eq, how, crossing
    said = f"Newton {how} creased on the way" if on_the_way else f"the pose {how} creases"
    steps = dataclasses.replace(options, continuation=UNFOLD_STEPS)
    again = continuation(model, dataclasses.replace(eq, status=said), None, steps)
    if not again.converged:
        return eq, how, crossing
    found = crossings(model, [again.x], creases_only=True)
    if not any(where is not None for where in found):
        return again, f"by continuation from rest ({said}: another branch)", found
    # a crease on the path from rest too: the fold is real; where Newton stopped on the way to one, the
    # path's pose shows it
    return (again, f"by continuation from rest ({said}, and so does the path)", found) if on_the_way else \
        (eq, how, crossing)


def _said(eq, how: str, seconds: float, refuted: bool) -> str:
    """What :func:`bounds_at` says of a level solved at the returned contractions."""
    if eq.converged:
        return f"solved {how} in {seconds:.1f} s ({eq.iterations} Newton iterations)"
    return (f"not on the answer's branch: Newton {how} did not converge in {eq.iterations} iterations "
            f"({seconds:.1f} s; {eq.status}): left out of the estimate there"
            + ("" if not refuted else "; finer than the level in use, so the answer's branch does not "
               "survive refinement: the dearer levels are not solved"))


def fold_at(scene: Scene, levels: list[Level], used: Level) -> dict | None:
    """Where the pose of the cheapest of ``levels`` (as :func:`bounds_at`
    returns them: one pose each) that is ``used`` or :func:`finer` than it
    creases: ``{"element", "nodes", "where"}``, or None (none does, or the
    scene has self-contact and its poses never cross). A body folded
    through itself in a crease has no converged answer there (a crease has
    no length scale: each finer mesh folds further), so no estimate made
    there means anything; an overlap (:data:`~plush_opt.fem.contact_boundary.CREASE_SPAN`)
    converges like any pose and is no fold."""
    for lv in sorted(levels, key=lambda lv: lv.cost):
        if lv.poses[0] is None or not (lv is used or finer(lv, used)):
            continue
        # (as bounds_at found it; levels it did not solve there, unchecked, are checked here)
        where = lv.crossing[0] if lv.crossing else _crossing(scene, lv.mesh, lv.poses[0])
        if where is not None:
            return {"element": lv.element, "nodes": lv.mesh.n_nodes, "where": where}
    return None


def _crossing(scene: Scene, mesh, x) -> str | None:
    """Where the pose ``x`` on ``mesh`` creases, or None (also in a scene
    with self-contact, whose poses never cross): what
    :func:`~plush_opt.fem.contact_boundary.crossings` says of a model, for a
    level that keeps none."""
    if scene.contact is not None and scene.contact.self_contact:
        return None
    return self_crossing(boundary_of(mesh), x, creases_only=True)


def _sweep_has(levels: list[Level], start, j: int) -> bool:
    """Whether the answer ``start`` = (mesh, flat pose) is the pose the sweep
    solved at its probe contraction ``j`` on that mesh (to solver tolerance:
    1e-6 of the mesh's diameter)."""
    mesh, x = start
    for lv in levels:
        if lv.mesh is mesh and lv.poses[j] is not None:
            return float(np.max(np.abs(np.asarray(lv.poses[j]) - x))) <= 1e-6 * mesh.diameter
    return False


def finer(lv: Level, than: Level) -> bool:
    """Whether ``lv`` resolves more than ``than``: more nodes, or P2 on as
    many nodes as a P1 level."""
    n, m = lv.mesh.n_nodes, than.mesh.n_nodes
    return n > m or (n == m and lv.element == "P2" and than.element == "P1")


def follow(model, contraction, sources, options: EquilibriumOptions | None = None, creases=None):
    """The equilibrium of ``model`` at ``contraction`` on the branch of the
    poses ``sources`` ((mesh, flat pose) pairs at ``contraction``, the
    finest first): Newton from the first of them carried to the model's
    mesh admissibly (:func:`~plush_opt.solve.accuracy_carry.carried_start`),
    :func:`~plush_opt.solve.accuracy_carry.solve_on_branch`. Its ``converged`` is False where the level has no
    equilibrium near that branch there; None where none carries over
    admissibly (that says nothing of the branch). ``creases``: the watch
    of :func:`~plush_opt.solve.accuracy_carry.solve_on_branch`."""
    x0 = carried_start(model, sources)
    if x0 is None:
        return None
    return solve_on_branch(model, contraction, x0, options or LEVEL_OPTIONS, creases)


#: The element whose levels check a P1 answer: P1 triangles lock in the
#: bending of thin parts, and near a fold its levels can agree with each
#: other (and with a coarse P2 level) long before they are right; a P2 level
#: with an estimate of its own shows whether they are.
CHECK_ELEMENT = "P2"


def seed_level(scene: Scene, used: Level, contraction, resolution: Resolution, points,
               options: EquilibriumOptions | None = None) -> Level:
    """The level ``resolution`` of :data:`CHECK_ELEMENT` solved at
    ``contraction`` ((n_winches,)), from the pose of ``used`` there (a level
    as :func:`bounds_at` returns it) carried over, so on the same branch of
    equilibria (:func:`~plush_opt.solve.accuracy_carry.solve_on_branch`); its cost
    timed as a sweep's level's. A level with no equilibrium near that pose
    is a :class:`SceneError`."""
    c = np.asarray(contraction, dtype=np.float64).reshape(1, -1)
    level = _solve_level(dataclasses.replace(scene, element=CHECK_ELEMENT), resolution, c, points, used,
                         options or LEVEL_OPTIONS, follow=True)
    if not level.on_branch:
        raise SceneError(f"{scene.source}: accuracy: the {CHECK_ELEMENT} mesh of {level.mesh.n_nodes} nodes has "
                         f"no equilibrium near the answer at contraction {c[0].tolist()}")
    return level


def bound_through(used: Level, others: list[Level]) -> tuple[float | None, Level | None]:
    """The least ``max |y_used - y_M| + estimate_M`` over the levels ``M`` of
    ``others`` with a confirmed finite estimate (all solved at the same
    single contraction as ``used``): a bound of ``used``'s error that does
    not rest on its own levels' differences. (None, None) without such a level."""
    best = (None, None)
    for m in others:
        if m.confirmed and m.estimate is not None and math.isfinite(m.estimate):
            b = m.estimate + float(np.max(np.linalg.norm(used.y[-1] - m.y[-1], axis=-1)))
            if best[0] is None or b < best[0]:
                best = (b, m)
    return best
