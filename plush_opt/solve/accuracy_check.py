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
mesh used does not meet the tolerance there.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..base.errors import SceneError
from ..fem.model import build_model
from ..fem.objective import Targets
from ..io.scene import Scene
from .accuracy import LEVEL_OPTIONS, Level, bound_errors, equilibrium_at, estimate_levels, transfer_pose
from .equilibrium import EquilibriumOptions, solve_equilibrium


def bounds_at(scene: Scene, levels: list[Level], probes, contraction, points,
              options: EquilibriumOptions | None = None, start=None) -> list[Level]:
    """The sweep's ``levels`` (solved at the contractions ``probes``, (m,
    n_winches)) solved at ``contraction`` ((n_winches,)), each from
    ``start`` (a (mesh, flat pose) at ``contraction``, e.g. the solve's
    answer: carried to the level's mesh, so every level finds the same
    branch) if given and that converges, else from its pose at the nearest
    probe contraction, by continuation where that fails (at a probe
    contraction itself: the sweep's poses, nothing solved), and estimated there: new
    :class:`Level` objects (same meshes, one pose
    each, ``y`` of shape (1, k, 2) at ``points``, (k, 2) rest coordinates),
    in the same order, with their ``estimate`` and ``bound`` at that
    contraction. A level whose equilibrium there cannot be certified is a
    :class:`SceneError`."""
    options = options or LEVEL_OPTIONS
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    probes = np.asarray(probes, dtype=np.float64).reshape(-1, c.size)
    gap = np.max(np.abs(probes - c), axis=1)
    near = int(np.argmin(gap))
    out = []
    for lv in levels:
        if gap[near] == 0.0:          # a probe contraction: its poses were solved in the sweep
            out.append(dataclasses.replace(lv, poses=[lv.poses[near]], y=lv.y[near:near + 1], difference_to_next=None,
                                           ratio=None, estimate=None, confirmed=False, bound=None, bound_via=None))
            continue
        s = dataclasses.replace(scene, element=lv.element)
        model = build_model(s, lv.mesh)
        probe = Targets.at_points(lv.mesh, points, points)
        eq = None
        if start is not None:
            eq = solve_equilibrium(model, c, transfer_pose(start[0], start[1], lv.mesh), options)
        if eq is None or not eq.converged:
            eq = equilibrium_at(model, c, lv.poses[near], options)
        if not eq.converged:
            raise SceneError(f"{scene.source}: accuracy: no certified equilibrium at contraction {c.tolist()} "
                             f"on the {lv.element} mesh of {lv.mesh.n_nodes} nodes: {eq.status}")
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
