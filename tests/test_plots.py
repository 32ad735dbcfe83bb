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
