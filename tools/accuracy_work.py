"""The counted work of a solve (plush_opt/solve/work.py) against its
measured CPU time, on the accuracy sweep's default levels.

    OPENBLAS_NUM_THREADS=1 python tools/accuracy_work.py [PROBLEM ...] [--max-nodes N] [--repeats R]

For each problem (default: cantilever, gripper, hexapod, hexapod_leg),
element (P1, P2) and default level up to N nodes (default 30,000): the
sweep's timed solve (from rest at the file's contractions, after the
symbolic analysis), its median CPU seconds over R runs, its counted work
and their ratio; then the range of the ratio. The weights in work.py are
fitted so that this range stays within about 0.5-2."""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from plush_opt.base.linalg import NotPositiveDefinite
from plush_opt.fem.model import build_model
from plush_opt.io import load_scene
from plush_opt.solve.accuracy import LEVEL_OPTIONS, default_levels, level_mesh
from plush_opt.solve.equilibrium import solve_equilibrium
from plush_opt.solve.plant import make_plant, path_dependent
from plush_opt.solve.work import counted

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = [ROOT / "problems" / f"{name}.yaml" for name in ("cantilever", "gripper", "hexapod", "hexapod_leg")]


def level_rows(path: Path, max_nodes: int, repeats: int):
    """(name, element, nodes, median CPU s, counted s) per default level."""
    for element in ("P1", "P2"):
        scene = dataclasses.replace(load_scene(path), element=element)
        for res in default_levels(scene, element):
            mesh = level_mesh(scene, res, announce=False)
            if mesh.n_nodes > max_nodes:
                continue
            model = build_model(scene, mesh)
            c = scene.contraction
            try:                  # the symbolic analysis, as the sweep does before timing
                model.factorizer.factor(model.evaluate(model.X, c, order=2).hessian_form)
            except NotPositiveDefinite:
                pass
            times, works = [], []
            for _ in range(repeats):
                plant = make_plant(model) if path_dependent(scene) else None
                t = time.process_time()
                with counted(model) as work:
                    if plant is None:
                        solve_equilibrium(model, c, None, LEVEL_OPTIONS)
                    else:
                        plant.equilibrium(c, options=LEVEL_OPTIONS)
                times.append(time.process_time() - t)
                works.append(work.seconds)
            yield scene.name, element, mesh.n_nodes, float(np.median(times)), works[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problems", nargs="*", type=Path, default=DEFAULT)
    ap.add_argument("--max-nodes", type=int, default=30_000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print("| problem | element | nodes | CPU s (median) | counted s | CPU / counted |")
    print("|---|---|---|---|---|---|")
    ratios = []
    for path in args.problems:
        for name, element, nodes, cpu, work in level_rows(path, args.max_nodes, args.repeats):
            ratios.append(cpu / work)
            print(f"| {name} | {element} | {nodes:,} | {cpu:.4f} | {work:.4f} | {ratios[-1]:.2f} |", flush=True)
    print(f"\nCPU / counted: {min(ratios):.2f}-{max(ratios):.2f} over {len(ratios)} levels "
          f"(median {np.median(ratios):.2f})")


if __name__ == "__main__":
    main()
