"""The hysteresis loop of a sweep: each scene point's displacement against
the swept winch's contraction, loading and unloading."""

from __future__ import annotations

import numpy as np

from ..base.files import atomic_path


def loop_area(c: np.ndarray, d: np.ndarray) -> float:
    """Signed area of the closed polygon (c_i, d_i) (shoelace): what one
    load-unload cycle encloses, 0 without friction."""
    return 0.5 * float(np.sum(c * np.roll(d, -1) - np.roll(c, -1) * d))


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
        area = abs(loop_area(c, d))
        ax.plot(c, d, marker=".", label=f"point {k} {tuple(np.round(X[node], 1).tolist())}: "
                f"loop area {area:.3g}")
    ax.set_xlabel(f"contraction of {winch} [length units]")
    ax.set_ylabel("displacement [length units]")
    ax.set_title(f"{problem.scene.name}: loading and unloading (the loops: friction)")
    if len(problem.mesh.point_nodes):
        ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
