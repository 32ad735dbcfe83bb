"""The error estimate of ``--accuracy`` where the pose depends on the path
(friction at via points or at contacts: a path-dependent plant, docs/plant.md).

There the returned pose is the end of a path: for a control run, its
starting state (reached from the scene's start state) and its accepted
iterates, each driven from the one before; for a forward solve, the plant's
fresh path from the scene's start state to the contractions. The error of
the returned pose is the error of that path's end, so every mesh level
replays the same path (:func:`replay`), and the levels' ends are estimated
as :func:`~plush_opt.solve.accuracy_check.bounds_at` estimates the levels'
poses at the returned contractions (:func:`levels_along`). Where no level
meets the tolerance there, the sweep's default levels not solved yet are
replayed, coarse to fine, until one does (:func:`extend_along`). The sweep
that picks the mesh in the first place solves each probe contraction by the
plant's fresh path (:func:`~plush_opt.solve.accuracy._solve_level`).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..base.errors import SceneError
from ..fem.model import build_model
from ..fem.objective import Targets
from ..io.scene import Scene
from .accuracy import (LEVEL_OPTIONS, Level, cheapest_meeting, default_levels, estimate_each_element,
                       RestPushes, level_mesh, level_model, one_pose)
from .equilibrium import Equilibrium, EquilibriumOptions
from .plant import make_plant
from .plant_base import Plant
from .work import counted

#: where a replayed pose says it came from (the result's ``friction_path.from``)
REPLAY_ORIGIN = "the returned path replayed on another mesh level (--accuracy)"


def replay(plant: Plant, waypoints, contraction, options: EquilibriumOptions | None = None) -> Equilibrium:
    """The end of a path on ``plant``'s mesh, with its own history (a fork).

    ``waypoints`` ((m, n_winches) contractions): the first reached from the
    scene's start state, each next driven from the state before and
    committed, as the control loop drives its iterates; the end certified as
    the loop certifies its own (:meth:`Plant.finish`). ``waypoints`` None: a
    forward solve's path, the plant's fresh path from the scene's start
    state to ``contraction`` (:meth:`Plant.equilibrium`). A step that does
    not converge ends the replay with its equilibrium (not converged)."""
    options = options or LEVEL_OPTIONS
    plant = plant.fork()
    if waypoints is None:
        return plant.equilibrium(np.asarray(contraction, dtype=np.float64), options=options)
    waypoints = np.asarray(waypoints, dtype=np.float64)
    if len(waypoints) == 0:
        raise SceneError("accuracy: the returned pose has no path to replay (a control run without iterates)")
    eq = None
    for c in waypoints:
        eq = plant.drive(c, None, options, origin=REPLAY_ORIGIN)
        if not eq.converged:
            return eq
        plant.commit(eq)
    return plant.finish(eq, waypoints, options, origin=REPLAY_ORIGIN)


def path_key(waypoints, contraction) -> bytes:
    """What identifies a replayed path (:func:`replay`'s ``waypoints``, None
    for a fresh path, and ``contraction``): a level whose pose ends the same
    path is not replayed again."""
    w = b"fresh" if waypoints is None else np.asarray(waypoints, dtype=np.float64).tobytes()
    return w + b"|" + np.asarray(contraction, dtype=np.float64).tobytes()


def _level_along(scene: Scene, lv: Level, waypoints, contraction, points, options) -> Level:
    """``lv``'s mesh with the path replayed on it: a new :class:`Level`
    (one pose, ``y`` (1, k, 2), ``along`` the path's :func:`path_key`); a
    :class:`SceneError` if its end is not certified."""
    s = dataclasses.replace(scene, element=lv.element)
    model = lv.model if lv.model is not None else build_model(s, lv.mesh)
    eq = replay(make_plant(model), waypoints, contraction, options)
    if not eq.converged:
        raise SceneError(f"{scene.source}: accuracy: the returned path replayed on the {lv.element} mesh of "
                         f"{lv.mesh.n_nodes} nodes does not reach a certified pose: {eq.status}")
    return dataclasses.replace(one_pose(lv, eq.x, Targets.at_points(lv.mesh, points, points).y(eq.x)[None]),
                               along=path_key(waypoints, contraction))


def levels_along(scene: Scene, levels: list[Level], waypoints, contraction, points, answer=None,
                 options: EquilibriumOptions | None = None, progress=None) -> list[Level]:
    """The sweep's ``levels`` with the returned path replayed on each
    (:func:`replay`; ``waypoints`` None: a forward solve's fresh path to
    ``contraction``), estimated there: new :class:`Level` objects in the same
    order, as :func:`~plush_opt.solve.accuracy_check.bounds_at` returns
    them. ``answer`` = (mesh, flat pose): the path's end on the mesh it was
    solved on, taken as that level's pose (no replay); a level that already
    ends this path (:func:`extend_along` replayed it) is kept as it is.
    ``progress(line)`` hears of each level replayed."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    key = path_key(waypoints, contraction)
    out = []
    for lv in levels:
        if answer is not None and answer[0] is lv.mesh:
            out.append(one_pose(lv, answer[1], Targets.at_points(lv.mesh, points, points).y(answer[1])[None]))
            continue
        if lv.along == key:          # (its estimates made afresh below)
            out.append(dataclasses.replace(one_pose(lv, lv.poses[0], lv.y), along=key))
            continue
        t0 = time.perf_counter()
        out.append(_level_along(scene, lv, waypoints, contraction, points, options or LEVEL_OPTIONS))
        if progress is not None:
            progress(f"accuracy: {lv.element} level of {lv.mesh.n_nodes:,} nodes: the returned path replayed "
                     f"in {time.perf_counter() - t0:.1f} s")
    return estimate_each_element(out)


def extend_along(scene: Scene, at: list[Level], waypoints, contraction, points, tol: float, element: str,
                 options: EquilibriumOptions | None = None, progress=None) -> tuple[list[Level], int | None]:
    """No level of ``at`` (the levels with the path replayed,
    :func:`levels_along`) meets ``tol``: the default levels of ``element``
    not among them are meshed, timed as a sweep's level (one solve by the
    plant's fresh path at the scene's contractions) and replayed, coarse to
    fine, until one meets ``tol``. Returns (``at`` and the levels added, the
    index of the cheapest level meeting ``tol`` or None)."""
    options = options or LEVEL_OPTIONS
    done = {(lv.element, lv.resolution) for lv in at}
    s = dataclasses.replace(scene, element=element)
    levels = list(at)
    for res in default_levels(scene, element):
        if (element, res) in done:
            continue
        t0 = time.perf_counter()
        mesh = level_mesh(s, res, announce=False)
        t_mesh = time.perf_counter() - t0
        try:
            model = level_model(s, mesh)
        except RestPushes as exc:     # this level and the finer ones cannot be used: the levels end here
            if progress is not None:
                progress(f"accuracy: {element} level of {mesh.n_nodes:,} nodes not used, nor the finer ones: {exc}")
            break
        plant = make_plant(model)
        with counted(model) as work:
            cold = plant.equilibrium(scene.contraction, options=options)
        lv = Level(element, res, mesh, t_mesh, work.cpu_s, cold.iterations, [], np.empty((0, 0, 2)),
                   work=work.seconds)
        levels.append(_level_along(scene, lv, waypoints, contraction, points, options))
        if progress is not None:
            progress(f"accuracy: {element} level of {mesh.n_nodes:,} nodes added: the returned path replayed "
                     f"in {time.perf_counter() - t0:.1f} s")
        levels.sort(key=lambda lv: (lv.element, lv.mesh.n_nodes))
        k = cheapest_meeting(estimate_each_element(levels), tol)
        if k is not None:
            return levels, k
    return levels, None
