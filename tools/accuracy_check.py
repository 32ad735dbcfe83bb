"""Check the accuracy estimate and ``--accuracy`` against fine P2 solves.

Usage: python tools/accuracy_check.py PROBLEM.yaml ... [--tols 1 0.25 0.05]
       [--refinements 3] [--out accuracy_check.md] [--save DIR]

For each problem file it writes two tables (markdown) to ``--out``:

1. P2 mesh convergence: the P2 levels of the default sweep (two families
   of nested meshes, A refined up to ``--refinements`` times, B one time
   less, interleaved by size), for each level its family, the nodes, the
   estimated error of the compared points (plush_opt.solve.accuracy), their
   error against the next level of its family (4x the nodes) and against
   the finest level (the reference), the ratio estimate / error against 4x
   finer (the acceptance asks for 0.5-2, and >= 1 for a conservative
   estimate), the bound the pick uses (plush_opt.solve.accuracy.bound_errors:
   through a finer level where the level has no estimate of its own), and
   per point the level from which its distance to the reference shrinks at
   every further level (monotone convergence), over all levels in order of
   size and within each family.
2. ``--accuracy TOL`` for each TOL: the element and nodes chosen, the
   estimated error, the true error (against the reference), whether the
   reference has at least 4x the chosen mesh's nodes, the one-solve time,
   and whether the pose is within TOL.

The errors are the largest distance (length units) over the compared
points (the targets, else the tendon stoppers and the scene's points) and
the probe contractions (the file's, and mid-range for a control problem).

The P2 levels and each tolerance's check of its pick are independent
solves run as batches (plush_opt.batch, ``--jobs N``, default the number
of cores): every P2 level is solved from the coarsest level's poses
(solved again inside the same input, so no input waits for another), not
from the previous level's, and the tables do not depend on ``--jobs``. The
P1 levels a pick needs are solved here, one after the other, as
``choose_mesh`` does. The picks weigh solve times, which depend on the
machine's load.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import platform
import sys
import time
from pathlib import Path

import numpy as np

from plush_opt.batch import run_batch
from plush_opt.batch.progress import Progress
from plush_opt.solve.accuracy import (LEVEL_OPTIONS, MAX_RATIO, REFINEMENTS, SAFETY, _solve_level,
                                choose_mesh, default_levels, equilibrium_at, probe_contractions,
                                probe_points, sweep)
from plush_opt.io import load_scene
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from plush_opt.fem.objective import Targets
from plush_opt.base.errors import SceneError
from plush_opt.base.files import atomic_path, write_text_atomic

OPTIONS = LEVEL_OPTIONS
#: Changes below this fraction of the largest error of any point are round-off, not divergence.
NOISE = 1e-3


def distance(a, b) -> np.ndarray:
    """Largest distance over contractions, per point: (k,)."""
    return np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1).max(axis=0)


def contractions(scene, file_only: bool) -> np.ndarray:
    """The probe contractions, or only the file's (``--file-contraction``)."""
    cs = probe_contractions(scene)
    return cs[:1] if file_only else cs


def solve_level(job: tuple, scene, cs, points):
    """One input of the levels' batch: ``job`` (element, resolution, the
    element's coarsest resolution) solved from the coarsest level's poses
    (that one solved here first; itself from rest)."""
    element, res, coarsest = job
    s = dataclasses.replace(scene, element=element)
    start = None if res == coarsest else _solve_level(s, coarsest, cs, points, None, OPTIONS)
    return _solve_level(s, res, cs, points, start, OPTIONS)


def solve_levels(scene, refinements: int, cs, jobs, progress) -> dict:
    """Every level of the P2 sweep (``refinements``) as one batch, largest
    first; {(element, resolution): Level}. A level that failed is a
    SceneError naming it."""
    levels = default_levels(scene, "P2", refinements)
    work = [("P2", res, levels[0]) for res in levels]
    # nodes grow as 4^refinements / max_area
    work.sort(key=lambda j: -(4.0 ** j[1].refinements / j[1].max_area))
    points, _ = probe_points(scene)
    if progress is not None:
        progress.describe = lambda i: f"{work[i][0]} max_area {work[i][1].max_area:.4g} x{work[i][1].refinements}"
    batch = run_batch(functools.partial(solve_level, scene=scene, cs=cs, points=points), work,
                      jobs=jobs, progress=progress)
    batch.raise_if_interrupted()
    for job, item in zip(work, batch.items):
        if not item.ok:
            raise SceneError(f"{scene.source}: accuracy: level {job[0]} max_area {job[1].max_area:g} "
                             f"refined {job[1].refinements}x: {item.error}")
    return {(job[0], job[1]): item.value for job, item in zip(work, batch.items)}


def convergence_rows(scene, refinements: int, cs, solved: dict):
    """The default sweep's P2 levels (taken from ``solved``, see
    :func:`solve_levels`); returns (levels, rows, monotone) with the
    reference the finest level, and per point the level from which it
    converges monotonically: over all levels, and within the worse family."""
    points, _ = probe_points(scene)
    levels = sweep(scene, "P2", default_levels(scene, "P2", refinements), cs, points, 0.0, OPTIONS,
                   solved=solved)
    ref = levels[-1].y
    families = list(dict.fromkeys(lv.resolution.family for lv in levels))
    rows = []
    for k, lv in enumerate(levels[:-1]):
        same = [m for m in levels[k + 1:] if m.resolution.family == lv.resolution.family]
        e4 = float(distance(lv.y, same[0].y).max()) if same else None
        est = lv.estimate
        rows.append({"family": "AB"[families.index(lv.resolution.family)], "nodes": lv.mesh.n_nodes,
                     "refinements": lv.resolution.refinements, "estimate": est, "bound": lv.bound,
                     "error_4x": e4, "error_ref": float(distance(lv.y, ref).max()),
                     "ratio": None if est is None or e4 in (None, 0.0) else est / e4,
                     "bound_ratio": None if lv.bound is None or e4 in (None, 0.0) else lv.bound / e4,
                     "per_point": distance(lv.y, ref)})
    per_point = np.array([r["per_point"] for r in rows])          # (levels, points)
    # a point that hardly moves (a stopper on a pinned edge) wobbles at round-off
    floor = NOISE * per_point.max(initial=0.0)
    monotone = []
    for j in range(per_point.shape[1]):
        overall = monotone_from(per_point[:, j], floor)
        within = 0
        for name in "AB"[:len(families)]:
            idx = [i for i, r in enumerate(rows) if r["family"] == name]
            m = monotone_from(per_point[idx, j], floor) if idx else 0
            within = max(within, idx[m] if m > 0 else 0)
        monotone.append((overall, within))
    return levels, rows, monotone


def reference_error(levels) -> float | None:
    """The reference's own error, estimated like any level's: the tail after
    it, SAFETY r d / (1 - r), with d its distance to the level before it in
    its family and r the ratio used there. Errors against the reference
    below this are within its own uncertainty."""
    same = [lv for lv in levels if lv.resolution.family == levels[-1].resolution.family]
    if len(same) < 2 or same[-2].ratio is None or not same[-2].ratio < MAX_RATIO:
        return None
    r = same[-2].ratio
    return SAFETY * r * same[-2].difference_to_next / (1.0 - r)


def monotone_from(errors: np.ndarray, floor: float) -> int:
    """The first level from which the distances to the reference shrink at
    every further level (0: all of them; len - 1: only the last one left)."""
    rising = np.flatnonzero(np.diff(errors) >= floor)
    return 0 if rising.size == 0 else int(rising[-1] + 1)


def chosen_error(job: tuple, scene, ref_level, cs, points) -> float:
    """Largest distance of the chosen mesh's predicted points from the
    reference's. Each probe is solved from rest, not from the previous
    probe's pose (a jump from one winch pulled to another can end on
    another equilibrium than the sweep's levels found). ``job`` is (TOL,
    the pick's report): one input of the picks' batch."""
    _, report = job
    s = dataclasses.replace(scene, element=report["element"])
    mesh = build_mesh(s, max_area=report["max_area"], graded=report.get("graded", False),
                      refinements=report.get("refinements") or 0)
    model = build_model(s, mesh)
    probe = Targets.at_points(mesh, points, points)
    ys = [probe.y(equilibrium_at(model, c, None, OPTIONS).x) for c in cs]
    return float(distance(ys, ref_level.y).max())


def fmt(v, spec=".3g") -> str:
    return "n/a" if v is None else ("inf" if v == float("inf") else format(v, spec))


def save_levels(path: Path, solved: dict) -> None:
    """Every level's predicted points, to re-evaluate the estimate offline."""
    levels = sorted(solved.values(), key=lambda lv: (lv.element, lv.mesh.n_nodes))
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:      # makes the folder too
        np.savez(fh, element=np.array([lv.element for lv in levels]),
                 max_area=np.array([lv.max_area for lv in levels]),
                 refinements=np.array([lv.resolution.refinements for lv in levels]),
                 family=np.array([lv.resolution.family or 0.0 for lv in levels]),
                 nodes=np.array([lv.mesh.n_nodes for lv in levels]),
                 t_solve=np.array([lv.t_solve for lv in levels]),
                 y=np.array([lv.y for lv in levels]))


def check(path: Path, tols, refinements: int, file_only: bool = False, save: Path | None = None,
          jobs: int | None = None, progress: bool = True) -> str:
    scene = load_scene(path)
    points, kind = probe_points(scene)
    cs = contractions(scene, file_only)
    t0 = time.perf_counter()
    solved = solve_levels(scene, refinements, cs, jobs, Progress(f"accuracy_check {path.name}: levels")
                          if progress else None)
    levels, rows, monotone = convergence_rows(scene, refinements, cs, solved)
    ref = levels[-1]
    out = [f"## {scene.name} ({path.name})", "",
           f"Compared points: {kind} ({len(points)}); contractions {cs.tolist()}; reference: P2, "
           f"{ref.mesh.n_nodes} nodes (max_area {ref.max_area:.4g} refined {ref.resolution.refinements}x), "
           f"its own estimated error {fmt(reference_error(levels))} (the tail after it, as for any "
           "level: errors against it are uncertain by that much).", "",
           "P2 mesh convergence (error = largest distance over points and contractions; "
           "4x finer = the next level of the same family):", "",
           "| family | refined | nodes | estimate | bound | error vs 4x finer | error vs reference "
           "| estimate / error 4x | bound / error 4x |",
           "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['family']} | {r['refinements']} | {r['nodes']} | {fmt(r['estimate'])} | "
                   f"{fmt(r['bound'])} | {fmt(r['error_4x'])} | {fmt(r['error_ref'])} | "
                   f"{fmt(r['ratio'], '.2f')} | {fmt(r['bound_ratio'], '.2f')} |")

    def shrinking(k):
        return "at every level" if k == 0 else f"from {rows[k]['nodes']} nodes on"
    out += ["", "Distance to the reference shrinking (per point; all levels in order of size / "
            "within each family): "
            + ", ".join(f"{tuple(np.round(p, 3).tolist())}: {shrinking(k)} / {shrinking(w)}"
                        for p, (k, w) in zip(points, monotone)), "",
            "| TOL | element | nodes | estimated error | true error | reference >= 4x finer | one solve s | within TOL |",
            "|---|---|---|---|---|---|---|---|"]
    picks = [(tol, choose_mesh(scene, tol, contractions=cs, solved=solved)[1]) for tol in tols]
    checked = run_batch(functools.partial(chosen_error, scene=scene, ref_level=ref, cs=cs, points=points),
                        picks, jobs=jobs)
    checked.raise_if_interrupted()
    for (tol, report), item in zip(picks, checked.items):
        if not item.ok:
            raise SceneError(f"{scene.source}: accuracy: the pick for {tol:g}: {item.error}")
        true = item.value
        four = ref.mesh.n_nodes >= 4 * report["nodes"]
        ok = "yes" if true <= tol else "NO"
        met = "" if report["reached"] else " (not met: said so)"
        out.append(f"| {tol:g} | {report['element']} | {report['nodes']} | "
                   f"{fmt(report['estimated_error'])}{met} | {fmt(true)} | {'yes' if four else 'no'} | "
                   f"{report['t_solve_s']:.4f} | {ok} |")
    out += ["", f"({time.perf_counter() - t0:.0f} s for this problem)", ""]
    if save is not None:
        save_levels(save / f"{path.stem}_levels.npz", solved)
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("problems", nargs="+", type=Path)
    ap.add_argument("--tols", nargs="+", type=float, default=[1.0, 0.25, 0.05])
    ap.add_argument("--refinements", type=int, default=REFINEMENTS,
                    help=f"uniform refinements of the coarsest level (default {REFINEMENTS}): the "
                         "reference has 4^refinements x its nodes")
    ap.add_argument("--file-contraction", action="store_true",
                    help="compare at the file's contractions only (not also mid-range)")
    ap.add_argument("--out", type=Path, default=Path("accuracy_check.md"))
    ap.add_argument("--jobs", "-j", type=int, default=None,
                    help="worker processes (default: the number of cores; 1: one after the other)")
    ap.add_argument("--save", type=Path, default=None,
                    help="a folder to write each problem's levels to (NAME_levels.npz: element, "
                         "max_area, refinements, family (its coarse max_area), nodes, t_solve, y)")
    args = ap.parse_args(argv)
    parts = ["# Accuracy estimate check", "",
             f"`python tools/accuracy_check.py {' '.join(str(p) for p in args.problems)} "
             f"--tols {' '.join(f'{t:g}' for t in args.tols)} --refinements {args.refinements}"
             f"{' --file-contraction' if args.file_contraction else ''}` "
             f"(Python {platform.python_version()}).", ""]
    for path in args.problems:
        parts.append(check(path, args.tols, args.refinements, args.file_contraction, args.save, args.jobs))
        write_text_atomic(args.out, "\n".join(parts) + "\n")      # what exists so far, if interrupted
        print(f"accuracy_check: {path.name} done", file=sys.stderr)
    print(f"accuracy_check: wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
