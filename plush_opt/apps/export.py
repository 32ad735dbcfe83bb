"""Poses, control traces and runs for the field's mesh viewers (ParaView,
anything meshio reads).

A pose is one ``.vtu``: the deformed body's triangles and the tendons'
polylines (as line segments) in one unstructured grid, with

- point data ``displacement`` (x - X, 3 components, z = 0) and ``rest`` (X),
  lengths in the scene's units (``Scene.units``; the field names carry none),
- cell data ``J`` (area ratio det F of each triangle; NaN on tendon
  segments), ``tension`` (force units, of the segment: with friction at via points
  the segments of one tendon pull differently; NaN on triangles) and
  ``tendon`` (index into the problem's tendon list, -1 on triangles).

A sequence (control iterates, the commands of a run) is a ``.pvd`` file
naming one ``.vtu`` per frame with its time: ParaView plays it.

With friction at via points a pose depends on the robot's history
(docs/model.md), so an export never solves "the" pose at some
contractions without saying which history it assumed:

- a result file (:func:`recorded_pose`) gives the state it recorded: the
  segment rest lengths, then the equilibrium at those rest lengths from
  the recorded pose (a result without them: a fresh path from the start
  state, and the note says so);
- a run log (:func:`run_frames`) is replayed by driving the robot from
  command to command in order;
- a problem file alone gets the pose reached from the scene's start state
  along a straight path (the plant's ``history_note``, which the command
  prints).

Which of these a scene needs is the plant's business
(:class:`~plush_opt.solve.plant.Plant`): this module only replays and records.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from ..base.errors import SceneError, SolverError
from ..base.files import atomic_path, write_text_atomic
from ..fem.contact_report import node_forces
from ..solve.plant import segment_table
from .run_log import read_run_log

NO_VALUE = np.nan   # a field that does not apply to a cell (J of a tendon segment)
# The recorded rest nodes must be the problem's mesh: JSON keeps doubles
# exactly, so only a mesh of another file or size differs beyond this.
REST_MATCH = 1e-9


def _xyz(points2d: np.ndarray) -> np.ndarray:
    return np.column_stack([points2d, np.zeros(len(points2d))])


def area_ratio(X: np.ndarray, x: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """det F of each linear triangle: deformed over rest signed area, (n_elems,)."""
    def signed(p):
        a, b, c = p[triangles[:, 0]], p[triangles[:, 1]], p[triangles[:, 2]]
        return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    return signed(x) / signed(X)


def pose_mesh(model, x, contraction, eq=None):
    """The pose as a :class:`meshio.Mesh` (see the module docstring); ``eq``
    the equilibrium it is, whose friction state (if any) gives the segment tensions."""
    import meshio
    X = model.X.reshape(-1, 2)
    xn = np.asarray(x, dtype=np.float64).reshape(-1, 2)
    tri = np.asarray(model.mesh.triangles, dtype=np.int64)
    tension = [T for seg in segment_table(model, xn, contraction, eq) for T in seg["segment_tensions"]]
    segs, seg_tendon = [], []
    for k, path in enumerate(model.tendon_paths):
        path = np.asarray(path, dtype=np.int64)
        segs.append(np.column_stack([path[:-1], path[1:]]))
        seg_tendon += [k] * (len(path) - 1)
    cells = [("triangle", tri)]
    seg_tendon = np.asarray(seg_tendon, dtype=np.int64)
    if len(seg_tendon):
        cells.append(("line", np.vstack(segs)))
    n_seg = len(seg_tendon)

    def per_cell(on_tri, on_seg):
        return [on_tri, on_seg] if n_seg else [on_tri]

    cell_data = {
        "J": per_cell(area_ratio(X, xn, tri), np.full(n_seg, NO_VALUE)),
        "tension": per_cell(np.full(len(tri), NO_VALUE), np.asarray(tension, dtype=np.float64)),
        "tendon": per_cell(np.full(len(tri), -1, dtype=np.int64), seg_tendon),
    }
    point_data = {"displacement": _xyz(xn - X), "rest": _xyz(X)}
    if model.contact is not None:
        point_data.update(_contact_point_data(model, xn))
    return meshio.Mesh(_xyz(xn), cells, point_data=point_data, cell_data=cell_data)


def _contact_point_data(model, xn: np.ndarray) -> dict[str, np.ndarray]:
    """Per node: the contact forces on it (``contact_normal_force``,
    ``contact_friction_force``, zero where it feels none), summed over what
    it touches."""
    normal, friction = np.zeros_like(xn), np.zeros_like(xn)
    for entry in node_forces(model.contact, xn.reshape(-1)):
        normal[entry["node"]] += entry["normal_force"]
        friction[entry["node"]] += entry["friction_force"]
    return {"contact_normal_force": _xyz(normal), "contact_friction_force": _xyz(friction)}


def write_pose(path, model, x, contraction, eq=None) -> Path:
    """Write one pose as ``.vtu`` (``eq`` as in :func:`pose_mesh`); returns its path."""
    path = Path(path)
    mesh = pose_mesh(model, x, contraction, eq)
    with atomic_path(path) as tmp:
        mesh.write(tmp, file_format="vtu")
    return path


def write_series(folder, name: str, model, frames) -> Path:
    """Write ``frames`` (``(time, x, contraction)`` triples, or with the
    frame's equilibrium as a fourth) as ``folder/name_0000.vtu``... and the
    time series ``folder/name.pvd``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    entries = []
    for k, (t, x, c, *eq) in enumerate(frames):
        vtu = write_pose(folder / f"{name}_{k:04d}.vtu", model, x, c, *eq)
        entries.append(f'    <DataSet timestep="{float(t)!r}" part="0" file={quoteattr(vtu.name)}/>')
    pvd = folder / f"{name}.pvd"
    write_text_atomic(pvd, '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
                   + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
    return pvd


def write_control(folder, model, eq, history=()) -> list[Path]:
    """The final pose (``pose.vtu``) and, for a control run, its iterates as
    ``trace.pvd`` (time: the iterate's wall time, s)."""
    files = [write_pose(Path(folder) / "pose.vtu", model, eq.x, eq.contraction, eq)]
    if history:
        files.append(write_series(folder, "trace", model,
                                  [(h.t_wall, h.x, h.contraction, h.equilibrium) for h in history]))
    return files


def export(problem, pose, folder) -> list[Path]:
    """Write ``pose`` for ParaView as ``plush-opt solve --vtk DIR`` does and
    return the files: ``folder/pose.vtu`` (the module docstring's fields),
    and for a :class:`~plush_opt.control.ControlResult` whose iterates are
    all certified equilibria (the gradient loop) ``folder/trace.pvd``, one
    ``.vtu`` per iterate. ``pose``: that result or an
    :class:`~plush_opt.solve.equilibrium.Equilibrium` of ``problem``;
    ``folder`` is made if missing."""
    eq = getattr(pose, "equilibrium", pose)
    history = tuple(getattr(pose, "history", ()))
    if not all(h.equilibrium is not None for h in history):
        history = ()           # IPOPT's iterates are not poses
    Path(folder).mkdir(parents=True, exist_ok=True)
    return write_control(folder, problem.model, eq, history)


def run_frames(log_path, problem):
    """``(time, x, contraction, equilibrium)`` of each command in a run log,
    the pose recomputed by a fork of the problem's plant: the equilibrium
    at the commanded contractions, each solve starting from the previous
    pose; where the pose depends on the path the robot driven from command
    to command in order, from the scene's start state driven to the
    scene's contractions (where the run's planner starts)."""
    rows = read_run_log(log_path, problem.winch_names)
    commands = [(n, r) for n, r in enumerate(rows, start=1)
                if r.get("event") in ("start", "command") and r.get("commanded")]
    if not commands:
        raise SceneError(f"{log_path}: no commanded contractions (a run log from plush-opt run?)")
    plant = problem.plant.fork()
    plant.commit(problem.equilibrium())      # where the run's planner starts
    frames, eq = [], None
    for n, r in commands:
        c = problem.contraction_vector(r["commanded"], what=f"{log_path}: line {n}: commanded:")
        eq = plant.drive(c, None if eq is None else eq.x,
                         origin="the run's previous command")
        if not eq.converged:
            raise SolverError(f"{log_path}: t = {r['t']} s: no equilibrium at {r['commanded']}: {eq.status}")
        plant.commit(eq)
        frames.append((r["t"], eq.x, eq.contraction, eq))
    return frames


def write_run(folder, log_path, problem) -> Path:
    """A run log replayed as ``run.pvd`` (time: the log's t, s)."""
    return write_series(folder, "run", problem.model, run_frames(log_path, problem))


def export_run(folder: Path, log_path: Path) -> Path:
    """A run log replayed (the pose at each command) as folder/run.pvd."""
    from ..problem import load
    return write_run(folder, log_path, load(read_run_log(log_path)[0]["problem"]))


def _read_result(result_path, scene) -> dict:
    """The document of a result file, checked to be a plush-opt result
    (:func:`~plush_opt.solve.result_file.read_result`) of ``scene``."""
    from ..solve.result_file import read_result
    where = str(result_path)
    doc = read_result(result_path)
    if doc.get("problem") != scene.name:
        raise SceneError(f"{where}: problem: {doc.get('problem')!r}, but {scene.source} is {scene.name!r}")
    return doc


def _same_nodes(X, Y) -> bool:
    """Two rest node arrays of one mesh (equal to round-off)."""
    return X.shape == Y.shape and bool(np.max(np.abs(X - Y), initial=0.0)
                                       <= REST_MATCH * (1 + float(np.max(np.abs(Y), initial=0.0))))


def _check_same_mesh(where: str, nodes, rest_nodes, X, source) -> None:
    """A result's ``nodes`` and ``model.rest_nodes`` are one point per node of
    the problem's mesh ``X``, at its rest positions; else one line saying
    which differs: the node counts, or (equal counts) how far apart."""
    if rest_nodes.ndim != 2 or rest_nodes.shape[1:] != (2,) or len(rest_nodes) != len(X):
        raise SceneError(f"{where}: model.rest_nodes: {len(rest_nodes)} nodes, the mesh of {source} has "
                         f"{len(X)}: a result of another mesh size?")
    if nodes.shape != X.shape:
        raise SceneError(f"{where}: nodes: {len(nodes)} points, one per node of the mesh of {source} "
                         f"({len(X)}) expected")
    if not _same_nodes(rest_nodes, X):
        moved = np.linalg.norm(rest_nodes - X, axis=1)
        k = int(np.argmax(moved))
        raise SceneError(f"{where}: model.rest_nodes[{k}]: {moved[k]:.3g} length units from node {k} of the "
                         f"mesh of {source} ({int(np.count_nonzero(moved > REST_MATCH * (1 + np.abs(X).max())))} "
                         f"of its {len(X)} nodes elsewhere): a result of another problem file or mesh?")


def recorded_pose(problem, result_path, options=None, doc=None):
    """The pose a result file of ``problem`` recorded, as an equilibrium of
    the problem: at its recorded segment rest lengths with friction at via
    points (the robot's state; every point taken as stuck), else at its
    contractions, each solved from the recorded pose. ``doc``: the file's
    document, if already read. Returns (equilibrium, note): the note says
    what was done and how far the solve moved the recorded pose; a friction
    result without rest lengths gets a fresh path from the start state, and
    the note says so."""
    from ..solve.equilibrium import EquilibriumOptions
    where = str(result_path)
    model = problem.model
    doc = _read_result(result_path, model.scene) if doc is None else doc
    try:
        contraction, nodes = doc["contractions"], np.asarray(doc["nodes"], dtype=np.float64)
        rest_nodes = np.asarray(doc["model"]["rest_nodes"], dtype=np.float64)
        tendons = list(doc["model"]["tendons"]["list"])
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise SceneError(f"{where}: not a result file of plush-opt solve ({exc})") from None
    if len(tendons) != model.n_tendons:
        raise SceneError(f"{where}: model.tendons.list: {len(tendons)} tendons, the problem has {model.n_tendons}")
    X = model.X.reshape(-1, 2)
    _check_same_mesh(where, nodes, rest_nodes, X, problem.source)
    if set(contraction) != set(model.winch_names):
        raise SceneError(f"{where}: contractions: winches {sorted(contraction)}, the problem has "
                         f"{sorted(model.winch_names)}")
    c = problem.contraction_vector(contraction, what=f"{where}: contractions:")
    x = nodes.reshape(-1)
    return problem.plant.recorded(doc, x, c, options or EquilibriumOptions(), where)


def result_problem(problem_path, result_path):
    """The problem of ``problem_path`` on the mesh a result file of it was
    solved on: the file's own, or (a solve with ``--accuracy``, or on
    another problem file's mesh) the element and mesh the result recorded in
    its ``model`` (``element``, ``rest_nodes``, ``triangles``). Returns
    (problem, the result file's document)."""
    from ..io import load_scene
    from ..fem.mesh import build_mesh
    from ..problem import from_scene
    scene = load_scene(Path(problem_path))
    doc = _read_result(result_path, scene)
    try:
        model = doc["model"]
        element, X = model["element"], np.asarray(model["rest_nodes"], dtype=np.float64)
        triangles = np.asarray(model["triangles"], dtype=np.int64)
    except (ValueError, KeyError, TypeError) as exc:
        raise SceneError(f"{result_path}: not a result file of plush-opt solve ({exc})") from None
    own = build_mesh(scene)
    if element == own.element.name and np.array_equal(triangles, own.elements) and _same_nodes(X, own.X):
        return from_scene(scene, own), doc
    corners = {"P1": 3, "P2": 6}.get(element)
    if corners is None or X.ndim != 2 or X.shape[1] != 2 or triangles.ndim != 2 \
            or triangles.shape[1] != corners or not len(triangles) \
            or triangles.min() < 0 or triangles.max() >= len(X):
        raise SceneError(f"{result_path}: model: element {element!r} with triangles of shape "
                         f"{triangles.shape} on rest_nodes of shape {X.shape}: not a mesh")
    # the recorded mesh as an explicit mesh of the same scene (its tendon
    # and pin points are nodes of it: it was meshed from this scene)
    recorded = dataclasses.replace(scene, outline=None, holes=(), max_area=None, min_angle=None,
                                   nodes=X, triangles=triangles, element=element)
    return from_scene(recorded), doc


def export_result(folder, problem_path, result_path) -> tuple[Path, str, bool]:
    """``folder/pose.vtu`` of the pose a result file of the problem file
    recorded (:func:`recorded_pose`), on the mesh it was solved on
    (:func:`result_problem`); returns (its path, the note, converged)."""
    problem, doc = result_problem(problem_path, result_path)
    eq, note = recorded_pose(problem, result_path, doc=doc)
    return write_pose(Path(folder) / "pose.vtu", problem.model, eq.x, eq.contraction, eq), note, eq.converged
