"""Poses, control traces and runs for the field's mesh viewers (ParaView,
anything meshio reads).

A pose is one ``.vtu``: the deformed body's triangles and the tendons'
polylines (as line segments) in one unstructured grid, with

- point data ``displacement`` (x - X, 3 components, z = 0) and ``rest`` (X),
- cell data ``J`` (area ratio det F of each triangle; NaN on tendon
  segments), ``tension`` (N, of the segment's tendon; NaN on triangles)
  and ``tendon`` (index into the problem's tendon list, -1 on triangles).

A sequence (control iterates, the commands of a run) is a ``.pvd`` file
naming one ``.vtu`` per frame with its time: ParaView plays it.
"""

from __future__ import annotations

import json
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

NO_VALUE = np.nan   # a field that does not apply to a cell (J of a tendon segment)


def _xyz(points2d: np.ndarray) -> np.ndarray:
    return np.column_stack([points2d, np.zeros(len(points2d))])


def area_ratio(X: np.ndarray, x: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """det F of each linear triangle: deformed over rest signed area, (n_elems,)."""
    def signed(p):
        a, b, c = p[triangles[:, 0]], p[triangles[:, 1]], p[triangles[:, 2]]
        return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    return signed(x) / signed(X)


def pose_mesh(model, x, contraction):
    """The pose as a :class:`meshio.Mesh` (see the module docstring)."""
    import meshio
    X = model.X.reshape(-1, 2)
    xn = np.asarray(x, dtype=np.float64).reshape(-1, 2)
    tri = np.asarray(model.mesh.triangles, dtype=np.int64)
    tension = model.tendon_state(xn.reshape(-1), contraction)["tension"]
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
        "tension": per_cell(np.full(len(tri), NO_VALUE), np.asarray(tension, dtype=np.float64)[seg_tendon]),
        "tendon": per_cell(np.full(len(tri), -1, dtype=np.int64), seg_tendon),
    }
    return meshio.Mesh(_xyz(xn), cells, point_data={"displacement": _xyz(xn - X), "rest": _xyz(X)},
                       cell_data=cell_data)


def write_pose(path, model, x, contraction) -> Path:
    """Write one pose as ``.vtu``; returns its path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pose_mesh(model, x, contraction).write(path, file_format="vtu")
    return path


def write_series(folder, name: str, model, frames) -> Path:
    """Write ``frames`` (``(time, x, contraction)`` triples) as
    ``folder/name_0000.vtu``... and the time series ``folder/name.pvd``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    entries = []
    for k, (t, x, c) in enumerate(frames):
        vtu = write_pose(folder / f"{name}_{k:04d}.vtu", model, x, c)
        entries.append(f'    <DataSet timestep="{float(t)!r}" part="0" file={quoteattr(vtu.name)}/>')
    pvd = folder / f"{name}.pvd"
    pvd.write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
                   + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
    return pvd


def write_control(folder, model, eq, history=()) -> list[Path]:
    """The final pose (``pose.vtu``) and, for a control run, its iterates as
    ``trace.pvd`` (time: the iterate's wall time, s)."""
    files = [write_pose(Path(folder) / "pose.vtu", model, eq.x, eq.contraction)]
    if history:
        files.append(write_series(folder, "trace", model,
                                  [(h.t_wall, h.x, h.contraction) for h in history]))
    return files


def run_frames(log_path, problem):
    """``(time, x, contraction)`` of each command in a run log, the pose
    recomputed (the equilibrium at the commanded contractions, each solve
    starting from the previous pose)."""
    from ..errors import SceneError, SolverError
    rows = []
    for i, line in enumerate(Path(log_path).read_text().splitlines()):
        try:
            rows.append(json.loads(line))
        except ValueError:
            raise SceneError(f"{log_path}: line {i + 1}: not a JSON object (a run log from plush-opt run?)") from None
    commands = [r for r in rows if r.get("event") in ("start", "command") and r.get("commanded")]
    if not commands:
        raise SceneError(f"{log_path}: no commanded contractions (a run log from plush-opt run?)")
    frames, x = [], None
    for r in commands:
        eq = problem.equilibrium(r["commanded"], x)
        if not eq.converged:
            raise SolverError(f"{log_path}: t = {r['t']} s: no equilibrium at {r['commanded']}: {eq.status}")
        x = eq.x
        frames.append((r["t"], eq.x, eq.contraction))
    return frames


def write_run(folder, log_path, problem) -> Path:
    """A run log replayed as ``run.pvd`` (time: the log's t, s)."""
    return write_series(folder, "run", problem.model, run_frames(log_path, problem))
