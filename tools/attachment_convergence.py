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

``--halving`` writes instead the table of the accuracy levels (P2,
max_area = FACTORS x the file's, halving per level, as ``--accuracy``
uses them) at the file's contractions of CASES and at mid-range
contractions: nodes, then x and y of every target point, then the largest
change of any target coordinate from the previous level. Monotone mesh
convergence shows as changes that shrink from level to level.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from plush_opt import linalg
from plush_opt.elements import interpolation_weights
from plush_opt.equilibrium import solve_equilibrium
from plush_opt.io import load_scene
from plush_opt.mesh import build_mesh
from plush_opt.model import build_model

ROOT = Path(__file__).resolve().parents[1]
# scene -> contractions (by winch) held fixed: well into the taut range
CASES = {
    "gripper": {"left": 12.0, "right": 0.0, "grip": 10.0},
    "hexapod_leg": {"leg": 8.0},
}
REFINE = 4.0            # max_area ratio between levels
# --halving: the fixed contractions (the gripper's: grip only, the bar's tips curling)
HALVING_CASES = {"gripper": {"grip": 10.0}, "hexapod_leg": {"leg": 8.0}}
HALVING = (2.0, 1.0, 0.5, 0.25, 0.125)   # --halving: max_area factors of the file's


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
    target = interpolation_weights(model.element, beta)[0] @ u[nodes]
    end = np.asarray(model.via_weights[0][0] @ u).ravel()
    return {"nodes": model.n_nodes, "converged": eq.converged, "seconds": seconds,
            "target": float(np.linalg.norm(target)), "end": float(np.linalg.norm(end))}


def _targets_at(scene, model, c):
    """Rest-to-deformed positions of the scene's targets at contractions c, (k, 2)."""
    eq = solve_equilibrium(model, c)
    x = eq.x.reshape(-1, 2)
    tri, beta = model.mesh.locate(np.array([t.at for t in scene.targets]))
    w = interpolation_weights(model.element, beta)
    return np.einsum("kn,knd->kd", w, x[model.mesh.elements[tri]]), eq.converged


def halving(levels: int) -> list[str]:
    """The P2 accuracy-level table (see the module docstring)."""
    lines = ["# P2 target positions (mm) under max_area halving; d = largest change "
             "of a target coordinate from the previous level"]
    for name, case in HALVING_CASES.items():
        scene = replace(load_scene(ROOT / "problems" / f"{name}.yaml"), element="P2")
        model0 = build_model(scene, build_mesh(scene))
        fixed = np.array([case.get(w, 0.0) for w in model0.winch_names])
        mid = 0.5 * (scene.lower + scene.upper)
        for label, c in (("fixed", fixed), ("mid", mid)):
            lines.append(f"{name} P2 contractions {label} = {np.round(c, 3).tolist()}")
            prev = None
            for f in HALVING[:levels]:
                model = build_model(scene, build_mesh(scene, scene.max_area * f))
                y, ok = _targets_at(scene, model, c)
                d = "" if prev is None else f" d={np.abs(y - prev).max():.4f}"
                coords = " ".join(f"{v:9.4f}" for v in y.ravel())
                line = f"  x{f:<6g} nodes {model.n_nodes:6d} {coords}{d}{'' if ok else ' NOT CONVERGED'}"
                print(line, flush=True)
                lines.append(line)
                prev = y
    return lines


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "out" / "attachment_convergence.txt"))
    parser.add_argument("--levels", type=int, default=4, help="P1 levels (P2: one fewer)")
    parser.add_argument("--supernodal", action="store_true",
                        help="CHOLMOD's supernodal factorisation at every size (a fine mesh "
                             "with resolved discs has dense tendon blocks, where it is far faster)")
    parser.add_argument("--halving", action="store_true",
                        help="the P2 accuracy-level table instead (levels: up to 5)")
    args = parser.parse_args(argv)
    if args.supernodal:
        linalg.SUPERNODAL_MIN_DOFS = 0
    if args.halving:
        _write(args.out, halving(args.levels))
        return
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
    _write(args.out, lines)


def _write(path, lines) -> None:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
