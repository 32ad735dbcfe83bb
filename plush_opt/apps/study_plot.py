"""The picture of a study: each measured quantity against the first
varied key, one curve per combination of the others."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

from ..base.files import atomic_path

#: the measured columns and their titles ({length} and {force}: the problem's units)
PANELS = (("target_error", "target error (RMS) [{length}]"),
          ("max_tension", "largest tendon tension [{force}]"),
          ("hysteresis_work", "hysteresis: work lost per cycle [{force} {length}]"),
          ("release_error", "pose left after release [{length}]"))


def plot_study(out: Path, problem: Path, result) -> Path:
    """Write the trade-off curves of ``result`` (a StudyResult) to ``out``
    (PNG), labelled in the units of the ``problem`` file."""
    from ..io.problem_file import file_units
    units = file_units(problem)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    keys, rows = result.keys, result.rows
    x_key, others = keys[0], keys[1:]
    groups = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in others), []).append(r)
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    colours = itertools.cycle(plt.rcParams["axes.prop_cycle"].by_key()["color"])
    for group, members in groups.items():
        colour = next(colours)
        label = ", ".join(f"{k.rsplit('.', 1)[-1]}={v:g}" for k, v in zip(others, group)) or None
        members = sorted(members, key=lambda r: r[x_key])
        for ax, (col, title) in zip(axes.flat, PANELS):
            good = [(r[x_key], r[col]) for r in members if r["certified"] and _finite(r[col])]
            if good:
                ax.plot(*zip(*good), marker="o", color=colour, label=label)
            bad = [r[x_key] for r in members if not r["certified"]]
            if bad:
                ax.plot(bad, [0.0] * len(bad), "x", color=colour, ms=9)
            ax.set_title(title.format(length=units.length, force=units.force), fontsize=10)
            ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel(x_key)
    if others:
        axes[0, 0].legend(fontsize=8)
    n_bad = sum(not r["certified"] for r in rows)
    fig.suptitle(f"{Path(problem).name}: {len(rows)} variants"
                 + (f" ({n_bad} failed or not certified: x at 0)" if n_bad else ", every pose certified"))
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return Path(out)


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)
