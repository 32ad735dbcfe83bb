"""The hysteresis loop of a sweep: each scene point's displacement against
the swept winch's contraction, loading and unloading."""

from __future__ import annotations

import numpy as np

from ..results import atomic_path


def plot_sweep(problem, states, winch: str, out) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    w = problem.winch_names.index(winch)
    c = np.array([s.contraction[w] for s in states])
    X = problem.mesh.X
    fig, ax = plt.subplots(figsize=(6, 4))
    for k, node in enumerate(problem.mesh.point_nodes):
        d = np.array([np.linalg.norm(s.nodes[node] - X[node]) for s in states])
        ax.plot(c, d, marker=".", label=f"point {k} {tuple(np.round(X[node], 1).tolist())}")
    ax.set_xlabel(f"contraction of {winch} [length units]")
    ax.set_ylabel("displacement [length units]")
    ax.set_title(f"{problem.scene.name}: loading and unloading")
    if len(problem.mesh.point_nodes):
        ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
