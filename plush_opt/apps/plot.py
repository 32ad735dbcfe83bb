"""Figures of poses and control runs (matplotlib; never imported by solvers)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.transforms import offset_copy

from ..base.files import atomic_path
from ..fem.contact_report import node_forces
from ..io.units import DEFAULT_UNITS

REST_COLOR = "#b0b0b0"
BODY_COLOR = "#f3d9b1"   # felt
EDGE_COLOR = "#8a6d4b"
PIN_COLOR = "#222222"
TARGET_COLOR = "#d62728"
TENDON_CMAP = "viridis"
LABEL_FONT = 7           # tendon, winch and error labels: small, the pose stays readable
#: the pose's legend hangs this far (points) below its axes: under the tick labels and the
#: x label whatever the axes' height (a fraction of it put a wide body's legend on its x label)
LEGEND_DROP = 34.0
LABEL_MERGE = 0.05       # stoppers closer than this fraction of the picture share a label (no overprint)
GROUND_COLOR = "#5a5a5a"
OBSTACLE_COLOR = "#9fb4c7"
CONTACT_COLOR = "#1f77b4"
NOT_CONVERGED = "NOT CONVERGED"
NOT_CONVERGED_COLOR = "#c00000"
NOT_CONVERGED_WRAP = 60  # characters a line of the not-converged note: it stays inside the pose axes
FORCE_LENGTH = 0.08      # the largest contact force is drawn this fraction of the picture long


def draw_pose(ax, model, x, contraction, targets=None, *, title=None, show_rest=True,
              tension_max=None, colorbar=True, labels=False):
    """Draw rest pose (faint), deformed mesh, tendons coloured by tension,
    pins and targets on ``ax``. Returns the artists that change with x
    (for interactive updates).

    Axes and labels are in the scene's units (``model.scene.units``).
    ``tension_max`` fixes the top of the tension colour scale (force units), so that
    pictures of several poses compare; by default it is this pose's largest
    tension. ``labels`` adds a legend, the tendon and winch names and each
    target's error (static text: for pictures, not interactive updates).
    """
    units = model.scene.units
    X = model.X.reshape(-1, 2)
    xn = np.asarray(x, dtype=np.float64).reshape(-1, 2)
    tri = model.mesh.triangles
    artists = {}
    if show_rest:
        ax.add_collection(PolyCollection(X[tri], facecolors="none", edgecolors=REST_COLOR,
                                         linewidths=0.3, alpha=0.6, zorder=1))
    body = PolyCollection(xn[tri], facecolors=BODY_COLOR, edgecolors=EDGE_COLOR,
                          linewidths=0.35, zorder=2)
    ax.add_collection(body)
    artists["body"] = body

    state = model.tendon_state(xn.reshape(-1), contraction)
    tension = state["tension"]
    top = float(tension.max(initial=0.0))
    vmax = tension_max if tension_max is not None else max(top, 1e-9)
    segs = [xn[p] for p in model.tendon_paths]
    tendons = LineCollection(segs, cmap=TENDON_CMAP, linewidths=2.2, zorder=4)
    tendons.set_array(tension)
    tendons.set_clim(0.0, vmax)
    ax.add_collection(tendons)
    artists["tendons"] = tendons
    if colorbar and model.n_tendons:
        cb = ax.figure.colorbar(tendons, ax=ax, fraction=0.04, pad=0.02,
                                extend="max" if top > vmax else "neither")
        cb.set_label(f"tendon tension [{units.force}]")
        artists["colorbar"] = cb
    ends = np.array([xn[p[0]] for p in model.tendon_paths]) if model.n_tendons else np.zeros((0, 2))
    artists["stoppers"] = ax.plot(ends[:, 0], ends[:, 1], "o", ms=3.5, color="#444", zorder=5)[0]

    if model.contact is not None:
        artists["contact_forces"] = draw_contact(ax, model, xn.reshape(-1))
    # pins hold their nodes at rest: drawn at X
    artists["pins"] = ax.plot(X[model.pin_nodes, 0], X[model.pin_nodes, 1], "^", ms=5,
                              color=PIN_COLOR, zorder=6, label="pins")[0]
    if targets is not None and targets.n_targets:
        y = targets.y(xn.reshape(-1))
        q = targets.to
        artists["target_lines"] = LineCollection(np.stack([y, q], axis=1), colors=TARGET_COLOR,
                                                 linestyles="dotted", linewidths=1.0, zorder=6)
        ax.add_collection(artists["target_lines"])
        artists["targets"] = ax.plot(q[:, 0], q[:, 1], "x", color=TARGET_COLOR, ms=9, mew=2,
                                     zorder=7, label="targets")[0]
        artists["points"] = ax.plot(y[:, 0], y[:, 1], "o", mfc="white", mec=TARGET_COLOR, ms=5,
                                    zorder=7, label="target points")[0]
    if labels:
        _label_tendons(ax, model, xn, contraction)
        if targets is not None and targets.n_targets:
            _label_errors(ax, targets, xn, units.length)
        _legend(ax, model, targets, show_rest)
    allpts = np.vstack([X, xn] + ([targets.to] if targets is not None and targets.n_targets else []))
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.06 * (hi - lo).max()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel(f"x [{units.length}]")
    ax.set_ylabel(f"y [{units.length}]")
    if title:
        ax.set_title(title, fontsize=10)
    return artists


def draw_contact(ax, model, x) -> LineCollection:
    """The floor (a line), the obstacles (filled polygons) and the contact
    forces at pose ``x`` (arrows as segments from each node, the largest
    :data:`FORCE_LENGTH` of the picture long). Returns the forces' artist."""
    term = model.contact
    if term.ground is not None:
        g = term.ground
        ax.axline((0.0, g.height), slope=float(np.tan(np.radians(g.slope))), color=GROUND_COLOR,
                  lw=1.5, zorder=1.5, label="ground")
    if term.obstacles:
        ax.add_collection(PolyCollection([o.outline for o in term.obstacles], facecolors=OBSTACLE_COLOR,
                                         edgecolors=GROUND_COLOR, linewidths=0.8, zorder=1.5))
    forces = LineCollection(contact_segments(model, x), colors=CONTACT_COLOR, linewidths=1.4, zorder=5.5)
    ax.add_collection(forces)
    return forces


def contact_segments(model, x) -> np.ndarray:
    """(k, 2, 2) one segment per node that feels a contact force at flat
    pose ``x``: from the node along its force, scaled for the picture."""
    entries = node_forces(model.contact, np.asarray(x, dtype=np.float64).reshape(-1))
    if not entries:
        return np.zeros((0, 2, 2))
    xn = np.asarray(x).reshape(-1, 2)
    at = xn[[e["node"] for e in entries]]
    F = np.array([np.add(e["normal_force"], e["friction_force"]) for e in entries])
    size = float(np.ptp(model.X.reshape(-1, 2), axis=0).max())
    scale = FORCE_LENGTH * size / max(float(np.linalg.norm(F, axis=1).max()), 1e-300)
    return np.stack([at, at + scale * F], axis=1)


def _label_tendons(ax, model, xn, contraction):
    """Each tendon's name and winch, ``name (winch)``, at its stopper end;
    tendons whose stoppers nearly coincide share one label. The winches'
    contractions are in the title."""
    near = LABEL_MERGE * float(np.ptp(xn, axis=0).max())
    groups: list[tuple[np.ndarray, list[str]]] = []
    for tendon, path in zip(model.scene.tendons, model.tendon_paths):
        at, text = xn[path[0]], f"{tendon.name} ({tendon.winch})"
        for where, names in groups:
            if np.linalg.norm(where - at) < near:
                names.append(text)
                break
        else:
            groups.append((at, [text]))
    for at, names in groups:
        ax.annotate(", ".join(names), at, xytext=(4, 4), textcoords="offset points", fontsize=LABEL_FONT,
                    color="#1f3b73", zorder=8)


def _label_errors(ax, targets, xn, length: str):
    """Each target's distance from its point (``length`` units), beside the target."""
    for q, e in zip(targets.to, targets.errors(xn.reshape(-1))):
        ax.annotate(f"{e:.2f} {length}", q, xytext=(6, -6), textcoords="offset points", va="top",
                    fontsize=LABEL_FONT, color=TARGET_COLOR, zorder=8)


def _legend(ax, model, targets, show_rest):
    handles = [Patch(facecolor=BODY_COLOR, edgecolor=EDGE_COLOR, label="body (deformed)")]
    if show_rest:
        handles.append(Patch(facecolor="none", edgecolor=REST_COLOR, label="body at rest"))
    if model.n_tendons:
        handles += [Line2D([], [], color="#2a788e", lw=2.2, label="tendon (winch); colour: tension"),
                    Line2D([], [], ls="", marker="o", ms=3.5, color="#444", label="tendon stopper")]
    if len(model.pin_nodes):
        handles.append(Line2D([], [], ls="", marker="^", ms=5, color=PIN_COLOR, label="pins"))
    if model.contact is not None:
        handles += [Line2D([], [], color=GROUND_COLOR, lw=1.5, label="ground / obstacles"),
                    Line2D([], [], color=CONTACT_COLOR, lw=1.4, label="contact force")]
    if targets is not None and targets.n_targets:
        handles += [Line2D([], [], ls="", marker="x", ms=8, mew=2, color=TARGET_COLOR, label="target"),
                    Line2D([], [], ls="", marker="o", mfc="white", mec=TARGET_COLOR, ms=5,
                           label="target point (error beside its target)")]
    below = offset_copy(ax.transAxes, fig=ax.figure, y=-LEGEND_DROP, units="points")
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.0), bbox_transform=below, ncol=3,
              fontsize=LABEL_FONT, frameon=False)


def contraction_label(model, contraction) -> str:
    """``name = c unit`` per winch, in the scene's length unit."""
    length = model.scene.units.length
    return ", ".join(f"{n} = {c:.2f} {length}" for n, c in zip(model.winch_names, contraction))


def save_figure(fig, path, **savefig_kwargs) -> None:
    """Write ``fig`` to ``path`` atomically (a full disk leaves no partial
    file; the error names ``path``) and close it."""
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, **savefig_kwargs)
    finally:
        plt.close(fig)


def pose_figure(model, x, contraction, targets=None, title=None, tension_max=None, *,
                converged: bool = True, status: str = ""):
    """The figure of one pose, with its legend, names and target errors
    (what :func:`plot_pose` writes). ``tension_max`` (force units) fixes the tension
    colour scale (see :func:`draw_pose`). A pose that is not ``converged``
    says so in red, with ``status``, in its title, across the picture and
    by a red frame: it must not pass for a solved pose."""
    fig, ax = plt.subplots(figsize=(7, 6.6), dpi=120)
    if title is None:
        title = f"{model.scene.name}: {contraction_label(model, contraction)}"
        if targets is not None and targets.n_targets:
            title += (f"\nRMS target error {targets.rms_error(np.asarray(x).reshape(-1)):.3g} "
                      f"{model.scene.units.length}")
    draw_pose(ax, model, x, contraction, targets, title=title, tension_max=tension_max, labels=True)
    if not converged:
        mark_not_converged(ax, status)
    fig.tight_layout()
    return fig


def mark_not_converged(ax, status: str) -> None:
    """Mark the pose on ``ax`` as not converged: a red frame, the words
    ``NOT CONVERGED: status`` in its upper left corner and after its title."""
    words = "\n".join(textwrap.wrap(f"{NOT_CONVERGED}: {status}" if status else NOT_CONVERGED,
                                    NOT_CONVERGED_WRAP))
    for spine in ax.spines.values():
        spine.set(color=NOT_CONVERGED_COLOR, linewidth=3.0, visible=True)
    ax.text(0.02, 0.98, words, transform=ax.transAxes, va="top", ha="left", fontsize=9, weight="bold",
            color=NOT_CONVERGED_COLOR, zorder=9,
            bbox={"facecolor": "white", "edgecolor": NOT_CONVERGED_COLOR, "alpha": 0.85})
    title = ax.get_title()
    ax.set_title(f"{title}\n{NOT_CONVERGED}" if title else NOT_CONVERGED, fontsize=10)
    ax.title.set_color(NOT_CONVERGED_COLOR)


def plot_pose(path, model, x, contraction, targets=None, title=None, tension_max=None, *,
              converged: bool = True, status: str = ""):
    """Write a PNG of one pose (:func:`pose_figure`: its legend, names and
    target errors; a pose that is not ``converged`` marked so, with ``status``)."""
    fig = pose_figure(model, x, contraction, targets, title, tension_max, converged=converged, status=status)
    save_figure(fig, path, bbox_inches="tight")


def plot(problem, pose, path, *, tension_max=None) -> Path:
    """Write the picture of a pose that ``plush-opt solve --plot`` draws (PNG,
    atomically) and return ``path``: the deformed body over its rest
    outline, tendons coloured by tension, pins, targets with their errors,
    a legend; a pose that is not converged marked so in red with its status.

    Parameters
    ----------
    problem : the :class:`~plush_opt.problem.Problem` the pose belongs to.
    pose : a :class:`~plush_opt.control.ControlResult` (its final pose, with
        the targets it was run for) or an
        :class:`~plush_opt.solve.equilibrium.Equilibrium` (with the problem's targets).
    path : the PNG file.
    tension_max : top of the tension colour scale (force units; default: this pose's
        largest tension), to compare pictures.
    """
    eq = getattr(pose, "equilibrium", pose)
    targets = getattr(pose, "targets", problem.targets)
    plot_pose(path, problem.model, eq.x, eq.contraction, targets if targets.n_targets else None,
              tension_max=tension_max, converged=pose.converged, status=pose.status)
    return Path(path)


def plot_trace(path, history, title=None, units=DEFAULT_UNITS):
    """Objective against iterate and against wall time of a control run
    (O in ``units.length`` squared: the scene's :class:`~plush_opt.io.units.Units`)."""
    it = [h.iteration for h in history]
    obj = np.array([max(h.objective, 1e-300) for h in history])
    t = [h.t_wall for h in history]
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6), dpi=120)
    a.semilogy(it, obj, "o-", ms=3)
    a.set_xlabel("iterate")
    a.set_ylabel(f"objective O [{units.length}$^2$]")
    b.semilogy(t, obj, "o-", ms=3)
    b.set_xlabel("wall time [s]")
    b.set_ylabel(f"objective O [{units.length}$^2$]")
    for ax in (a, b):
        ax.grid(True, which="both", alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)


def plot_run_log(path, log_lines, title=None, length: str = "mm"):
    """Commanded and measured contraction (``length`` units, the problem's)
    of each winch over a scripted run (the JSON-lines log of
    plush_opt.runs, already parsed); a dry run's is a plan, drawn against
    its planned time."""
    plan = any(r.get("kind") == "start" and r.get("dry_run") for r in log_lines)
    rows = [r for r in log_lines if r.get("commanded")]
    if not rows:
        raise ValueError("the run log has no commanded contractions")
    names = list(rows[0]["commanded"])
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 1.9 * len(names) + 0.8), dpi=120, sharex=True,
                             squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        t = [r["t"] for r in rows]
        ax.step(t, [r["commanded"][name] for r in rows], where="post", color="#1f77b4",
                label="planned command" if plan else "commanded")
        meas = [(r["t"], r["measured"][name]) for r in rows if r.get("measured")]
        if meas:
            ax.plot(*zip(*meas), ".", ms=3, color="#ff7f0e", label="measured")
        ax.set_ylabel(f"{name} [{length}]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    steps, seen = [], set()
    for r in rows:
        if r.get("step") is not None and r["step"] not in seen:
            seen.add(r["step"])
            steps.append((r["t"], r["kind"]))
    for t, _ in steps:
        for ax in axes[:, 0]:
            ax.axvline(t, color="#999", lw=0.6, ls="--")
    axes[-1, 0].set_xlabel("planned time [s]" if plan else "time [s]")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _step_names(axes[0, 0], steps)      # (their lines depend on the laid-out axes' width ...)
    fig.tight_layout()                  # (... and take room above it)
    save_figure(fig, path)


#: step names above a run's plot: font size, and points per character (a generous width)
STEP_FONT, STEP_CHAR_WIDTH = 7, 4.6


def _step_names(ax, steps) -> None:
    """Each step's name above ``ax`` at its start time; a name that would run
    into the one before on its line goes a line higher (short steps: a pose
    solved in a tenth of a second, then its hold)."""
    lo, hi = ax.get_xlim()
    width = ax.get_window_extent().width * 72.0 / ax.figure.dpi        # the axes' width in points
    ends: list[float] = []                 # per line: where its last name ends (points from the left)
    for t, kind in steps:
        at = (t - lo) / (hi - lo) * width
        line = next((k for k, end in enumerate(ends) if at >= end), len(ends))
        if line == len(ends):
            ends.append(0.0)
        ends[line] = at + STEP_CHAR_WIDTH * (len(kind) + 1)
        ax.annotate(kind, (t, 1.02), xycoords=("data", "axes fraction"), xytext=(0, 1.3 * STEP_FONT * line),
                    textcoords="offset points", fontsize=STEP_FONT, va="bottom")
