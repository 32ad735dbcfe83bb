"""The hysteresis loop of a sweep: each scene point's displacement against
the swept winch's contraction, loading and unloading."""

from __future__ import annotations

import numpy as np


def loop_area(c: np.ndarray, d: np.ndarray) -> float:
    """Signed area of the closed polygon (c_i, d_i) (shoelace): what one
    load-unload cycle encloses, 0 without friction."""
    return 0.5 * float(np.sum(c * np.roll(d, -1) - np.roll(c, -1) * d))


#: line style and marker of each point's curve, in turn: curves that coincide
#: (points moving alike) stay told apart, the later one drawn smaller on top
CURVE_STYLES = (("-", "o", 6.0), ("--", "s", 4.5), (":", "^", 3.5), ("-.", "D", 3.0), ((0, (1, 3)), "x", 5.0))
#: two curves closer than this fraction of the largest displacement look
#: like one at the picture's scale: the legend says which lies over which
SAME_CURVE = 0.03


def sweep_figure(problem, states, winch: str):
    """The hysteresis figure of a sweep (what :func:`plot_sweep` writes):
    each scene point's displacement against the swept winch's contraction,
    lengths in the problem's unit (``problem.scene.units``); a curve that coincides with an earlier
    one says so in the legend."""
    import matplotlib.pyplot as plt
    length = problem.scene.units.length
    w = problem.winch_names.index(winch)
    c = np.array([s.contraction[w] for s in states])
    X = problem.mesh.X
    curves = [np.array([np.linalg.norm(s.nodes[node] - X[node]) for s in states])
              for node in problem.mesh.point_nodes]
    scale = max((float(np.max(np.abs(d), initial=0.0)) for d in curves), default=0.0)
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for k, (node, d) in enumerate(zip(problem.mesh.point_nodes, curves)):
        area = abs(loop_area(c, d))
        gaps = [(float(np.max(np.abs(curves[j] - d), initial=0.0)), j) for j in range(k)]
        gap, under = min(gaps, default=(np.inf, -1))
        ls, marker, size = CURVE_STYLES[k % len(CURVE_STYLES)]
        label = f"point {k} {tuple(np.round(X[node], 1).tolist())}: loop area {area:.3g} {length}$^2$"
        if gap <= SAME_CURVE * max(scale, 1e-300):
            label += f" (over point {under}'s curve, within {gap:.2g} {length})"
        ax.plot(c, d, linestyle=ls, marker=marker, ms=size, label=label)
    ax.set_xlabel(f"contraction of {winch} [{length}]")
    ax.set_ylabel(f"displacement [{length}]")
    ax.set_title(f"{problem.scene.name}: loading and unloading (the loops: friction)")
    if len(problem.mesh.point_nodes):      # below the axes: it never hides a loop
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def plot_sweep(problem, states, winch: str, out) -> None:
    """Write the hysteresis picture of a sweep (:func:`sweep_figure`) to ``out``."""
    import matplotlib
    matplotlib.use("Agg")
    from .plot import save_figure
    save_figure(sweep_figure(problem, states, winch), out, dpi=120, bbox_inches="tight")
