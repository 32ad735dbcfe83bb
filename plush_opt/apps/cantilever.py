"""The element accuracy check: a cantilever under gravity against beam theory.

    python -m plush_opt.apps.cantilever [problems/cantilever.yaml] [--areas 64 16 8 4 2 1 0.5]

prints, for P1 and P2 elements at each mesh size (``max_area``), the tip
deflection's error against Timoshenko beam theory (plane strain, with its
shear correction) and the forward solve time. The scene is a straight strip
clamped (pinned) along its left end, with one ``points`` entry at the middle
of its free end, where the deflection is read; its load is small enough for
the linear range (docs/model.md, "Element accuracy").
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from ..solve.equilibrium import EquilibriumOptions, solve_equilibrium
from ..io import load_scene
from ..fem.mesh import build_mesh
from ..fem.model import build_model

DEFAULT_PROBLEM = Path(__file__).resolve().parents[2] / "problems" / "cantilever.yaml"
DEFAULT_AREAS = (64.0, 16.0, 8.0, 4.0, 2.0, 1.0, 0.5)
SHEAR_CORRECTION = 5 / 6          # Timoshenko's kappa for a rectangular section
NO_EIG = EquilibriumOptions(eigenvalue=False)   # timing the solve, not the check
REPEATS = 5                       # solve times are medians: a single short run is noise


def beam_deflection(scene) -> float:
    """Tip deflection of the scene's strip by Timoshenko beam theory in plane
    strain: q L^4 / (8 E' I) + q L^2 / (2 kappa G A), E' = E / (1 - nu^2),
    G = mu, q = density |g| A per unit length (A = height x thickness)."""
    lo, hi = scene.outline.min(axis=0), scene.outline.max(axis=0)
    length, height = hi - lo
    mat = scene.material
    nu = mat.lam / (2 * (mat.lam + mat.mu))
    e_plane = 2 * mat.mu * (1 + nu) / (1 - nu**2)
    area = height * mat.thickness
    inertia = mat.thickness * height**3 / 12
    q = mat.density * float(np.linalg.norm(scene.gravity)) * area
    return q * length**4 / (8 * e_plane * inertia) + q * length**2 / (2 * SHEAR_CORRECTION * mat.mu * area)


def deflection_rows(path=DEFAULT_PROBLEM, areas=DEFAULT_AREAS, elements=("P1", "P2")) -> list[dict]:
    """One row per element type and ``max_area``: nodes, tip deflection,
    its relative error against :func:`beam_deflection`, median forward solve
    time from rest (s)."""
    base = load_scene(Path(path))
    reference = beam_deflection(base)
    rows = []
    for element in elements:
        scene = dataclasses.replace(base, element=element)
        for area in areas:
            mesh = build_mesh(scene, max_area=area)
            model = build_model(scene, mesh)
            solve_equilibrium(model, scene.contraction, options=NO_EIG)   # warm the kernels
            times = []
            for _ in range(REPEATS):
                t0 = time.perf_counter()
                eq = solve_equilibrium(model, scene.contraction, options=NO_EIG)
                times.append(time.perf_counter() - t0)
            seconds = float(np.median(times))
            tip = int(mesh.point_nodes[0])
            deflection = -(eq.x[2 * tip + 1] - model.X[2 * tip + 1])
            rows.append({"element": element, "max_area": float(area), "nodes": mesh.n_nodes,
                         "deflection": float(deflection), "reference": reference,
                         "error": float(deflection / reference - 1), "solve_s": seconds,
                         "converged": bool(eq.converged)})
    return rows


def format_table(rows: list[dict]) -> str:
    lines = [f"reference (Timoshenko, plane strain): {rows[0]['reference']:.6g}" if rows else "",
             "| element | max_area | nodes | deflection | error | solve [s] |",
             "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        flag = "" if r["converged"] else " (not converged)"
        lines.append(f"| {r['element']} | {r['max_area']:g} | {r['nodes']} | {r['deflection']:.6g} | "
                     f"{100 * r['error']:+.2f}% | {r['solve_s']:.3f}{flag} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m plush_opt.apps.cantilever",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("problem", nargs="?", default=str(DEFAULT_PROBLEM))
    parser.add_argument("--areas", type=float, nargs="+", default=list(DEFAULT_AREAS),
                        help="mesh sizes (max_area) to run")
    args = parser.parse_args(argv)
    print(format_table(deflection_rows(args.problem, args.areas)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
