"""Regenerate the figures in docs/img/ (shipped problems and the gripper's
control run). Usage: .venv/bin/python tools/make_figures.py"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import plush_opt  # noqa: E402
from plush_opt.apps.plot import plot_pose, plot_trace  # noqa: E402

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
        p = plush_opt.load(ROOT / "problems" / f"{name}.yaml")
        model, targets = p.model, p.targets
        for c in poses:
            eq = p.equilibrium(dict(zip(p.winch_names, c)))
            assert eq.converged, eq.status
            tag = "_".join(f"{v:g}" for v in c)
            plot_pose(OUT / f"{name}_forward_{tag}.png", model, eq.x, c)
            print(f"{name} at {c}: {eq.status}, {eq.iterations} Newton iterations")
        res = p.control()
        plot_pose(OUT / f"{name}_control.png", model, res.equilibrium.x, res.contraction, targets,
                  title=f"{name}: control to the file's targets ({res.status})")
        plot_trace(OUT / f"{name}_control_trace.png", res.history,
                   title=f"{name}: objective per iterate (method 1, reparam)")
        print(f"{name} control: {res.status}; c = {res.contraction.round(3).tolist()}, "
              f"O = {res.objective:.4g}, {res.stats.iterations} iterates, {res.stats.t_wall:.3f} s")


if __name__ == "__main__":
    main()
