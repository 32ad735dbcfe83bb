"""Where a scene's body folds through itself on finer meshes than its file's.

Usage: python tools/crease_scan.py FILE name=value [name=value ...]
       [--factors 1 0.25] [--element P2] [--uniform] [--steps 10]

For each factor, a mesh of the scene at that multiple of the file's
``max_area`` (graded towards corners and attachment discs, as compare's
reference and the accuracy sweep's family A, unless ``--uniform``) is solved
from rest to the given contractions in ``--steps`` equal steps, each from
the pose before, and each step's pose is checked for self-crossings
(plush_opt.fem.contact_boundary: creases and overlaps). One line per step:
the mesh's nodes, the contraction's fraction, O, and where the body crosses
itself (or "-").

A crease here means the model has no converged answer at that pose (the
body passes through itself where it would touch; refinement folds it
further): compare measures no errors there and ``--accuracy`` makes no
claim (docs/comparison.md, docs/accuracy.md).
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from plush_opt.fem.contact_boundary import crossings
from plush_opt.fem.mesh import build_mesh
from plush_opt.io import load_scene
from plush_opt.problem import from_scene
from plush_opt.solve.accuracy import base_area, equilibrium_at


def scan(path: str, contraction: dict, factors, element: str, graded: bool, steps: int):
    scene = load_scene(path)
    unknown = sorted(set(contraction) - set(scene.winch_names))
    if unknown:
        raise SystemExit(f"crease_scan: {path}: no winch named {', '.join(unknown)} "
                         f"(winches: {', '.join(scene.winch_names)})")
    c = np.array([contraction.get(n, float(v)) for n, v in zip(scene.winch_names, scene.contraction)])
    sc = dataclasses.replace(scene, element=element)
    for factor in factors:
        p = from_scene(sc, build_mesh(sc, base_area(scene) * factor, graded=graded))
        x = None
        for s in np.linspace(1.0 / steps, 1.0, steps):
            eq = equilibrium_at(p.model, s * c, x)
            if not eq.converged:
                print(f"{p.model.n_nodes} nodes  {s:.2f}  not converged: {eq.status}", flush=True)
                break
            x = eq.x
            where = crossings(p.model, [x])
            print(f"{p.model.n_nodes} nodes  {s:.2f}  O {p.targets.value(x):.6g}  "
                  f"{(where[0] if where else '- (self-contact: it cannot cross itself)') or '-'}", flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("file")
    ap.add_argument("contractions", nargs="+", help="name=value (mm); winches left out stay at the file's")
    ap.add_argument("--factors", type=float, nargs="+", default=[1.0, 0.25])
    ap.add_argument("--element", default="P2", choices=("P1", "P2"))
    ap.add_argument("--uniform", action="store_true", help="uniform meshes, not graded")
    ap.add_argument("--steps", type=int, default=10)
    args = ap.parse_args(argv)
    contraction = {}
    for item in args.contractions:
        name, _, value = item.partition("=")
        try:
            contraction[name] = float(value)
        except ValueError:
            raise SystemExit(f"crease_scan: expected name=value, got {item!r}") from None
    scan(args.file, contraction, args.factors, args.element, not args.uniform, args.steps)


if __name__ == "__main__":
    main()
