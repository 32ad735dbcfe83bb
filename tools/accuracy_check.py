"""Check the accuracy estimate and ``--accuracy`` against fine P2 solves.

Usage: python tools/accuracy_check.py PROBLEM.yaml ... [--tols 1 0.25 0.05]
       [--finest 0.0625] [--out accuracy_check.md] [--save DIR]

For each problem file it writes two tables (markdown) to ``--out``:

1. P2 mesh convergence: the P2 levels of the default sweep (max_area
   halving, down to ``--finest`` x the file's), for each level the nodes,
   the estimated error of the compared points (plush_opt.accuracy), their
   error against the P2 level two steps finer (about 4x the nodes) and
   against the finest level (the reference), the ratio estimate / error
   against 4x finer (the acceptance asks for 0.5-2, and >= 1 for a
   conservative estimate), the bound the pick uses (plush_opt.accuracy.
   bound_errors: through a confirmed level where the level has no
   estimate of its own), and per point the level from which its distance
   to the reference shrinks at every further level (monotone convergence).
2. ``--accuracy TOL`` for each TOL: the element and nodes chosen, the
   estimated error, the true error (against the reference), whether the
   reference is at least 4x finer than the chosen mesh, the one-solve time,
   and whether the pose is within TOL.

The errors are the largest distance (length units) over the compared
points (the targets, else the tendon stoppers and the scene's points) and
the probe contractions (the file's, and mid-range for a control problem).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
import time
from pathlib import Path

import numpy as np

from plush_opt.accuracy import (DEFAULT_FACTORS, base_area, choose_mesh, equilibrium_at,
                                probe_contractions, probe_points, sweep)
from plush_opt.equilibrium import EquilibriumOptions
from plush_opt.io import load_scene
from plush_opt.mesh import build_mesh
from plush_opt.model import build_model
from plush_opt.objective import Targets
from plush_opt.results import atomic_path

OPTIONS = EquilibriumOptions(eigenvalue=False)
#: Levels between a level and the one with about 4x its nodes (areas halve per level).
FOUR_TIMES = 2
#: Changes below this fraction of the largest error of any point are round-off, not divergence.
NOISE = 1e-3


def distance(a, b) -> np.ndarray:
    """Largest distance over contractions, per point: (k,)."""
    return np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1).max(axis=0)


def contractions(scene, file_only: bool) -> np.ndarray:
    """The probe contractions, or only the file's (``--file-contraction``)."""
    cs = probe_contractions(scene)
    return cs[:1] if file_only else cs


def convergence_rows(scene, finest: float, cs, solved: dict):
    """P2 levels from the coarsest default factor down to ``finest``; returns
    (levels, rows) with the reference the finest level. The levels solved
    are added to ``solved`` (the ``--accuracy`` picks reuse them)."""
    base = base_area(scene)
    factors = sorted(set(DEFAULT_FACTORS) | {finest}, reverse=True)
    areas = [base * f for f in factors if f >= finest - 1e-12]
    points, _ = probe_points(scene)
    levels = sweep(scene, "P2", areas, cs, points, 0.0, OPTIONS, solved=solved)
    ref = levels[-1].y
    rows = []
    for k, lv in enumerate(levels[:-1]):
        four = levels[k + FOUR_TIMES].y if k + FOUR_TIMES < len(levels) else None
        e4 = None if four is None else float(distance(lv.y, four).max())
        est = lv.estimate
        rows.append({"nodes": lv.mesh.n_nodes, "max_area": lv.max_area, "estimate": est, "bound": lv.bound,
                     "error_4x": e4, "error_ref": float(distance(lv.y, ref).max()),
                     "ratio": None if est is None or e4 in (None, 0.0) else est / e4,
                     "per_point": distance(lv.y, ref)})
    per_point = np.array([r["per_point"] for r in rows])          # (levels, points)
    # a point that hardly moves (a stopper on a pinned edge) wobbles at round-off
    floor = NOISE * per_point.max(initial=0.0)
    monotone = [monotone_from(per_point[:, j], floor) for j in range(per_point.shape[1])]
    return levels, rows, monotone


def monotone_from(errors: np.ndarray, floor: float) -> int:
    """The first level from which the distances to the reference shrink at
    every further level (0: all of them; len - 1: only the last one left)."""
    rising = np.flatnonzero(np.diff(errors) >= floor)
    return 0 if rising.size == 0 else int(rising[-1] + 1)


def chosen_error(scene, report, ref_level, cs, points) -> float:
    """Largest distance of the chosen mesh's predicted points from the
    reference's. Each probe is solved from rest, not from the previous
    probe's pose (a jump from one winch pulled to another can end on
    another equilibrium than the sweep's levels found)."""
    s = dataclasses.replace(scene, element=report["element"])
    mesh = build_mesh(s, max_area=report["max_area"], graded=report.get("graded", False))
    model = build_model(s, mesh)
    probe = Targets.at_points(mesh, points, points)
    ys = [probe.y(equilibrium_at(model, c, None, OPTIONS).x) for c in cs]
    return float(distance(ys, ref_level.y).max())


def fmt(v, spec=".3g") -> str:
    return "n/a" if v is None else ("inf" if v == float("inf") else format(v, spec))


def save_levels(path: Path, solved: dict) -> None:
    """Every level's predicted points, to re-evaluate the estimate offline."""
    levels = sorted(solved.values(), key=lambda lv: (lv.element, -lv.max_area))
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:      # makes the folder too
        np.savez(fh, element=np.array([lv.element for lv in levels]),
                 max_area=np.array([lv.max_area for lv in levels]),
                 nodes=np.array([lv.mesh.n_nodes for lv in levels]),
                 t_solve=np.array([lv.t_solve for lv in levels]),
                 y=np.array([lv.y for lv in levels]))


def check(path: Path, tols, finest: float, file_only: bool = False, save: Path | None = None) -> str:
    scene = load_scene(path)
    points, kind = probe_points(scene)
    cs = contractions(scene, file_only)
    t0 = time.perf_counter()
    solved: dict = {}
    levels, rows, monotone = convergence_rows(scene, finest, cs, solved)
    ref = levels[-1]
    out = [f"## {scene.name} ({path.name})", "",
           f"Compared points: {kind} ({len(points)}); contractions {cs.tolist()}; reference: P2, "
           f"{ref.mesh.n_nodes} nodes (max_area {ref.max_area:.4g}).", "",
           "P2 mesh convergence (error = largest distance over points and contractions):", "",
           "| nodes | max_area | estimate | bound | error vs 4x finer | error vs reference | estimate / error 4x |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['nodes']} | {r['max_area']:.4g} | {fmt(r['estimate'])} | {fmt(r['bound'])} | "
                   f"{fmt(r['error_4x'])} | {fmt(r['error_ref'])} | {fmt(r['ratio'], '.2f')} |")
    def shrinking(k):
        return "at every level" if k == 0 else f"from {rows[k]['nodes']} nodes on"
    out += ["", "Distance to the reference shrinking (per point): "
            + ", ".join(f"{tuple(np.round(p, 3).tolist())}: {shrinking(k)}"
                        for p, k in zip(points, monotone)), "",
            "| TOL | element | nodes | estimated error | true error | reference >= 4x finer | one solve s | within TOL |",
            "|---|---|---|---|---|---|---|---|"]
    for tol in tols:
        _, report = choose_mesh(scene, tol, contractions=cs, solved=solved)
        true = chosen_error(scene, report, ref, cs, points)
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
    ap.add_argument("--finest", type=float, default=0.0625,
                    help="the reference's max_area as a multiple of the file's (default 1/16)")
    ap.add_argument("--file-contraction", action="store_true",
                    help="compare at the file's contractions only (not also mid-range)")
    ap.add_argument("--out", type=Path, default=Path("accuracy_check.md"))
    ap.add_argument("--save", type=Path, default=None,
                    help="a folder to write each problem's levels to (NAME_levels.npz: element, "
                         "max_area, nodes, t_solve, y)")
    args = ap.parse_args(argv)
    parts = ["# Accuracy estimate check", "",
             f"`python tools/accuracy_check.py {' '.join(str(p) for p in args.problems)} "
             f"--tols {' '.join(f'{t:g}' for t in args.tols)} --finest {args.finest:g}"
             f"{' --file-contraction' if args.file_contraction else ''}` "
             f"(Python {platform.python_version()}).", ""]
    for path in args.problems:
        parts.append(check(path, args.tols, args.finest, args.file_contraction, args.save))
        args.out.write_text("\n".join(parts) + "\n")      # what exists so far, if interrupted
        print(f"accuracy_check: {path.name} done", file=sys.stderr)
    print(f"accuracy_check: wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
