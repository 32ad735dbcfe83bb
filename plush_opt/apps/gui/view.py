"""The posing window: a matplotlib figure over a :class:`PosingSession`.

Its handlers turn mouse, key, slider and toggle events into calls on the
session, then show the new state; its timer calls :meth:`PosingWindow.tick`
(one control iterate at most). See docs/gui.md.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.backend_bases import key_press_handler

from ...base.files import atomic_path
from ..plot import contact_segments
from . import figure as F
from .session import TIMES_KEPT, PosingSession, status_line

log = logging.getLogger(__name__)

# matplotlib backends that draw to files only: no window can open
NON_INTERACTIVE = ("agg", "pdf", "ps", "svg", "pgf", "cairo", "template")
HANDLER_KINDS = ("tick", "tick_blit", "full_redraw", "press", "motion", "release", "key",
                 "slider", "freeze")


class PosingWindow:
    """The window of a posing session: pose, sliders, freeze toggles,
    status line, and the handlers that drive the session.

    Parameters
    ----------
    session : :class:`PosingSession`
    figure : matplotlib Figure, optional (default: a new pyplot figure).

    Attributes
    ----------
    session : the session shown.
    fig, ax : the figure and its pose axes.
    sliders, freeze_buttons : widgets by winch name.
    artists : the pose's artists by name (``body``, ``tendons``, ``targets``,
        ``preview``, ...).
    status_text, message_text : the two lines of the status strip.
    timer : the timer that calls :meth:`tick` every ``options.interval_ms``.
    callback_times : kind -> seconds spent in each handler call: 'tick',
        'press', 'motion', 'release', 'key', 'slider', 'freeze';
        'full_redraw': redraws of the whole window asked for by a handler
        (synchronous on Agg, deferred to the event loop on a screen);
        'tick_blit': the ticks without a full redraw.
    """

    def __init__(self, session: PosingSession, figure=None):
        self.session = session
        self.options = session.options
        self.callback_times = {k: deque(maxlen=TIMES_KEPT) for k in HANDLER_KINDS}
        self._syncing = False         # widgets being set from the state: not user input
        self.mouse = TargetDrag(self)
        model = session.model
        self._tension_max = F.tension_scale(model, session.equilibrium_options)
        self._clim_drawn = self._tension_max
        fig = figure if figure is not None else plt.figure(figsize=self.options.figsize)
        self.fig = fig
        try:
            fig.canvas.manager.set_window_title(f"plush-opt: {model.scene.name}")
        except AttributeError:
            pass
        self.ax, self.artists, legend = F.pose_axes(fig, model, session.x, session.contraction,
                                                    self._tension_max)
        F.fit_limits(self.ax, fig, model.X.reshape(-1, 2), session.targets)
        self.sliders, self.freeze_buttons = F.winch_panel(
            fig, model, session.contraction, session.frozen, legend, self._on_slider, self._on_freeze)
        self._status_ax, self.status_text, self.message_text = F.status_strip(fig)
        self.blitter = self._blitter()
        self._connect()
        self.redraw()

    def _blitter(self) -> F.Blitter:
        a = self.artists
        pose = [a[k] for k in ("body", "tendons", "stoppers", "target_lines", "points",
                               "targets", "preview_line", "grab", "preview", "pins", "contact_forces")
                if k in a]
        pose.sort(key=lambda artist: artist.get_zorder())
        regions = {"pose": pose, "status": [self.status_text], "message": [self.message_text]}
        periods = {"status": self.options.status_period}
        for name, s in self.sliders.items():
            s.drawon = False          # drawn by the blitter
            regions[f"slider:{name}"] = [s.poly, s.valtext] + ([s._handle] if hasattr(s, "_handle") else [])
            periods[f"slider:{name}"] = self.options.slider_period
        return F.Blitter(self.fig, regions,
                         lambda: F.region_bboxes(self.ax, self._status_ax, self.sliders,
                                                 self.freeze_buttons),
                         self._region_state, periods)

    def _connect(self) -> None:
        canvas = self.fig.canvas
        self._cids = [
            canvas.mpl_connect("draw_event", self.blitter.on_draw),
            canvas.mpl_connect("button_press_event", self.mouse.on_press),
            canvas.mpl_connect("motion_notify_event", self.mouse.on_motion),
            canvas.mpl_connect("button_release_event", self.mouse.on_release),
            canvas.mpl_connect("key_press_event", self._on_key),
            canvas.mpl_connect("close_event", self._on_close),
        ]
        # our keys (space, r, s, q) replace matplotlib's defaults for them
        # ('r' home, 's' save, 'q' quit); the toolbar's other keys still work
        manager = getattr(canvas, "manager", None)
        if manager is not None and getattr(manager, "key_press_handler_id", None) is not None:
            canvas.mpl_disconnect(manager.key_press_handler_id)
            manager.key_press_handler_id = None
        self.timer = canvas.new_timer(interval=self.options.interval_ms)
        self.timer.add_callback(self._on_timer)

    # ------------------------------------------------------------ showing

    def _region_state(self, region: str):
        if region == "status":
            return self.status_text.get_text()
        if region == "message":
            return self.message_text.get_text()
        if region.startswith("slider:"):
            return self.sliders[region[7:]].valtext.get_text()
        return None

    def sync(self) -> None:
        """Widgets follow the session without calling back (no forward
        solve), then the window shows the new state."""
        s = self.session
        self._syncing = True
        try:
            for i, slider in enumerate(self.sliders.values()):
                if slider.val != s.contraction[i]:
                    slider.set_val(float(s.contraction[i]))
            for i, box in enumerate(self.freeze_buttons.values()):
                if box.get_status()[0] != bool(s.frozen[i]):
                    box.set_active(0)
        finally:
            self._syncing = False
        self.redraw()

    def redraw(self) -> None:
        """Move the artists to the session's state and show them."""
        s, model, a = self.session, self.session.model, self.artists
        xn = s.x.reshape(-1, 2)
        a["body"].set_verts(xn[model.mesh.triangles])
        if model.n_tendons:
            tension = model.tendon_state(s.x, s.contraction)["tension"]
            self._tension_max = F.grown_scale(self._tension_max, tension)
            a["tendons"].set_segments([xn[p] for p in model.tendon_paths])
            a["tendons"].set_array(tension)
            a["tendons"].set_clim(0.0, self._tension_max)
            ends = np.array([xn[p[0]] for p in model.tendon_paths])
            a["stoppers"].set_data(ends[:, 0], ends[:, 1])
        if "contact_forces" in a:
            a["contact_forces"].set_segments(contact_segments(model, s.x))
        t = s.targets
        if t.n_targets:
            y = t.y(s.x)
            a["targets"].set_data(t.to[:, 0], t.to[:, 1])
            a["points"].set_data(y[:, 0], y[:, 1])
            a["target_lines"].set_segments(np.stack([y, t.to], axis=1))
        else:
            for k in ("targets", "points"):
                a[k].set_data([], [])
            a["target_lines"].set_segments([])
        self.mouse.draw_preview()
        self.update_status()

    def update_status(self) -> None:
        """The status strip follows the session; then blit what changed."""
        self.status_text.set_text(F.wrap_status(status_line(self.session), F.status_columns(self.fig)))
        self.message_text.set_text(self.session.message)
        self.refresh()

    def refresh(self) -> None:
        if self._clim_drawn != self._tension_max:     # the colour bar must be redrawn too
            self._clim_drawn = self._tension_max
            self.blitter.backgrounds = None
        t0 = time.perf_counter()
        if self.blitter.refresh():
            self.callback_times["full_redraw"].append(time.perf_counter() - t0)

    # ------------------------------------------------------------ the timer

    def tick(self):
        """One timer callback: the session's tick (at most one iterate, then
        the board), then the window. Returns the iterate shown, or None."""
        t0 = time.perf_counter()
        full_redraws = len(self.callback_times["full_redraw"])
        shown = None
        try:
            shown = self.session.tick()
            if shown is not None:
                self.sync()
            else:
                self.update_status()
        finally:
            dt = time.perf_counter() - t0
            self.callback_times["tick"].append(dt)
            if len(self.callback_times["full_redraw"]) == full_redraws:
                self.callback_times["tick_blit"].append(dt)
        return shown

    def _on_timer(self) -> None:
        try:
            self.tick()
        except Exception:  # noqa: BLE001 - a failing tick must not kill the timer silently
            log.exception("tick failed")
            self.session.halt("error in the control loop (see the log); paused")

    def timings(self) -> dict[str, list[float]]:
        """Seconds per handler call by kind, plus 'iterate': the control
        loop's part of the ticks."""
        times = {k: list(v) for k, v in self.callback_times.items()}
        times["iterate"] = list(self.session.iterate_seconds)
        return {k: times[k] for k in ("tick", "tick_blit", "iterate") + HANDLER_KINDS[2:]}

    # ------------------------------------------------------------ events

    def timed(self, kind: str, t0: float) -> None:
        self.callback_times[kind].append(time.perf_counter() - t0)

    def _on_key(self, event) -> None:
        t0 = time.perf_counter()
        try:
            key = event.key
            if key == " ":
                self.session.toggle_pause()
                self.redraw()
            elif key == "r":
                self.mouse.drag = None
                self.session.reset()
                self.sync()
            elif key == "s":
                self.save()
            elif key == "q":
                self.close()
            else:
                key_press_handler(event, self.fig.canvas, getattr(self.fig.canvas, "toolbar", None))
        finally:
            self.timed("key", t0)

    def _on_slider(self, i: int, value: float) -> None:
        if self._syncing:
            return
        t0 = time.perf_counter()
        try:
            self.session.set_contraction(i, value)
            self.sync()
        finally:
            self.timed("slider", t0)

    def _on_freeze(self, i: int) -> None:
        if self._syncing:
            return
        t0 = time.perf_counter()
        try:
            status = self.freeze_buttons[self.session.winch_names[i]].get_status()[0]
            self.session.set_frozen(i, status)
            self.redraw()
        finally:
            self.timed("freeze", t0)

    def _on_close(self, event) -> None:
        self.shutdown()

    # ------------------------------------------------------------ the end

    def save(self, path=None) -> tuple[Path, Path]:
        """Write the session's result JSON and a PNG of the window next to
        it (same name, ``.png``); returns both paths."""
        path = self.session.save(path)
        png = path.with_suffix(".png")
        self.session.message = f"saved {path} and {png.name}"
        self.redraw()
        with atomic_path(png) as tmp:       # a full disk leaves no partial picture
            self.fig.savefig(tmp, dpi=100)
        self.blitter.backgrounds = None       # redraw everything after saving
        self.fig.canvas.draw_idle()
        return path, png

    def shutdown(self) -> None:
        """Stop the timer, the loop and the winches (idempotent; the
        window's close event calls it)."""
        self.timer.stop()
        self.session.shutdown()

    def close(self) -> None:
        """Stop everything and close the window (``q``)."""
        self.shutdown()
        plt.close(self.fig)

    def show(self) -> None:
        """Start the timer and run the window until it is closed."""
        self.timer.start()
        try:
            plt.show()
        finally:
            self.shutdown()


class TargetDrag:
    """Mouse handling on the pose axes: press on the body and drag to make
    a target, drag a target's cross to move it, right-click to remove it;
    the orange preview while dragging.

    Attributes
    ----------
    drag : {'kind': 'new'|'move', ...} during a drag, else None.
    """

    def __init__(self, window: PosingWindow):
        self.window = window
        self.drag = None

    def _toolbar_busy(self) -> bool:
        toolbar = getattr(self.window.fig.canvas, "toolbar", None)
        return getattr(toolbar, "mode", "") not in ("", None)

    def _data_per_pixel(self) -> float:
        inv = self.window.ax.transData.inverted()
        (x0, _), (x1, _) = inv.transform([(0.0, 0.0), (1.0, 0.0)])
        return abs(x1 - x0)

    def _target_near(self, event, include_points: bool):
        """Index of the target marker (or body point) within the pick radius, or None."""
        t = self.window.session.targets
        if not t.n_targets:
            return None
        spots = [t.to] + ([t.y(self.window.session.x)] if include_points else [])
        best, best_d = None, self.window.options.pick_radius
        for pts in spots:
            pix = self.window.ax.transData.transform(pts)
            d = np.hypot(pix[:, 0] - event.x, pix[:, 1] - event.y)
            k = int(np.argmin(d))
            if d[k] <= best_d:
                best, best_d = k, d[k]
        return best

    def on_press(self, event) -> None:
        t0 = time.perf_counter()
        try:
            if event.inaxes is not self.window.ax or self._toolbar_busy() or event.xdata is None:
                return
            if event.button == 3:
                k = self._target_near(event, include_points=True)
                if k is not None:
                    self.window.session.remove_target(k)
                    self.window.redraw()
                return
            if event.button == 1:
                self._start_drag(event)
        finally:
            self.window.timed("press", t0)

    def _start_drag(self, event) -> None:
        s = self.window.session
        k = self._target_near(event, include_points=False)
        if k is not None:
            self.drag = {"kind": "move", "k": k, "to": None}
            s.message = f"moving target {k + 1}"
            return
        tol = self.window.options.pick_radius * self._data_per_pixel()
        found = s.locate((event.xdata, event.ydata), tol=tol)
        if found is None:
            s.message = "press on the body to grab a point of it"
            self.window.update_status()
            return
        tri, beta = found
        self.drag = {"kind": "new", "triangle": tri, "beta": beta,
                      "to": (float(event.xdata), float(event.ydata))}
        s.message = "drag to where this point should go, release to set the target"
        self.window.redraw()

    def on_motion(self, event) -> None:
        if self.drag is None or event.inaxes is not self.window.ax or event.xdata is None:
            return
        t0 = time.perf_counter()
        self.drag["to"] = (float(event.xdata), float(event.ydata))
        self.draw_preview()
        self.window.refresh()
        self.window.timed("motion", t0)

    def on_release(self, event) -> None:
        d = self.drag
        if d is None or event.button != 1:
            return
        t0 = time.perf_counter()
        try:
            self.drag = None
            if event.inaxes is self.window.ax and event.xdata is not None:
                to = (float(event.xdata), float(event.ydata))
            else:
                to = d["to"]   # released outside the axes: the last position seen
            if to is not None:
                if d["kind"] == "new":
                    self.window.session.add_target(d["triangle"], d["beta"], to)
                else:
                    self.window.session.move_target(d["k"], to)
            self.window.redraw()
        finally:
            self.window.timed("release", t0)

    def draw_preview(self) -> None:
        a = self.window.artists
        self.window.blitter.pose_changed = True
        d = self.drag
        if d is None or d.get("to") is None:
            for k in ("preview", "preview_line", "grab"):
                a[k].set_data([], [])
            return
        x = self.window.session.x
        if d["kind"] == "new":
            start = d["beta"] @ x.reshape(-1, 2)[self.window.session.model.mesh.triangles[d["triangle"]]]
        else:
            start = self.window.session.targets.y(x)[d["k"]]
        to = d["to"]
        a["grab"].set_data([start[0]], [start[1]])
        a["preview_line"].set_data([start[0], to[0]], [start[1], to[1]])
        a["preview"].set_data([to[0]], [to[1]])
