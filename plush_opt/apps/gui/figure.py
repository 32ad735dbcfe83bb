"""The posing window's figure: its layout, its artists and the blitting
that redraws only what changed. :mod:`.view` wires it to the session."""

from __future__ import annotations

import contextlib
import math
import textwrap
import time
from collections.abc import Callable

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle
from matplotlib.transforms import Bbox
from matplotlib.widgets import CheckButtons, Slider

from ...solve.equilibrium import solve_equilibrium
from ..plot import REST_COLOR, TARGET_COLOR, draw_pose

KEY_HELP = (
    "mouse\n"
    "  drag the body     add a target\n"
    "  drag a \u2715          move that target\n"
    "  right-click a \u2715   remove it\n"
    "keys\n"
    "  space   pause / run the loop\n"
    "  r       reset: scene contractions,\n"
    "          no targets\n"
    "  s       save result JSON + PNG\n"
    "  q       quit (stops the winches)"
)

# colours of the interactive parts (the pose itself uses plush_opt.plot's)
PREVIEW_COLOR = "#ff7f0e"
STATUS_FACE = "#f2f2f2"
# the status strip: its height (figure fraction: two status lines and the
# message at the default size), its font (points), the text's left margin
# (fraction of the width), and the monospace font's advance (DejaVu Sans
# Mono: 0.602 em) that says how many characters fit across
STRIP_HEIGHT, STATUS_FONT, STATUS_X, MONO_ADVANCE = 0.075, 9, 0.008, 0.602
STATUS_LINES = 2
# the pose axes' bottom (figure fraction): their x label clears the strip
POSE_BOTTOM = 0.145

# the pose axes show the rest body and the targets with this margin, as a
# fraction of their largest extent (room to drag a point outwards)
VIEW_MARGIN = 0.3
# a slider's handle sticks out of its axes by about this much (pixels): its
# blitted region includes it
HANDLE_OVERHANG = (12, 8)
# the tension colour scale grows by this factor past the largest tension
# seen, so that each growth (a full redraw) is rare
TENSION_GROWTH = 1.25
# panel layout: the winch rows start here (figure fraction, from the bottom)
# and share this much height at most
ROWS_TOP, ROWS_HEIGHT, ROW_MAX = 0.875, 0.52, 0.075


def nice_ceil(value: float) -> float:
    """The smallest of 1, 1.5, 2, 2.5, 3, 4, 5, 6, 8 times a power of ten
    that is >= value."""
    exp = math.floor(math.log10(value))
    for m in (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if m * 10.0**exp >= value:
            return m * 10.0**exp
    return 10.0 ** (exp + 1)


def tension_scale(model, equilibrium_options) -> float:
    """Top of the tension colour scale: the largest tension with every
    winch at its upper bound (one solve), so that colours compare across
    the session; the window still grows it if a pose goes beyond."""
    if not model.n_tendons:
        return 1.0
    # a tendon at rest pulls with about this: the scale is never below it
    floor = 2.0 * model.tendon_stiffness * model.tendon_smoothing
    eq = solve_equilibrium(model, model.upper, None, equilibrium_options)
    top = float(model.tendon_state(eq.x, model.upper)["tension"].max()) if eq.converged else 0.0
    return nice_ceil(max(top, floor, 1e-9))


def grown_scale(tension_max: float, tension: np.ndarray) -> float:
    """The colour scale's top after a pose with these tensions."""
    if tension.size and tension.max() > tension_max:
        return nice_ceil(TENSION_GROWTH * float(tension.max()))
    return tension_max


def boundary_edges(triangles):
    """Edges used by one triangle only: the outline (and holes) of the mesh."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return edges[counts[inverse.reshape(-1)] == 1]


@contextlib.contextmanager
def no_redraws(canvas):
    """Hold back the full redraws widgets ask for while they are built (on
    Agg each is done at once)."""
    canvas.draw_idle = lambda *args, **kwargs: None
    try:
        yield
    finally:
        del canvas.draw_idle


def pose_axes(fig, model, x, contraction, tension_max: float):
    """The big axes on the left: the pose over the rest outline, targets,
    the drag preview, and the tension colour bar. Returns (ax, artists,
    legend handles)."""
    ax = fig.add_axes([0.055, POSE_BOTTOM, 0.58, 0.955 - POSE_BOTTOM])
    artists = draw_pose(ax, model, x, contraction, None, show_rest=False, colorbar=False)
    artists["tendons"].set_clim(0.0, tension_max)
    outline = model.X.reshape(-1, 2)[boundary_edges(model.mesh.triangles)]
    ax.add_collection(LineCollection(outline, colors=REST_COLOR, linewidths=1.0,
                                     linestyles=(0, (4, 3)), zorder=1.5))
    artists["target_lines"] = ax.add_collection(LineCollection(
        [], colors=TARGET_COLOR, linestyles="dotted", linewidths=1.2, zorder=7))
    artists["targets"], = ax.plot([], [], "x", color=TARGET_COLOR, ms=11, mew=2.5, zorder=9)
    artists["points"], = ax.plot([], [], "o", mfc="white", mec=TARGET_COLOR, mew=1.5, ms=6, zorder=8)
    artists["preview_line"], = ax.plot([], [], "--", color=PREVIEW_COLOR, lw=1.5, zorder=10)
    artists["preview"], = ax.plot([], [], "x", color=PREVIEW_COLOR, ms=12, mew=2.5, alpha=0.8,
                                  zorder=10)
    artists["grab"], = ax.plot([], [], "o", color=PREVIEW_COLOR, ms=7, zorder=10)
    ax.set_title(f"{model.scene.name}: drag the body to pose it", fontsize=11, loc="left")
    ax.grid(True, alpha=0.15)
    legend = [Line2D([], [], color=REST_COLOR, ls=(0, (4, 3)), label="rest outline"),
              Line2D([], [], marker="^", ls="", color="#222222", label="pin"),
              Line2D([], [], marker="x", ls="", color=TARGET_COLOR, mew=2, label="target"),
              Line2D([], [], marker="o", ls="", mfc="white", mec=TARGET_COLOR,
                     label="its body point")]
    cax = fig.add_axes([0.645, POSE_BOTTOM, 0.01, 0.955 - POSE_BOTTOM])
    cb = fig.colorbar(artists["tendons"], cax=cax)
    cb.set_label(f"tendon tension [{model.scene.units.force}]", fontsize=9)
    cb.ax.tick_params(labelsize=8)
    return ax, artists, legend


def fit_limits(ax, fig, X, targets) -> None:
    """Rest body and targets with a margin, stretched to the axes' shape
    (equal scales without matplotlib moving the limits later)."""
    lo, hi = X.min(axis=0), X.max(axis=0)
    if targets.n_targets:
        lo = np.minimum(lo, targets.to.min(axis=0))
        hi = np.maximum(hi, targets.to.max(axis=0))
    centre, half = (lo + hi) / 2, (hi - lo) / 2 + VIEW_MARGIN * float((hi - lo).max())
    box = ax.get_position(original=True)
    w_in, h_in = fig.get_size_inches()
    ratio = (box.height * h_in) / (box.width * w_in)       # height / width of the box
    if half[1] / half[0] < ratio:
        half[1] = half[0] * ratio
    else:
        half[0] = half[1] / ratio
    ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
    ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
    ax.set_aspect("equal", adjustable="box")


def winch_panel(fig, model, contraction, frozen, legend, on_slider: Callable, on_freeze: Callable):
    """The right-hand panel: one slider and one freeze toggle per winch,
    the key help and the legend. Returns (sliders, freeze buttons) by winch name."""
    left, width = 0.745, 0.15
    fig.text(0.705, 0.935, f"Winch contractions [{model.scene.units.length}]", fontsize=11, weight="bold")
    row = min(ROW_MAX, ROWS_HEIGHT / max(model.n_winches, 1))
    sliders, buttons = {}, {}
    with no_redraws(fig.canvas):
        for i, name in enumerate(model.winch_names):
            y = ROWS_TOP - i * row
            s = Slider(fig.add_axes([left, y, width, 0.03]), name, float(model.lower[i]),
                       float(model.upper[i]), valinit=float(contraction[i]), valfmt="%.2f")
            s.label.set_fontsize(10)
            s.valtext.set_fontsize(9)
            s.valtext.set_x(1.06)     # clear of the handle at either bound
            s.label.set_x(-0.07)
            s.on_changed(lambda value, i=i: on_slider(i, value))
            sliders[name] = s
            bax = fig.add_axes([left + width + 0.045, y - 0.008, 0.07, 0.046])
            bax.set_frame_on(False)
            b = CheckButtons(bax, ["freeze"], [bool(frozen[i])], useblit=False)
            for text in b.labels:
                text.set_fontsize(9)
            b.on_clicked(lambda label, i=i: on_freeze(i))
            buttons[name] = b
    help_top = ROWS_TOP - model.n_winches * row - 0.02
    fig.text(0.705, help_top, KEY_HELP, fontsize=8.5, family="monospace", va="top",
             linespacing=1.35, color="#333333")
    # the legend lives in the panel: the body never covers it
    fig.legend(handles=legend, loc="lower left", bbox_to_anchor=(0.7, 0.075), fontsize=8.5,
               frameon=False, ncols=2)
    return sliders, buttons


def status_strip(fig):
    """The status strip at the bottom: (its axes, status text, message
    text); the status text holds :data:`STATUS_LINES` lines, the message one."""
    sax = fig.add_axes([0.0, 0.0, 1.0, STRIP_HEIGHT])
    sax.set_axis_off()
    sax.add_patch(Rectangle((0, 0), 1, 1, transform=sax.transAxes, facecolor=STATUS_FACE,
                            edgecolor="#cccccc"))
    status = sax.text(STATUS_X, 0.94, "", family="monospace", fontsize=STATUS_FONT, va="top", linespacing=1.15)
    message = sax.text(STATUS_X, 0.17, "", family="monospace", fontsize=STATUS_FONT, va="center",
                       color="#555555")
    return sax, status, message


def status_columns(fig) -> int:
    """How many characters of the status strip's monospace font fit across
    the window as it is now (it follows resizes)."""
    char = STATUS_FONT * fig.dpi / 72.0 * MONO_ADVANCE
    return max(20, int(fig.bbox.width * (1.0 - 2 * STATUS_X) / char))


def wrap_status(text: str, columns: int, sep: str = "  |  ") -> str:
    """``text``'s ``sep``-separated parts packed into lines of at most
    ``columns`` characters (a part longer than a line is wrapped itself)."""
    lines: list[str] = []
    for part in text.split(sep):
        pieces = [part] if len(part) <= columns else textwrap.wrap(part, columns)
        if lines and len(lines[-1]) + len(sep) + len(pieces[0]) <= columns:
            lines[-1] += sep + pieces.pop(0)
        lines += pieces
    return "\n".join(lines)


def region_bboxes(ax, status_ax, sliders, buttons) -> dict:
    """Pixel boxes of the blitted regions (after a draw: they follow resizes)."""
    strip = status_ax.bbox
    middle = strip.y0 + 0.33 * strip.height        # between the status lines and the message
    boxes = {"pose": ax.bbox.frozen(),
             "status": Bbox.from_extents(strip.x0, middle, strip.x1, strip.y1),
             "message": Bbox.from_extents(strip.x0, strip.y0, strip.x1, middle)}
    dx, dy = HANDLE_OVERHANG
    for name, s in sliders.items():
        b, right = s.ax.bbox, buttons[name].ax.bbox.x0
        boxes[f"slider:{name}"] = Bbox.from_extents(b.x0 - dx, b.y0 - dy, right, b.y1 + dy)
    return boxes


class Blitter:
    """Draws what changed over saved backgrounds of a few regions (the pose
    axes, each slider, the status lines), so that an iterate costs the mesh
    and a few texts, not the whole window.

    Parameters
    ----------
    fig : the figure.
    regions : region name -> its animated artists.
    bboxes : () -> region name -> pixel box (called after each full draw).
    state : region name -> what it shows (a region is redrawn when this
        changes); None for the pose, which is redrawn when :attr:`pose_changed`.
    periods : region name -> seconds between its redraws at most.
    """

    def __init__(self, fig, regions: dict, bboxes: Callable[[], dict], state: Callable,
                 periods: dict[str, float]):
        self.fig = fig
        self.regions = regions
        self.bboxes = bboxes
        self.state = state
        self.periods = periods
        self.backgrounds = None       # region -> (bbox, saved pixels), after a full draw
        self.drawn = {}               # region -> what it shows
        self.drawn_at = {}            # region -> when it was last blitted
        self.pose_changed = True
        for artists in regions.values():
            for artist in artists:
                artist.set_animated(True)

    def on_draw(self, event) -> None:
        """After a full draw (first show, resize, a widget click): keep the
        backgrounds of the regions, then draw their artists on them."""
        canvas = self.fig.canvas
        if canvas.is_saving() or not canvas.supports_blit:
            return
        self.backgrounds = {k: (b, canvas.copy_from_bbox(b)) for k, b in self.bboxes().items()}
        for region, artists in self.regions.items():
            for artist in artists:
                self.fig.draw_artist(artist)
            self.drawn[region] = self.state(region)
        self.pose_changed = False

    def refresh(self) -> bool:
        """Blit the regions that changed (each at most once per its period;
        one left behind is drawn by a later call), or ask for a full redraw
        when there are no backgrounds yet. Returns True for a full redraw."""
        canvas = self.fig.canvas
        if self.backgrounds is None:
            canvas.draw_idle()
            return True
        now = time.perf_counter()
        for region, artists in self.regions.items():
            if region == "pose":
                if not self.pose_changed:
                    continue
                self.pose_changed = False
            else:
                state = self.state(region)
                if state == self.drawn.get(region):
                    continue
                if now - self.drawn_at.get(region, -math.inf) < self.periods.get(region, 0.0):
                    continue
                self.drawn[region] = state
                self.drawn_at[region] = now
            bbox, background = self.backgrounds[region]
            canvas.restore_region(background)
            for artist in artists:
                self.fig.draw_artist(artist)
            canvas.blit(bbox)
        return False
