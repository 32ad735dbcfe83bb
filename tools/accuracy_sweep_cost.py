"""What the ``--accuracy`` sweep solves: levels, nodes and CPU time per tolerance.

Usage: python tools/accuracy_sweep_cost.py PROBLEM.yaml ... [--tols 1 0.25 0.05] [--out FILE]

For each problem file and tolerance it runs the sweep that ``--accuracy``
runs before its solve (:func:`plush_opt.solve.accuracy.choose_levels`, the
probe contractions only) and writes a markdown table: the levels solved
in the order solved (element and nodes), their total nodes, the largest,
the level picked and its bound, the CPU seconds of the sweep (process
time: whatever else runs on the machine) and of one solve on the picked
level, and why the sweep stopped. The check at the returned contractions
(docs/accuracy.md, "What is guaranteed") comes after a solve and is not
included.
"""

from __future__ import annotations

import argparse
import datetime
import sys
import time
from pathlib import Path

from plush_opt.base.files import write_text_atomic
from plush_opt.io import load_scene
from plush_opt.solve.accuracy import choose_levels


def row(path: Path, tol: float) -> str:
    scene = load_scene(path)
    t0 = time.process_time()
    best, levels, report = choose_levels(scene, tol)
    cpu = time.process_time() - t0
    order = ", ".join(f"{lv.element} {lv.mesh.n_nodes:,}" for lv in levels)
    nodes = [lv.mesh.n_nodes for lv in levels]
    bound = "-" if report["estimated_error"] is None else f"{report['estimated_error']:.3g}"
    return (f"| {path.name} | {tol:g} | {order} | {sum(nodes):,} | {max(nodes):,} | "
            f"{report['element']} {report['nodes']:,} | {bound} | {'met' if report['reached'] else 'NOT met'} | "
            f"{cpu:.1f} | {report['t_solve_s']:.3f} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problems", nargs="+", type=Path)
    ap.add_argument("--tols", nargs="+", type=float, default=[1.0, 0.25, 0.05])
    ap.add_argument("--out", type=Path, help="markdown file (default: stdout)")
    args = ap.parse_args(argv)
    lines = [f"Made by `python tools/accuracy_sweep_cost.py {' '.join(str(p) for p in args.problems)} "
             f"--tols {' '.join(f'{t:g}' for t in args.tols)}` on {datetime.date.today().isoformat()}.", "",
             "| problem | TOL | levels solved, in order | nodes in all | largest | picked | bound | tolerance | "
             "sweep CPU s | one solve on the pick, CPU s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for path in args.problems:
        for tol in args.tols:
            lines.append(row(path, tol))
            print(lines[-1], file=sys.stderr, flush=True)
    text = "\n".join(lines) + "\n"
    if args.out:
        write_text_atomic(args.out, text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
