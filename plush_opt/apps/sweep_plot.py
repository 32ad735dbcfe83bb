"""The hysteresis loop of a sweep: the displacement of each point it follows
(the scene's points, else its targets' points) against the swept winch's
contraction, loading and unloading."""

from __future__ import annotations

import numpy as np

from ..fem.objective import Targets


def followed_points(problem) -> tuple[np.ndarray, str]:
    """The body points a sweep follows, rest coordinates (k, 2), and what
    they are: the scene's ``points``, or where it has none its targets'
    points (a scene of targets alone gets a picture too); (0, 2) for neither."""
    mesh = problem.mesh
    if len(mesh.point_nodes):
        return np.asarray(mesh.X)[mesh.point_nodes], "point"
    at = [t.at for t in problem.scene.targets]
    return np.array(at, dtype=np.float64).reshape(-1, 2), "target point"


def followed_positions(problem, states) -> np.ndarray:
    """Where the :func:`followed_points` are in each of ``states``: (n_states, k, 2)."""
    mesh = problem.mesh
    if len(mesh.point_nodes):
        return np.array([s.nodes[mesh.point_nodes] for s in states]).reshape(len(states), -1, 2)
    rest, _ = followed_points(problem)
    at = Targets.at_points(mesh, rest, rest)
    return np.array([at.y(np.asarray(s.nodes).reshape(-1)) for s in states]).reshape(len(states), -1, 2)


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
    the displacement of each point it follows (:func:`followed_points`)
    against the swept winch's contraction, lengths in the problem's unit
    (``problem.scene.units``); a curve that coincides with an earlier one
    says so in the legend, and a scene with nothing to follow says so."""
    import matplotlib.pyplot as plt
    length = problem.scene.units.length
    w = problem.winch_names.index(winch)
    c = np.array([s.contraction[w] for s in states])
    rest, kind = followed_points(problem)
    curves = list(np.linalg.norm(followed_positions(problem, states) - rest, axis=-1).T)
    scale = max((float(np.max(np.abs(d), initial=0.0)) for d in curves), default=0.0)
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for k, (at, d) in enumerate(zip(rest, curves)):
        area = abs(loop_area(c, d))
        gaps = [(float(np.max(np.abs(curves[j] - d), initial=0.0)), j) for j in range(k)]
        gap, under = min(gaps, default=(np.inf, -1))
        ls, marker, size = CURVE_STYLES[k % len(CURVE_STYLES)]
        label = f"{kind} {k} {tuple(np.round(at, 1).tolist())}: loop area {area:.3g} {length}$^2$"
        if gap <= SAME_CURVE * max(scale, 1e-300):
            label += f" (over {kind} {under}'s curve, within {gap:.2g} {length})"
        ax.plot(c, d, linestyle=ls, marker=marker, ms=size, label=label)
    ax.set_xlabel(f"contraction of {winch} [{length}]")
    ax.set_ylabel(f"displacement [{length}]")
    back = bool(np.any(np.diff(c) > 0) and np.any(np.diff(c) < 0))
    ax.set_title(f"{problem.scene.name}: {kind}s as winch {winch} moves" + (", loading and unloading" if back else ""))
    if curves:      # below the axes: it never hides a loop
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    else:
        ax.text(0.5, 0.5, "nothing to follow: the scene has neither points nor targets", ha="center",
                va="center", transform=ax.transAxes)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def plot_sweep(problem, states, winch: str, out) -> None:
    """Write the hysteresis picture of a sweep (:func:`sweep_figure`) to ``out``."""
    import matplotlib
    matplotlib.use("Agg")
    from .plot import save_figure
    save_figure(sweep_figure(problem, states, winch), out, dpi=120, bbox_inches="tight")
