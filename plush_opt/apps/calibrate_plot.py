"""Calibration pictures: per pose, the measured markers against the model's
prediction before and after the fit, with the residual arrows.

matplotlib's object API (no pyplot, no global backend), like the compare
report's figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from ..base.files import atomic_path
from .plot import BODY_COLOR, EDGE_COLOR, REST_COLOR

MEASURED = "#222222"
BEFORE = "#d62728"
AFTER = "#1f77b4"
#: residual arrows are magnified so the longest is drawn at least this
#: fraction of the body's size (small residuals after a fit stay visible)
ARROW_SHARE = 0.06


def _panel(ax, pred, i, measured, seen, color, title):
    model = pred.model
    xn = pred.equilibria[i].x.reshape(-1, 2)
    tri = model.mesh.triangles
    ax.add_collection(PolyCollection(model.X.reshape(-1, 2)[tri], facecolors="none",
                                     edgecolors=REST_COLOR, linewidths=0.3, alpha=0.5))
    ax.add_collection(PolyCollection(xn[tri], facecolors=BODY_COLOR, edgecolors=EDGE_COLOR,
                                     linewidths=0.3, alpha=0.8))
    y = pred.y[i]
    ax.plot(measured[seen, 0], measured[seen, 1], "o", mfc="none", mec=MEASURED, ms=7,
            label="measured")
    ax.plot(y[:, 0], y[:, 1], "+", color=color, ms=8, mew=1.6, label="predicted")
    d = measured[seen] - y[seen]
    size = float(np.ptp(model.X.reshape(-1, 2), axis=0).max())
    longest = float(np.max(np.hypot(d[:, 0], d[:, 1]), initial=0.0))
    gain = max(1.0, ARROW_SHARE * size / longest) if longest > 0 else 1.0
    ax.quiver(y[seen, 0], y[seen, 1], gain * d[:, 0], gain * d[:, 1], angles="xy",
              scale_units="xy", scale=1, color=color, width=0.004,
              label="residual" + (f" x{gain:.3g}" if gain > 1 else ""))
    rms = float(np.sqrt(np.mean(np.sum(d**2, axis=1)))) if seen.any() else float("nan")
    length = model.scene.units.length          # the measured problem's units
    ax.set_title(f"{title}: RMS marker error {rms:.3g} {length}")
    ax.set_xlabel(f"x ({length})")
    ax.set_ylabel(f"y ({length})")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.legend(loc="upper right", fontsize=7)   # "best" tries every placement: slow on many points


def plot_poses(directory, meas, result) -> list[Path]:
    """One PNG per pose in ``directory`` (created): before | after, lengths
    in the units of the measurement file's problem (``meas.scene.units``)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(meas.n_poses):
        fig = Figure(figsize=(11, 4.8), layout="constrained")    # room for the suptitle and the axis labels
        axes = fig.subplots(1, 2, sharex=True, sharey=True)
        seen = meas.seen[i]
        _panel(axes[0], result.before, i, meas.positions[i], seen, BEFORE, "before")
        _panel(axes[1], result.after, i, meas.positions[i], seen, AFTER, "after")
        held = " (held out)" if not result.fitted_poses[i] else ""
        cs = ", ".join(f"{n}={c:g}" for n, c in zip(meas.scene.winch_names, meas.contractions[i]))
        fig.suptitle(f"{meas.scene.name}: pose {i}{held}: {cs}")
        path = directory / f"pose_{i:02d}.png"
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
        paths.append(path)
    return paths
