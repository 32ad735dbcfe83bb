"""Regenerate the figures in docs/img/ (shipped problems and the gripper's
control run). Usage: .venv/bin/python tools/make_figures.py"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

from plush_opt.control.gradient import solve_control  # noqa: E402
from plush_opt.equilibrium import solve_equilibrium  # noqa: E402
from plush_opt.mesh import build_mesh  # noqa: E402
from plush_opt.model import build_model  # noqa: E402
from plush_opt.objective import Targets  # noqa: E402
from plush_opt.apps.plot import plot_pose, plot_trace  # noqa: E402
from plush_opt.io import load_scene  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "img"

POSES = {
    "gripper": [[0, 0, 0], [15, 0, 0], [0, 0, 15], [12, 0, 12]],
    "hexapod": [[0, 0], [15, 0], [15, 15]],
    "hexapod_leg": [[0], [6], [12]],
}


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    for name, poses in POSES.items():
        scene = load_scene(ROOT / "problems" / f"{name}.yaml")
        mesh = build_mesh(scene)
        model = build_model(scene, mesh)
        targets = Targets.from_mesh(mesh, scene)
        for c in poses:
            eq = solve_equilibrium(model, c)
            assert eq.converged, eq.status
            tag = "_".join(f"{v:g}" for v in c)
            plot_pose(OUT / f"{name}_forward_{tag}.png", model, eq.x, c)
            print(f"{name} at {c}: {eq.status}, {eq.iterations} Newton iterations")
        res = solve_control(model, targets)
        plot_pose(OUT / f"{name}_control.png", model, res.equilibrium.x, res.contraction, targets,
                  title=f"{name}: control to the file's targets ({res.status})")
        plot_trace(OUT / f"{name}_control_trace.png", res.history,
                   title=f"{name}: objective per iterate (method 1, reparam)")
        print(f"{name} control: {res.status}; c = {res.contraction.round(3).tolist()}, "
              f"O = {res.objective:.4g}, {len(res.history) - 1} iterates, {res.t_wall:.3f} s")


if __name__ == "__main__":
    main()
