"""A newcomer's rough edges (issue 35): targets from plain lists, the
documented plot and export calls, short reprs of results, pictures that
say what they show (a not-converged pose, log axes with readable ticks,
the sweep's units and coinciding curves), the posing window's status line
and a missing tkinter, and a bare ``plush-opt``. Figures are checked as
objects (texts, tick labels, colours), never by pixels."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.colors import to_hex  # noqa: E402

import plush_opt  # noqa: E402
from plush_opt.io.units import Units  # noqa: E402
from shipped import ROOT  # noqa: E402

#: the gripper's bar tips pulled down and in, symmetrically (reachable: O ends near 0)
GRIP = [{"at": [-78, 122], "to": [-68, 96]}, {"at": (78, 122), "to": [68, 96], "weight": 1.5}]


@pytest.fixture(scope="module")
def gripper():
    return plush_opt.load(ROOT / "problems" / "gripper.yaml")


@pytest.fixture(scope="module")
def gripped(gripper):
    q = gripper.with_targets(GRIP)
    return q, q.control(method="reparam")


# -- Python API: targets as the problem file writes them ---------------------------

def test_with_targets_takes_the_problem_files_target_list(gripper, gripped):
    q, result = gripped
    assert q.targets.n_targets == 2 and gripper.targets.n_targets == 3      # the original untouched
    assert q.targets.to.tolist() == [[-68.0, 96.0], [68.0, 96.0]] and q.targets.weight.tolist() == [1.0, 1.5]
    assert q.model is gripper.model and q.mesh is gripper.mesh               # shared, not rebuilt
    assert result.converged and np.all(q.targets.errors(result.x) < 0.5)
    assert gripper.with_targets([]).targets.n_targets == 0


@pytest.mark.parametrize("entries, message", [
    ([{"at": [70, 125]}], r"with_targets: targets\[0\]\.to: missing required key"),
    ([GRIP[0], {"at": [70, 125], "to": [1, "x"]}], r"with_targets: targets\[1\]\.to\[1\]: expected a number"),
    ([{"at": [500, 125], "to": [1, 2]}], r"with_targets: targets\[0\].at: point \(500, 125\) lies outside the body"),
    ([{"at": [70, 125], "to": [1, 2], "wieght": 2}], r"targets\[0\].wieght: unknown key \(did you mean 'weight'\?\)"),
    ([{"at": [70, 125], "to": [1, 2], "weight": 0}], r"targets\[0\].weight: must be > 0"),
    ({"at": [70, 125], "to": [1, 2]}, "with_targets: targets: expected a list of targets"),
])
def test_a_bad_target_is_one_clear_error_naming_index_and_key(gripper, entries, message):
    with pytest.raises(plush_opt.SceneError, match=message):
        gripper.with_targets(entries)


# -- Python API: plot and export ---------------------------------------------------

def test_plot_and_export_write_what_solve_plot_and_vtk_write(gripped, tmp_path):
    import meshio
    q, result = gripped
    png = plush_opt.plot(q, result, tmp_path / "pose.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    files = plush_opt.export(q, result, tmp_path / "vtk")
    assert [f.name for f in files] == ["pose.vtu", "trace.pvd"]
    mesh = meshio.read(files[0])
    assert np.allclose(mesh.points[:, :2], result.x.reshape(-1, 2))
    assert len(list((tmp_path / "vtk").glob("trace_*.vtu"))) == len(result.history)
    eq = q.equilibrium({"left": 5.0})
    assert [f.name for f in plush_opt.export(q, eq, tmp_path / "eq")] == ["pose.vtu"]
    assert plush_opt.plot(q, eq, tmp_path / "eq.png").stat().st_size > 10_000


def test_a_pose_that_is_not_converged_is_marked_in_red(gripper):
    from plush_opt.apps.plot import NOT_CONVERGED_COLOR, pose_figure
    eq = gripper.equilibrium({"left": 10.0})
    good = pose_figure(gripper.model, eq.x, eq.contraction, gripper.targets)
    bad = pose_figure(gripper.model, eq.x, eq.contraction, gripper.targets, converged=False,
                      status="line search failed")
    (g,), (b,) = good.axes[:1], bad.axes[:1]
    assert "NOT CONVERGED" not in g.get_title() + " ".join(t.get_text() for t in g.texts)
    assert b.get_title().endswith("NOT CONVERGED")
    assert any(t.get_text() == "NOT CONVERGED: line search failed" for t in b.texts)
    assert {to_hex(s.get_edgecolor()) for s in b.spines.values()} == {NOT_CONVERGED_COLOR}
    plt.close(good)
    plt.close(bad)


def test_solve_plot_of_a_run_that_did_not_converge_marks_its_picture(monkeypatch, tmp_path):
    import plush_opt.apps.plot as plot
    from plush_opt.apps.cli import main
    drawn = {}
    monkeypatch.setattr(plot, "plot_pose", lambda *a, **kw: drawn.update(kw))
    code = main(["solve", str(ROOT / "problems" / "gripper.yaml"), "--max-iterations", "1",
                 "--plot", str(tmp_path / "p.png")])
    assert code == 3
    assert drawn["converged"] is False and drawn["status"].startswith("iteration limit (1) reached")


# -- short reprs --------------------------------------------------------------------

def test_results_print_in_a_line_without_arrays(gripper, gripped):
    _, result = gripped
    text = repr(result)
    assert "\n" not in text and len(text) < 300 and "array" not in text, text
    assert text.startswith("ControlResult(method='reparam', reason='stationary', converged=True, objective=")
    assert "'left': " in text and f"iterations={result.stats.iterations}" in text
    eq = result.equilibrium
    n = eq.x.size
    assert f"x=<array ({n},) float64>" in repr(eq) and "contraction=[" in repr(eq) and len(repr(eq)) < 400
    for shown in (result.history[-1], result.stats):
        assert "\n" not in repr(shown) and len(repr(shown)) < 400 and "<Equilibrium converged>" in repr(
            result.history[-1])


def test_a_problems_targets_and_mesh_print_short(gripper):
    assert repr(gripper.targets).startswith("Targets(triangles=[")
    assert "to=[[-74, 80], [50, 124], [-26, 142]], weight=[1, 1, 1])" in repr(gripper.targets)
    assert repr(gripper.mesh).startswith(f"Mesh(X=<array ({gripper.mesh.n_nodes}, 2) float64>, triangles=<array (")
    assert len(repr(gripper.mesh)) < 600


def test_friction_and_contact_states_print_short():
    from plush_opt.fem.contact_friction import Lag
    from plush_opt.solve.contact_plant import ContactEquilibrium, ContactState
    p = plush_opt.load(ROOT / "problems" / "gripper_friction.yaml")
    eq = p.equilibrium({"grip": 5.0})
    for shown in (eq, eq.friction):
        assert "<array (" in repr(shown) and len(repr(shown)) < 600, repr(shown)
    assert repr(eq).startswith("FrictionEquilibrium(") and "steps_done=10" in repr(eq)
    lag = Lag(np.zeros((40, 2)), np.arange(12), np.zeros(12, int), np.zeros((12, 2)), np.ones(12))
    state = ContactState(eq.x, eq.contraction, lag)
    assert repr(state) == (f"ContactState(x=<array ({eq.x.size},) float64>, contraction=[0, 0, 5], lag=<Lag>)")
    assert repr(lag).startswith("Lag(anchor=<array (40, 2) float64>, node=<array (12,) int64>")
    fields = {f.name: getattr(eq, f.name) for f in dataclasses.fields(plush_opt.Equilibrium)}
    contact = ContactEquilibrium(**fields, contact=state, steps_done=3)
    assert repr(contact).startswith("ContactEquilibrium(x=<array (") and "steps_done=3" in repr(contact)


# -- pictures ------------------------------------------------------------------------

def _labels(axis) -> list[str]:
    """The tick labels drawn inside the view of ``axis``."""
    lo, hi = sorted(axis.get_view_interval())
    return [t.get_text() for t, v in zip(axis.get_majorticklabels(), axis.get_majorticklocs())
            if lo <= v <= hi and t.get_text()]


@pytest.mark.parametrize("times", [(0.034, 0.036, 0.035), (0.034, 0.09, 0.05), (0.5, 3.0, 40.0),
                                   (0.037, 0.15, 0.1)])
def test_compare_log_axes_carry_at_least_two_readable_ticks(times):
    from plush_opt.apps.compare.report import anytime_figure, speed_error_figure
    problem = SimpleNamespace(scene=SimpleNamespace(name="gripper", units=Units()))
    runs = [SimpleNamespace(problem="gripper", sweep="main", method=m, curve=[(0.1, 10.0, True), (0.5, 9.0, True)],
                            resolved=[], n_nodes=300, t_solve=t, fine_target_error=0.3 + 0.01 * k, stable=True,
                            converged=True, pareto=k == 0, element="P1")
            for k, (m, t) in enumerate(zip(("reparam", "clip", "bilevel"), times))]
    for make, axis in ((speed_error_figure, "xaxis"), (anytime_figure, "yaxis")):
        fig, _ = make([problem], runs)
        FigureCanvasAgg(fig).draw()
        labels = _labels(getattr(fig.axes[0], axis))
        assert len(labels) >= 2 and all(float(s) > 0 for s in labels), (make.__name__, labels)
        # ... none running into another (0.08, 0.09 and 0.1 once printed as "0.080.090.1")
        drawn = [t.get_window_extent() for t in getattr(fig.axes[0], axis).get_majorticklabels()
                 if t.get_text() and t.get_visible()]
        assert not any(a.overlaps(b) for i, a in enumerate(drawn) for b in drawn[i + 1:]), (make.__name__, labels)
        plt.close(fig)


def _sweep_states(curves, c):
    """Fake sweep states: point k of a one-point-per-node mesh displaced by curves[k]."""
    X = np.zeros((len(curves), 2))
    return [SimpleNamespace(contraction=np.array([ci]), nodes=X + np.array([[d[i], 0.0] for d in curves]))
            for i, ci in enumerate(c)], SimpleNamespace(
        winch_names=("grip",), scene=SimpleNamespace(name="strip", units=Units()),
        mesh=SimpleNamespace(X=X, point_nodes=np.arange(len(curves))))


def test_the_sweep_plot_says_mm_and_tells_coinciding_curves_apart():
    from plush_opt.apps.sweep_plot import sweep_figure
    c = np.array([0.0, 5.0, 10.0, 5.0, 0.0])
    loop = np.array([0.0, 1.0, 3.0, 2.0, 0.0])
    states, problem = _sweep_states([loop, loop, 2 * loop], c)
    fig = sweep_figure(problem, states, "grip")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "contraction of grip [mm]" and ax.get_ylabel() == "displacement [mm]"
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend[1].endswith("(over point 0's curve, within 0 mm)") and "over point" not in legend[0] + legend[2]
    lines = ax.get_lines()
    assert len({(str(line.get_linestyle()), line.get_marker()) for line in lines}) == 3
    assert "units" not in " ".join(legend + [ax.get_xlabel(), ax.get_ylabel()])
    plt.close(fig)


def test_a_sweep_of_a_scene_without_points_follows_its_targets_points(tmp_path):
    """hexapod_stand has targets and no `points`: its sweep's picture was
    empty and its CSV had no positions."""
    from plush_opt.apps.sweep import run_sweep, write_csv
    from plush_opt.apps.sweep_plot import sweep_figure
    from plush_opt.problem import load
    problem = load(ROOT / "problems" / "hexapod_stand.yaml")
    plant, states = run_sweep(problem, np.array([[2.0, 0.0], [4.0, 0.0], [2.0, 0.0]]))
    write_csv(problem, plant, states, tmp_path / "s.csv")
    header = (tmp_path / "s.csv").read_text().splitlines()[0].split(",")
    assert header[3:7] == ["x_0", "y_0", "x_1", "y_1"]
    fig = sweep_figure(problem, states, "a")
    try:
        ax = fig.axes[0]
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        assert [text.split(":")[0] for text in legend] == ["target point 0 (-40.0, 30.5)",
                                                            "target point 1 (40.0, 30.5)"]
        assert ax.get_title() == "hexapod_stand: target points as winch a moves, loading and unloading"
        rows = [line.split(",") for line in (tmp_path / "s.csv").read_text().splitlines()[1:]]
        front = [float(r[6]) for r in rows]            # the front corner rises as its leg curls, and comes back
        assert front[2] > front[1] > front[0] and front[3] < front[2]
    finally:
        plt.close(fig)


# -- the posing window ----------------------------------------------------------------

def test_the_status_line_fits_the_default_window(gripper):
    from plush_opt.apps.gui.session import PosingSession, status_line
    from plush_opt.apps.gui.view import PosingWindow

    class Board:                     # a board that takes everything
        winch_names = gripper.winch_names
        send = stop = close = lambda *a: None
        positions = moving = lambda self: None

    w = PosingWindow(PosingSession(gripper, Board(), None))
    try:
        w.update_status()
        w.fig.canvas.draw()
        renderer = w.fig.canvas.get_renderer()
        box, width = w.status_text.get_window_extent(renderer), w.fig.bbox.width
        assert len(status_line(w.session)) * 7 > width        # one line would not fit
        assert 0 <= box.x0 and box.x1 <= width, (box, width)
        assert w.status_text.get_text().replace("\n", "  |  ") == status_line(w.session)
        strip = w._status_ax.get_window_extent(renderer)
        assert box.y1 <= strip.y1 and w.message_text.get_window_extent(renderer).y1 < box.y0
        assert w.ax.xaxis.label.get_window_extent(renderer).y0 >= strip.y1     # nothing under the strip
    finally:
        w.close()
        plt.close("all")


def test_a_missing_tkinter_is_named_not_taken_for_a_missing_display(monkeypatch):
    import sys
    from plush_opt.apps.gui import run_gui
    monkeypatch.setitem(sys.modules, "tkinter", None)          # import tkinter -> ImportError
    with pytest.raises(plush_opt.SceneError, match=r"^tkinter is not installed: install python3-tk") as exc:
        run_gui(ROOT / "problems" / "gripper.yaml")
    assert "display" not in str(exc.value)


# -- the command line ----------------------------------------------------------------

def test_a_bare_plush_opt_prints_an_overview_and_exits_0(capsys):
    from plush_opt.apps.cli import build_parser, main
    assert main([]) == 0
    out = capsys.readouterr()
    assert out.err == "" and "docs/quickstart.md" in out.out
    commands = build_parser()._subparsers._group_actions[0].choices
    for name in commands:
        assert any(line.split()[:1] == [name] and len(line.split()) > 1 for line in out.out.splitlines()), name
    assert len(out.out.splitlines()) < 30
    with pytest.raises(SystemExit) as exc:      # options without a command stay a usage error
        main(["-q"])
    assert exc.value.code == 2
