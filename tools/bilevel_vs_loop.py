"""Bilevel (reduced space, default options) against the gradient loop
(reparam) on every shipped problem and comparison scene, at the file's mesh
and at about 3,000 nodes (the level `plush-opt compare` adds: the problem's
finest factor, 0.25, when that has at least LARGE_SHORTFALL x 3,000 nodes,
else a max_area scaled to about 3,000 nodes).

Usage: .venv/bin/python tools/bilevel_vs_loop.py [--out out/bilevel_vs_loop.md] [--repeat 2]

Each method runs --repeat times on the same model; the fastest time is kept
(the whole call: the bilevel method's set-up is inside it). Per row: the
objectives, the times, their ratios, and the acceptance checks: objective
at most 1.01 x the loop's (or both at the floor), time at most 5 x, no
success reported from the start contractions.
"""

from __future__ import annotations

import argparse
import glob
import time
from pathlib import Path

import numpy as np

from plush_opt.solve.accuracy import base_area
from plush_opt.apps.compare.settings import LARGE_SHORTFALL
from plush_opt.control import BilevelOptions, run_control
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
from plush_opt.io import load_scene
from plush_opt.fem.mesh import build_mesh
from plush_opt.problem import from_scene

ROOT = Path(__file__).resolve().parent.parent
LARGE_NODES = 3000
FINEST = 0.25          # compare's finest mesh factor
OBJECTIVE_RATIO, TIME_RATIO = 1.01, 5.0
FLOOR = 1e-12          # both objectives below this count as equal (targets reached)


def _areas(scene):
    if scene.outline is None:
        return [("file", None)]
    b = base_area(scene)
    n = build_mesh(scene, b * FINEST).n_nodes
    large = FINEST if n >= LARGE_SHORTFALL * LARGE_NODES else FINEST * n / LARGE_NODES
    return [("file", b), ("~3000", b * large)]


def _timed(p, method, repeat):
    best = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        r = run_control(p.model, p.targets, method, options=BilevelOptions() if method == "bilevel" else None)
        t = time.perf_counter() - t0
        best = (r, t) if best is None or t < best[1] else best
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "out" / "bilevel_vs_loop.md"))
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    files = sorted(glob.glob(str(ROOT / "problems" / "*.yaml"))) + \
        sorted(glob.glob(str(ROOT / "problems" / "compare" / "*.yaml")))
    lines = ["| problem | level | nodes | loop O | loop s | bilevel O | bilevel s | O ratio | time ratio "
             "| bilevel iterations (loop) | checks | bilevel status |", "|" + "---|" * 12]
    t_all = time.perf_counter()
    for f in files:
        scene = load_scene(f)
        for level, area in _areas(scene):
            p = from_scene(scene, max_area=area)
            if p.targets.n_targets == 0 or p.plant.path_dependent:
                break          # no targets, or friction: bilevel refuses a pose that depends on the path
            # CHOLMOD's symbolic analysis is model set-up, paid by neither method
            solve_equilibrium(p.model, scene.contraction, options=EquilibriumOptions(eigenvalue=False))
            (rl, tl), (rb, tb) = _timed(p, "reparam", args.repeat), _timed(p, "bilevel", args.repeat)
            ratio = rb.objective / rl.objective if rl.objective > 0 else float("nan")
            checks = []
            if not (rb.objective <= OBJECTIVE_RATIO * rl.objective or max(rb.objective, rl.objective) <= FLOOR):
                checks.append("OBJECTIVE")
            if tb > TIME_RATIO * tl:
                checks.append("TIME")
            if rb.converged and np.array_equal(rb.contraction, scene.contraction):
                checks.append("SUCCESS AT START")
            row = (f"| {scene.name} | {level} | {p.mesh.n_nodes} | {rl.objective:.6g} | {tl:.3f} | "
                   f"{rb.objective:.6g} | {tb:.3f} | {ratio:.4f} | {tb / tl:.2f} | "
                   f"{rb.stats.iterations} ({rl.stats.iterations}) | {', '.join(checks) or 'ok'} | {rb.status} |")
            print(row, flush=True)
            lines.append(row)
    lines.append("")
    lines.append(f"Wall time of the whole run: {time.perf_counter() - t_all:.0f} s.")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(lines[-1])


if __name__ == "__main__":
    main()
