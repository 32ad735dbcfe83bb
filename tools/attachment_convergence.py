"""Mesh convergence with and without finite tendon attachments.

Usage: .venv/bin/python tools/attachment_convergence.py [--out FILE] [--levels N]

For the gripper and the hexapod leg, at fixed contractions, the equilibrium
is solved on meshes refined by 4x in area per level (P1: the file's
max_area and N - 1 finer ones; P2: one level fewer, as a P2 mesh has about
four times the nodes of the P1 mesh of the same max_area), once with every
attachment radius 0 (point loads) and once with the file's radii. Two
displacements are reported: the first target point (away from the loads)
and the stopper end of the first tendon (under the load: the mesh node for
r = 0, the disc-averaged point for r > 0, i.e. what the tendon pulls).
Under a point load the second grows like log(1/h) as the mesh is refined;
with a finite attachment it converges. The table (plain text) goes to
--out (default out/attachment_convergence.txt).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from plush_opt.solve.equilibrium import solve_equilibrium
from plush_opt.io import load_scene
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model

ROOT = Path(__file__).resolve().parents[1]
# scene -> contractions (by winch) held fixed: well into the taut range
CASES = {
    "gripper": {"left": 12.0, "right": 0.0, "grip": 10.0},
    "hexapod_leg": {"leg": 8.0},
}
REFINE = 4.0            # max_area ratio between levels


def _scene(name: str, element: str, point_loads: bool):
    scene = load_scene(ROOT / "problems" / f"{name}.yaml")
    tendons = scene.tendons
    if point_loads:
        tendons = tuple(replace(t, attachment_radius=0.0) for t in tendons)
    return replace(scene, element=element, tendons=tendons)


def _row(name, element, point_loads, max_area):
    scene = _scene(name, element, point_loads)
    model = build_model(scene, build_mesh(scene, max_area))
    c = np.array([CASES[name].get(w, 0.0) for w in model.winch_names])
    t0 = time.perf_counter()
    eq = solve_equilibrium(model, c)
    seconds = time.perf_counter() - t0
    u = (eq.x - model.X).reshape(-1, 2)
    tri, beta = model.mesh.locate(scene.targets[0].at[None, :])
    nodes = model.mesh.elements[tri[0]]
    target = model.element.interpolation_weights(beta)[0] @ u[nodes]
    end = np.asarray(model.via_weights[0][0] @ u).ravel()
    return {"nodes": model.n_nodes, "converged": eq.converged, "seconds": seconds,
            "target": float(np.linalg.norm(target)), "end": float(np.linalg.norm(end))}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "out" / "attachment_convergence.txt"))
    parser.add_argument("--levels", type=int, default=4, help="P1 levels (P2: one fewer)")
    args = parser.parse_args(argv)
    lines = ["# Displacement (mm) at fixed contractions under mesh refinement",
             "# problem element radii nodes |u(target)| |u(stopper end)| converged solve_s"]
    for name in CASES:
        base = load_scene(ROOT / "problems" / f"{name}.yaml").max_area
        for element, levels in (("P1", args.levels), ("P2", args.levels - 1)):
            for point_loads in (True, False):
                radii = "r=0" if point_loads else "file"
                for k in range(levels):
                    r = _row(name, element, point_loads, base / REFINE ** k)
                    line = (f"{name:12s} {element} {radii:4s} {r['nodes']:6d} {r['target']:9.4f} "
                            f"{r['end']:9.4f} {r['converged']!s:5s} {r['seconds']:7.2f}")
                    print(line, flush=True)
                    lines.append(line)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
