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
from ..fem.model import build_model
from ..fem.objective import Targets
from ..io.scene import Scene
from .accuracy import (LEVEL_OPTIONS, Level, Resolution, _solve_level, bound_errors, equilibrium_at,
                       estimate_levels, transfer_pose)
from .equilibrium import EquilibriumOptions, solve_equilibrium


def bounds_at(scene: Scene, levels: list[Level], probes, contraction, points,
              options: EquilibriumOptions | None = None, start=None, progress=None) -> list[Level]:
    """The sweep's ``levels`` (solved at the contractions ``probes``, (m,
    n_winches)) solved at ``contraction`` ((n_winches,)), each from
    ``start`` (a (mesh, flat pose) at ``contraction``, e.g. the solve's
    answer) if given, or from the finest pose solved there so far if that
    is finer (carried to the level's mesh: closer to its answer than a
    coarse one, and every level on the same branch as ``start``), if that
    converges, else from its pose at the nearest
    probe contraction, by continuation where that fails (at a probe
    contraction itself: the sweep's poses, nothing solved), and estimated there: new
    :class:`Level` objects (same meshes, one pose
    each, ``y`` of shape (1, k, 2) at ``points``, (k, 2) rest coordinates),
    in the same order, with their ``estimate`` and ``bound`` at that
    contraction. A level whose equilibrium there cannot be certified is a
    :class:`SceneError`. ``progress(line)``, if given, hears of each level
    solved (its nodes, wall seconds, and how it was started)."""
    options = options or LEVEL_OPTIONS
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    probes = np.asarray(probes, dtype=np.float64).reshape(-1, c.size)
    gap = np.max(np.abs(probes - c), axis=1)
    near = int(np.argmin(gap))
    out, here = [], ([] if start is None else [start])
    for lv in levels:
        if gap[near] == 0.0:          # a probe contraction: its poses were solved in the sweep
            out.append(dataclasses.replace(lv, poses=[lv.poses[near]], y=lv.y[near:near + 1], difference_to_next=None,
                                           ratio=None, estimate=None, confirmed=False, bound=None, bound_via=None))
            continue
        t0 = time.perf_counter()
        s = dataclasses.replace(scene, element=lv.element)
        model = build_model(s, lv.mesh)
        probe = Targets.at_points(lv.mesh, points, points)
        eq, how = None, "from the answer"
        if here:
            src = start if start is not None and start[0] is lv.mesh else max(here, key=lambda m: m[0].n_nodes)
            how = "from the answer" if src is start else f"from the {src[0].n_nodes:,}-node pose there"
            eq = solve_equilibrium(model, c, transfer_pose(src[0], src[1], lv.mesh), options)
        if eq is None or not eq.converged:
            eq, how = equilibrium_at(model, c, lv.poses[near], options), "from the nearest probe's pose"
        if not eq.converged:
            raise SceneError(f"{scene.source}: accuracy: no certified equilibrium at contraction {c.tolist()} "
                             f"on the {lv.element} mesh of {lv.mesh.n_nodes} nodes: {eq.status}")
        here.append((lv.mesh, eq.x))
        if progress is not None:
            progress(f"accuracy: {lv.element} level of {lv.mesh.n_nodes:,} nodes solved at the returned "
                     f"contractions {how} in {time.perf_counter() - t0:.1f} s")
        out.append(dataclasses.replace(lv, poses=[eq.x], y=probe.y(eq.x)[None], difference_to_next=None,
                                       ratio=None, estimate=None, confirmed=False, bound=None, bound_via=None))
    for element in dict.fromkeys(lv.element for lv in out):
        estimate_levels([lv for lv in out if lv.element == element])
    bound_errors(out)
    return out


def cheapest_meeting(levels: list[Level], tol: float) -> int | None:
    """The index of the level with the least solve time whose bound is
    within ``tol``, or None."""
    meeting = [i for i, lv in enumerate(levels) if lv.meets(tol)]
    return min(meeting, key=lambda i: levels[i].t_solve) if meeting else None


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
    equilibria; its cost timed as a sweep's level's. A pose that cannot be
    certified there is a :class:`SceneError`."""
    c = np.asarray(contraction, dtype=np.float64).reshape(1, -1)
    return _solve_level(dataclasses.replace(scene, element=CHECK_ELEMENT), resolution, c, points, used,
                        options or LEVEL_OPTIONS)


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
