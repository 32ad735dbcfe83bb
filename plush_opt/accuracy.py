"""Mesh resolution from an accuracy tolerance.

A finer mesh predicts the pose better and costs more per equilibrium solve
(and much more in the bilevel method). :func:`choose_mesh` meshes the scene
at a sequence of resolutions, coarse to fine, solves the equilibrium at a
few contractions on each, and picks the coarsest mesh whose predicted
positions of a few body points (the targets, or else the tendon stoppers
and the scene's extra points) differ from the next finer mesh by less than
the tolerance (length units). The difference to the next finer mesh is the
usual a-posteriori estimate of the discretisation error of the coarser one.
These differences do not always shrink steadily with refinement (linear
triangles are stiff in bending), so by default the next pair must agree
too before a level is taken.

:func:`transfer_pose` carries a pose from one mesh of a scene to another
(barycentric interpolation of the displacement); the finer level's solve
starts from it, so every level follows the same branch of equilibria.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from .elements import interpolation_weights
from .equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium
from .errors import SceneError
from .geometry import ring_area
from .mesh import Mesh, build_mesh
from .model import Model, build_model
from .objective import Targets
from .scene import Scene

log = logging.getLogger(__name__)

#: Default resolution sweep: max_area as multiples of the scene's own.
DEFAULT_FACTORS = (16.0, 8.0, 4.0, 2.0, 1.0, 0.5, 0.25)
#: A level counts as finer than the previous one only with this many times its nodes.
MIN_REFINEMENT = 1.3


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
    weights = interpolation_weights(mesh_from.element, beta[inside])
    out[inside] = np.einsum("kj,kjd->kd", weights, u[nodes])
    if not inside.all():
        from scipy.spatial import cKDTree
        _, near = cKDTree(mesh_from.X).query(mesh_to.X[~inside])
        out[~inside] = u[near]
    return (mesh_to.X + out).reshape(-1)


def equilibrium_at(model: Model, contraction, x0=None,
                   options: EquilibriumOptions | None = None, steps: int = 4) -> Equilibrium:
    """Certified equilibrium at ``contraction`` from ``x0`` (default the rest
    pose); if that fails, by continuation from the rest contraction (0
    clipped to the bounds) in ``steps`` equal steps."""
    options = options or EquilibriumOptions(eigenvalue=False)
    c = np.asarray(contraction, dtype=np.float64)
    if x0 is not None and not model.admissible(x0):
        x0 = None
    eq = solve_equilibrium(model, c, x0, options)
    if eq.converged:
        return eq
    c_rest = np.clip(np.zeros_like(c), model.lower, model.upper)
    x = None
    for s in np.linspace(0, 1, steps + 1)[1:]:
        eq = solve_equilibrium(model, c_rest + s * (c - c_rest), x, options)
        if not eq.converged:
            return eq
        x = eq.x
    return eq


def base_area(scene: Scene) -> float:
    """The max_area resolution sweeps scale: the problem file's, or 1/400 of
    the body area if the file leaves it to the mesher's angle bound."""
    if scene.outline is None:
        raise SceneError(f"{scene.source}: mesh: an explicit mesh cannot be resized")
    if scene.max_area is not None:
        return float(scene.max_area)
    body = abs(ring_area(scene.outline)) - sum(abs(ring_area(h)) for h in scene.holes)
    return body / 400.0


def default_levels(scene: Scene) -> tuple[float, ...]:
    """max_area values of the default sweep, coarse to fine."""
    base = base_area(scene)
    return tuple(base * f for f in DEFAULT_FACTORS)


def probe_points(scene: Scene) -> tuple[np.ndarray, str]:
    """Body points (rest coordinates, (k, 2)) whose predicted positions are
    compared between meshes: the targets if any, else the tendon stoppers
    and the scene's extra points."""
    if scene.targets:
        return np.array([t.at for t in scene.targets], dtype=np.float64), "targets"
    pts = [t.path[0] for t in scene.tendons] + [p for p in scene.points]
    if not pts:
        pts = list(scene.outline) if scene.outline is not None else list(scene.nodes[:4])
        return np.array(pts, dtype=np.float64), "outline vertices"
    return np.array(pts, dtype=np.float64), "tendon stoppers and points"


def probe_contractions(scene: Scene) -> np.ndarray:
    """The contractions the meshes are compared at, (m, n_winches): the
    scene's own and, for a control problem, also mid-range for every free
    winch (a representative pose the controller will pass through)."""
    cs = [scene.contraction.copy()]
    if scene.targets:
        mid = scene.contraction.copy()
        free = ~scene.frozen
        mid[free] = 0.5 * (scene.lower[free] + scene.upper[free])
        if not np.array_equal(mid, cs[0]):
            cs.append(mid)
    return np.array(cs)


def choose_mesh(scene: Scene, tol: float, levels=None, contractions=None, points=None,
                options: EquilibriumOptions | None = None, confirm: bool = True) -> tuple[Mesh, dict]:
    """The coarsest mesh that predicts the pose to within ``tol``.

    Parameters
    ----------
    scene : an outline scene (an explicit mesh is returned unchanged).
    tol : largest acceptable difference (length units) between a level's
        predicted point positions and the next finer level's.
    levels : max_area values (length^2), coarse to fine (strictly
        decreasing); default :func:`default_levels`.
    contractions : (m, n_winches) contractions to compare at; default
        :func:`probe_contractions`.
    points : (k, 2) rest coordinates of the compared body points; default
        :func:`probe_points`.
    options : equilibrium options.
    confirm : also require the next finer level to agree with its own next
        finer level (two differences in a row below ``tol``). The
        differences of these meshes do not always shrink with refinement
        (linear triangles in bending and compression): one small
        difference can be a coincidence, two in a row rarely are. Costs one
        more level.

    Returns
    -------
    mesh : the chosen mesh.
    report : dict (JSON-able): ``tol``, ``picked`` (level index),
        ``max_area``, ``n_nodes``, ``reached`` (False if no level met the
        tolerance: the finest computed level is returned), ``confirmed``,
        ``levels`` (per
        level: max_area, n_nodes, n_elems, t_mesh_s, t_solve_s,
        difference_to_next; levels that are not 1.3 x finer than the previous
        one are skipped), ``points``, ``contractions``, and the savings
        against the next finer level and the scene's own mesh.

    Raises
    ------
    SceneError
        Bad ``tol``/``levels``, a point off the body, or a level whose
        equilibrium cannot be certified.
    """
    options = options or EquilibriumOptions(eigenvalue=False)
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
        raise SceneError(f"accuracy: tol must be a finite number > 0, got {tol!r}")
    if scene.outline is None:
        mesh = build_mesh(scene)
        return mesh, {"tol": float(tol), "picked": 0, "reached": True,
                      "n_nodes": mesh.n_nodes, "max_area": None,
                      "note": "explicit mesh: its resolution is fixed", "levels": []}
    levels = default_levels(scene) if levels is None else tuple(float(a) for a in levels)
    if len(levels) < 2 or any(not (a > 0 and math.isfinite(a)) for a in levels) \
            or any(b >= a for a, b in zip(levels, levels[1:])):
        raise SceneError(f"accuracy: levels must be >= 2 max_area values > 0, strictly "
                         f"decreasing (coarse to fine), got {list(levels)!r}")
    if points is None:
        points, kind = probe_points(scene)
    else:
        points, kind = np.asarray(points, dtype=np.float64).reshape(-1, 2), "given points"
    cs = probe_contractions(scene) if contractions is None else \
        np.asarray(contractions, dtype=np.float64).reshape(-1, len(scene.winches))

    rows, meshes = [], []
    prev = None            # (mesh, poses, y) of the previous (coarser) level
    picked = None
    confirmed = False
    for area in levels:
        t0 = time.perf_counter()
        mesh = build_mesh(scene, max_area=area)
        t_mesh = time.perf_counter() - t0
        if prev is not None and mesh.n_nodes < MIN_REFINEMENT * prev[0].n_nodes:
            # not really finer (forced points and the angle bound dominate):
            # comparing with it would say nothing about the error
            log.info("accuracy: max_area %.4g gives %d nodes, not finer than %d: skipped",
                     area, mesh.n_nodes, prev[0].n_nodes)
            continue
        model = build_model(scene, mesh)
        probe = Targets.at_points(mesh, points, points)
        # cost of one solve at this level: cold, from the rest pose
        t0 = time.perf_counter()
        cold = solve_equilibrium(model, cs[-1], None, options)
        t_solve = time.perf_counter() - t0
        poses, ys = [], []
        for j, c in enumerate(cs):
            x0 = transfer_pose(prev[0], prev[1][j], mesh) if prev is not None else None
            if x0 is None and j == len(cs) - 1 and cold.converged:
                eq = cold
            else:
                eq = equilibrium_at(model, c, x0, options)
            if not eq.converged:
                raise SceneError(f"{scene.source}: accuracy: no certified equilibrium at "
                                 f"contraction {c.tolist()} on the mesh with max_area {area:g}: "
                                 f"{eq.status}")
            poses.append(eq.x)
            ys.append(probe.y(eq.x))
        rows.append({"max_area": area, "n_nodes": mesh.n_nodes, "n_elems": mesh.n_elems,
                     "t_mesh_s": t_mesh, "t_solve_s": t_solve, "newton_iterations": cold.iterations,
                     "difference_to_next": None})
        meshes.append(mesh)
        log.info("accuracy: max_area %.4g, %d nodes, one solve %.3f s", area, mesh.n_nodes, t_solve)
        if prev is not None:
            rows[-2]["difference_to_next"] = max(
                float(np.max(np.linalg.norm(a - b, axis=1), initial=0.0)) for a, b in zip(prev[2], ys))
        prev = (mesh, poses, ys)
        # the coarsest candidate that can be decided now
        k = len(rows) - (3 if confirm else 2)
        if k >= 0 and rows[k]["difference_to_next"] < tol and (
                not confirm or rows[k + 1]["difference_to_next"] < tol):
            picked, confirmed = k, confirm
            break
    if picked is None and confirm and len(rows) >= 2 and rows[-2]["difference_to_next"] < tol:
        picked = len(rows) - 2          # the last pair agrees; nothing finer to confirm with
    reached = picked is not None
    if not reached:
        picked = len(rows) - 1
    chosen = meshes[picked]
    row, nxt = rows[picked], rows[picked + 1] if picked + 1 < len(rows) else None
    report = {
        "tol": float(tol), "picked": picked, "reached": reached, "confirmed": confirmed,
        "max_area": row["max_area"], "n_nodes": row["n_nodes"], "n_elems": row["n_elems"],
        "points": kind, "n_points": int(len(points)), "contractions": cs.tolist(),
        "levels": rows,
    }
    if nxt is not None:
        report["nodes_saved_vs_next"] = nxt["n_nodes"] - row["n_nodes"]
        report["t_solve_saved_vs_next_s"] = nxt["t_solve_s"] - row["t_solve_s"]
    if scene.max_area is not None:
        own = build_mesh(scene)
        report["scene_mesh_nodes"] = own.n_nodes
        report["nodes_saved_vs_scene_mesh"] = own.n_nodes - row["n_nodes"]
    report["summary"] = summary(report)
    return chosen, report


def summary(report: dict) -> str:
    """One line for the user: which level, why, what it saves."""
    if not report.get("levels"):
        return report.get("note", "")
    i = report["picked"]
    row = report["levels"][i]
    if report["reached"]:
        text = (f"mesh level {i} (max_area {row['max_area']:.4g}, {row['n_nodes']} nodes): "
                f"its {report['points']} differ from the next finer mesh by "
                f"{row['difference_to_next']:.3g} < tol {report['tol']:.3g}"
                + (" (and that one its next finer)" if report.get("confirmed") else ""))
    else:
        prev = report["levels"][i - 1]["difference_to_next"] if i > 0 else float("nan")
        text = (f"tolerance {report['tol']:.3g} not reached: using the finest level {i} "
                f"(max_area {row['max_area']:.4g}, {row['n_nodes']} nodes); the last two levels "
                f"differ by {prev:.3g}")
    if "scene_mesh_nodes" in report:
        text += f"; the problem file's own mesh has {report['scene_mesh_nodes']} nodes"
    if "t_solve_saved_vs_next_s" in report:
        nxt = report["levels"][i + 1]
        text += (f"; {report['nodes_saved_vs_next']} fewer nodes than the next finer level "
                 f"(one solve {row['t_solve_s']:.3f} s against {nxt['t_solve_s']:.3f} s)")
    return text
