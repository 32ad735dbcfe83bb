"""Scripted posing sessions: synthesised mouse and key events fed through
a window's callbacks, as a backend would. They make the screenshot in
docs/ and the callback timings, and drive the tests."""

from __future__ import annotations

import time

import numpy as np
from matplotlib.backend_bases import KeyEvent, MouseEvent

from ...base.files import atomic_path
from ...solve.equilibrium import EquilibriumOptions, solve_equilibrium
from .view import PosingWindow

# the demo's drags end where body points are at these contractions (as
# fractions of each winch's range, repeated over the winches): two bent
# poses that every shipped robot reaches
DEMO_POSES = ([0.6, 0.15, 0.3, 0.45], [0.0, 0.8, 0.0, 0.5])
# the second drag's point is the farthest from the first among the points
# at least this fraction as far from the pins as the farthest one
DEMO_REACH = 0.7
# where the third drag is caught for the screenshot, as fractions of the way
DEMO_CAUGHT = (0.2, 0.4, 0.6)


def mouse(window: PosingWindow, kind: str, xy, button: int = 1) -> None:
    """Feed one synthesised mouse event (``press``, ``motion``, ``release``)
    at data point ``xy`` of the pose axes through the figure's callbacks."""
    name = {"press": "button_press_event", "motion": "motion_notify_event",
            "release": "button_release_event"}[kind]
    px, py = window.ax.transData.transform(xy)
    event = MouseEvent(name, window.fig.canvas, px, py, button=None if kind == "motion" else button)
    window.fig.canvas.callbacks.process(name, event)


def key(window: PosingWindow, name: str) -> None:
    """Feed one synthesised key press through the figure's callbacks."""
    window.fig.canvas.callbacks.process("key_press_event",
                                        KeyEvent("key_press_event", window.fig.canvas, name))


def drag(window: PosingWindow, start, end, steps: int = 8, button: int = 1) -> None:
    """Press at ``start``, move in ``steps`` steps and release at ``end``
    (data coordinates)."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    mouse(window, "press", start, button)
    for s in np.linspace(0.0, 1.0, steps + 1)[1:]:
        mouse(window, "motion", start + s * (end - start))
    mouse(window, "release", end, button)


def run_ticks(window: PosingWindow, max_ticks: int) -> int:
    """Tick until the loop stops (or ``max_ticks``); returns the ticks done."""
    for n in range(1, max_ticks + 1):
        window.tick()
        if not window.session.running:
            return n
    return max_ticks


def demo_drags(model):
    """Three drags for a scripted session, as (body point, destination) in
    rest coordinates.

    The points: the triangle centroid farthest from the pins; among those
    at least 70 % as far, the one farthest from the first; the centroid
    nearest the middle of those two. The destinations are where the points
    are at reachable poses: the first two at contractions of 60, 15, 30,
    45, 60, ... % of each winch's range, the third at 0, 80, 0, 50, 0, ... %.
    """
    X = model.X.reshape(-1, 2)
    pivot = X[model.pin_nodes].mean(axis=0)
    C = X[model.mesh.triangles].mean(axis=1)
    reach = np.linalg.norm(C - pivot, axis=1)
    k0 = int(np.argmax(reach))
    far = np.where(reach >= DEMO_REACH * reach.max(), np.linalg.norm(C - C[k0], axis=1), -1.0)
    k1 = int(np.argmax(far))
    k2 = int(np.argmin(np.linalg.norm(C - (C[k0] + C[k1]) / 2, axis=1)))
    moved = []
    for fractions in DEMO_POSES:
        c = model.lower + np.resize(fractions, model.n_winches) * (model.upper - model.lower)
        x = solve_equilibrium(model, c, None, EquilibriumOptions(eigenvalue=False)).x.reshape(-1, 2)
        moved.append(x[model.mesh.triangles].mean(axis=1))
    return [(C[k0], moved[0][k0]), (C[k1], moved[0][k1]), (C[k2], moved[1][k2])]


def current_position(session, rest_point):
    """Where the body point at ``rest_point`` (rest coordinates) is now."""
    tri, beta = session.model.mesh.locate(np.reshape(rest_point, (1, 2)))
    nodes = session.x.reshape(-1, 2)[session.model.mesh.triangles[tri[0]]]
    return beta[0] @ nodes


def scripted_session(window: PosingWindow, *, ticks: int = 80, screenshot=None,
                     full: bool = True) -> dict:
    """A scripted drag session, as a user would run it.

    ``r`` (no targets), two drags (see :func:`demo_drags`), each followed
    by ticks until the loop stops, and a third drag, caught half-way for
    the screenshot, then released and followed by ticks. With ``full``,
    then: the first target dragged again, a slider move, space, a freeze,
    a right-click removal, each followed by ticks.
    Returns the handler times (seconds) by kind (a tick includes blitting
    the new pose) plus ``draw``: five full redraws of the window (what a
    resize or a widget click costs).
    """
    session = window.session
    key(window, "r")
    first, second, (point, to) = demo_drags(session.model)
    for p, q in (first, second):
        drag(window, current_position(session, p), q)
        run_ticks(window, ticks)
    start = current_position(session, point)
    mouse(window, "press", start)
    for f in DEMO_CAUGHT:
        mouse(window, "motion", start + f * (np.asarray(to) - start))
    if screenshot is not None:
        window.fig.canvas.draw()
        with atomic_path(screenshot) as tmp:
            window.fig.savefig(tmp, dpi=100)
    mouse(window, "release", start + DEMO_CAUGHT[-1] * (np.asarray(to) - start))
    run_ticks(window, ticks)
    if full:
        _more_edits(window, ticks)
    times = window.timings()
    times["draw"] = []
    for _ in range(5):
        t0 = time.perf_counter()
        window.fig.canvas.draw()
        times["draw"].append(time.perf_counter() - t0)
    return times


def _more_edits(window: PosingWindow, ticks: int) -> None:
    """The rest of a full scripted session: move, slider, space, freeze, remove."""
    session = window.session
    to = session.targets.to[0]
    drag(window, to, to + 0.3 * (session.targets.y(session.x)[0] - to))
    run_ticks(window, ticks)
    name = session.winch_names[0]
    window.sliders[name].set_val(0.5 * (session.model.lower[0] + session.model.upper[0]))
    key(window, " ")
    run_ticks(window, ticks)
    window.freeze_buttons[name].set_active(0)
    run_ticks(window, ticks)
    mouse(window, "press", session.targets.to[0], button=3)
    run_ticks(window, ticks)


def timing_table(times: dict) -> str:
    """Count, median and worst (ms) of each handler kind."""
    lines = [f"{'callback':<12} {'count':>6} {'median ms':>10} {'worst ms':>9}"]
    for k, v in times.items():
        if v:
            lines.append(f"{k:<12} {len(v):>6} {1e3 * np.median(v):>10.1f} {1e3 * max(v):>9.1f}")
    return "\n".join(lines)
