"""Pictures people can read and compare: the pose picture's legend, names
and target errors, a fixed tension scale, and compare plots whose legends
are never cut off."""

from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from plush_opt.apps.compare.report import plot_anytime, plot_speed_error  # noqa: E402
from plush_opt.apps.plot import draw_pose  # noqa: E402
from plush_opt.io.units import Units  # noqa: E402
from shipped import ROOT  # noqa: E402


@pytest.fixture(scope="module")
def gripper():
    import plush_opt
    p = plush_opt.load(ROOT / "problems" / "gripper.yaml")
    return p, p.equilibrium({"left": 10.0, "grip": 5.0})


def test_pose_picture_has_legend_names_errors_and_a_fixed_scale(gripper):
    p, eq = gripper
    fig, ax = plt.subplots()
    artists = draw_pose(ax, p.model, eq.x, eq.contraction, p.targets, tension_max=50.0, labels=True)
    texts = " ".join(t.get_text() for t in ax.texts)
    for tendon in p.scene.tendons:
        assert tendon.name in texts and f"({tendon.winch})" in texts
    for e in p.targets.errors(eq.x):
        assert f"{e:.2f} mm" in texts
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "pins" in legend and "target" in legend
    assert artists["tendons"].get_clim() == (0.0, 50.0)      # the same scale in every picture
    plt.close(fig)


@pytest.mark.parametrize("name", ["gripper", "hexapod_stand"])
def test_the_pose_legend_hangs_below_the_x_label_of_a_tall_body_and_of_a_wide_one(name):
    """The legend once hung a fraction of the axes' height below them: on
    the wide, flat hexapod that put it over the x label."""
    import plush_opt
    from plush_opt.apps.plot import pose_figure
    p = plush_opt.load(ROOT / "problems" / f"{name}.yaml")
    x = p.model.X.reshape(-1)
    fig = pose_figure(p.model, x, np.zeros(p.model.n_winches), p.targets)
    fig.canvas.draw()
    ax = fig.axes[0]
    renderer = fig.canvas.get_renderer()
    label = ax.xaxis.label.get_window_extent(renderer)
    legend = ax.get_legend().get_window_extent(renderer)
    assert legend.y1 < label.y0                     # (display coordinates: y grows upwards)
    plt.close(fig)


def test_the_names_of_steps_close_in_time_do_not_run_into_each_other(monkeypatch):
    """A pose solved in a tenth of a second and its hold: their names once
    printed over each other ("pohseld") above a run's plot."""
    from plush_opt.apps import plot
    figures = []
    monkeypatch.setattr(plot, "save_figure", lambda fig, path, **kw: figures.append(fig))
    starts = [(0.0, "pose"), (0.35, "hold"), (2.35, "pose"), (2.42, "hold"), (4.42, "pose"), (4.5, "release")]
    rows = [{"t": t, "commanded": {"a": 1.0}, "step": k, "kind": kind} for k, (t, kind) in enumerate(starts)]
    rows.append({"t": 4.85, "commanded": {"a": 0.0}, "step": 5, "kind": "release"})
    plot.plot_run_log("r.png", rows, title="a run")
    fig = figures[0]
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        names = [a for a in fig.axes[0].texts if a.get_text() in ("pose", "hold", "release")]
        assert [a.get_text() for a in names] == [kind for _, kind in starts]
        boxes = [a.get_window_extent(renderer) for a in names]
        assert not any(b.overlaps(c) for i, b in enumerate(boxes) for c in boxes[i + 1:])
        assert all(b.y0 > fig.axes[0].get_window_extent(renderer).y1 for b in boxes)    # above the axes
        title = [t for t in fig.findobj(matplotlib.text.Text) if t.get_text() == "a run"]
        assert len(title) == 1 and not any(b.overlaps(title[0].get_window_extent(renderer)) for b in boxes)
    finally:
        plt.close(fig)


def _white_border(png) -> bool:
    img = plt.imread(png)[..., :3]
    return all(np.all(strip > 0.99) for strip in (img[:2], img[-2:], img[:, :2], img[:, -2:]))


def test_single_problem_compare_plots_keep_their_legends_whole(tmp_path):
    problem = SimpleNamespace(scene=SimpleNamespace(name="gripper", units=Units()))
    runs = [SimpleNamespace(problem="gripper", sweep="main", method=m, curve=[(0.1, 10.0, True), (0.5, 1.0, True)],
                            resolved=[(0.2, 5.0)], n_nodes=300, t_solve=0.5, fine_target_error=0.3 + k,
                            stable=True, converged=True, pareto=k == 0)
            for k, m in enumerate(("reparam", "clip", "bilevel"))]
    for plot, name in ((plot_anytime, "anytime.png"), (plot_speed_error, "speed.png")):
        path = plot(tmp_path / name, [problem], runs)
        assert _white_border(path), f"{name}: something is cut off at the edge"
