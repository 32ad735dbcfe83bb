"""The problem file's ``units:`` key (issue 35): a file written in metres and
newtons says so, and every output (summary line, result file, pictures,
the posing window, warnings) speaks in its units; files without the key
still say mm, N and MPa; a unit name outside the accepted set is one line
naming the file and the key. Units are labels: the numbers are the same."""

from __future__ import annotations

import json
import logging

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from cli_helpers import cli, one_error_line  # noqa: E402
from plush_opt.base.errors import SceneError  # noqa: E402
from plush_opt.io import load_scene  # noqa: E402
from plush_opt.io.plausibility import plausibility_warnings  # noqa: E402
from plush_opt.io.problem_file import scene_from_dict  # noqa: E402
from plush_opt.io.units import Units  # noqa: E402
from plush_opt.io.yaml_reader import read_yaml  # noqa: E402
from shipped import ROOT  # noqa: E402

#: a 0.2 m x 0.02 m strip of felt in metres, newtons and pascals, clamped at
#: its left end, one tendon along its top, one target at its tip; SMOOTHING
#: is filled in (a metre-sized one, or the docs' 0.05)
METRES = """\
format: plush-opt/1
name: strip_m
units: {{length: m, force: N}}
mesh:
  outline: [[0, -0.01], [0.2, -0.01], [0.2, 0.01], [0, 0.01]]
  max_area: 4.0e-6
material: {{model: neo_hookean, youngs_modulus: 2.0e+4, poisson_ratio: 0.3, thickness: 0.03}}
pins: {{stiffness: 1.0e+7, at: [[0, -0.01], [0, 0.01]], box: [0, -0.01, 0, 0.01]}}
winches: [{{name: pull, bounds: [0.0, 0.02]}}]
tendons:
  stiffness: 100.0
  smoothing: {smoothing}
  list:
    - {{name: top, winch: pull, path: [[0.19, 0.008], [0.1, 0.008], [0.0, 0.008]]}}
targets:
  - {{at: [0.2, 0.0], to: [0.19, 0.02]}}
"""


@pytest.fixture
def metres(tmp_path):
    path = tmp_path / "strip_m.yaml"
    path.write_text(METRES.format(smoothing="1.0e-4"))
    return path


def test_the_units_key_names_length_force_and_what_follows():
    assert (Units().length, Units().force, Units().stress) == ("mm", "N", "MPa")
    assert Units().density == "t/mm^3" and Units().mass == "t"
    si = Units(length="m", force="N")
    assert (si.stress, si.mass, si.density, si.gravity) == ("Pa", "kg", "kg/m^3", "m/s^2")
    assert Units(length="mm", force="mN").stress == "mN/mm^2"       # written out, not renamed
    assert Units(length="mm", force="mN").density == "kg/mm^3"
    assert Units(length="cm", force="N").stress == "N/cm^2"
    assert Units(length="cm", force="N").density == "N s^2/cm^4"    # no named mass: written out
    assert Units(length="m", force="kN").stress == "kPa"
    with pytest.raises(ValueError, match=r"^units.length: 'meter' is not one of um, mm, cm, m, in$"):
        Units(length="meter")


def test_a_file_in_metres_loads_with_its_units_and_without_unit_warnings(metres, caplog):
    with caplog.at_level(logging.WARNING, logger="plush_opt"):
        scene = load_scene(metres)
    assert scene.units == Units(length="m", force="N") and scene.units.stress == "Pa"
    assert caplog.records == []                 # 0.2 m and 2e4 Pa are plausible in m and Pa


def test_the_docs_smoothing_in_a_metres_file_is_named_in_metres(tmp_path):
    """The issue's case: 0.05 on a body 0.2 m long curls it at zero contraction."""
    path = tmp_path / "curl.yaml"
    path.write_text(METRES.format(smoothing="0.05"))
    lines = plausibility_warnings(load_scene(path))
    assert [line.split(":")[0] for line in lines] == ["tendons.smoothing"]
    assert lines[0].startswith("tendons.smoothing: 0.05 is 24.9 % of the body's size (0.201), both in m;")
    assert "units: length m, force N, so moduli in Pa" in lines[0]
    # the same file without its units key: also too small for mm, and says which key fixes it
    plain = scene_from_dict({k: v for k, v in read_yaml(path).items() if k != "units"}, "curl.yaml")
    lines = plausibility_warnings(plain)
    assert [line.split(":")[0] for line in lines] == ["mesh", "tendons.smoothing", "material"]
    assert "implausibly small in mm" in lines[0] and "units: {length: ..., force: ...}" in lines[0]


def test_gravity_in_mm_per_s2_in_a_metres_file_is_named(metres):
    doc = read_yaml(metres)
    doc["gravity"] = [0.0, -9810.0]                              # the docs' mm/s^2
    doc["material"]["density"] = 200.0
    lines = plausibility_warnings(scene_from_dict(doc, "g.yaml"))
    assert lines == ["gravity: 1e+03 times Earth's gravity (9.81 m/s^2): is it in mm/s^2? (the file says "
                     "units: length m, force N, so moduli in Pa)"]
    doc["gravity"] = [0.0, -9.81]
    assert plausibility_warnings(scene_from_dict(doc, "g.yaml")) == []


def test_a_modulus_is_judged_in_the_files_stress_unit(metres):
    doc = read_yaml(metres)
    doc["material"]["youngs_modulus"] = 2.0e12                   # 2 TPa: no soft body
    lines = plausibility_warnings(scene_from_dict(doc, "e.yaml"))
    assert len(lines) == 1 and lines[0].startswith(
        "material: Young's modulus 2e+12 is stiffer than any soft body in Pa (felt about 2e+04, silicone 1e+05-1e+07;")


def test_the_summary_line_and_the_result_file_say_metres_and_pascals(metres, tmp_path):
    out = tmp_path / "r.json"
    p = cli("solve", metres, "-c", "pull=0.002", "--method", "forward", "--out", out)
    assert p.returncode == 0, p.stderr
    line = p.stdout.strip().splitlines()[-1]
    assert line.startswith("strip_m: forward: converged") and "pull=0.0020 m;" in line, line
    assert "targets RMS error " in line and " m (worst " in line and "mm" not in line, line
    assert " N; " in line.split("residual ")[1], line
    doc = json.loads(out.read_text())
    assert doc["units"] == {"length": "m", "force": "N", "stress": "Pa", "mass": "kg", "density": "kg/m^3",
                            "gravity": "m/s^2", "time": "s"}
    assert "MPa" not in out.read_text() and "mm" not in json.dumps(doc["units"])


def test_default_files_still_say_mm_n_and_mpa(tmp_path):
    out = tmp_path / "r.json"
    p = cli("solve", ROOT / "problems" / "gripper.yaml", "--method", "forward", "--out", out)
    assert p.returncode == 0, p.stderr
    line = p.stdout.strip().splitlines()[-1]
    assert " mm; targets RMS error " in line and " mm (worst " in line, line
    doc = json.loads(out.read_text())
    assert doc["units"]["length"] == "mm" and doc["units"]["stress"] == "MPa" and doc["units"]["density"] == "t/mm^3"


def test_units_are_labels_the_solve_is_the_same(metres):
    """The same numbers with and without the units key give the same pose."""
    from plush_opt.problem import from_scene
    scene = load_scene(metres)
    plain = scene.replace(units=Units())
    a, b = (from_scene(s).equilibrium({"pull": 0.002}) for s in (scene, plain))
    assert np.array_equal(a.x, b.x)


def test_the_pose_picture_and_trace_speak_metres_and_newtons(metres):
    from plush_opt.apps.plot import pose_figure
    from plush_opt.problem import from_scene
    p = from_scene(load_scene(metres))
    eq = p.equilibrium({"pull": 0.002})
    fig = pose_figure(p.model, eq.x, eq.contraction, p.targets)
    try:
        ax = fig.axes[0]
        assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [m]", "y [m]")
        assert "pull = 0.00 m" in ax.get_title() and ax.get_title().rstrip().endswith(" m")
        assert fig.axes[1].get_ylabel() == "tendon tension [N]"
        texts = [t.get_text() for t in ax.texts]
        assert texts and all(not t.endswith(" mm") for t in texts) and any(t.endswith(" m") for t in texts)
    finally:
        plt.close(fig)


def test_the_sweep_plot_says_metres(metres):
    from plush_opt.apps.sweep import run_sweep
    from plush_opt.apps.sweep_plot import sweep_figure
    from plush_opt.problem import load
    doc = read_yaml(metres)
    doc["points"] = [[0.2, 0.0]]
    path = metres.with_name("points.yaml")
    import yaml
    path.write_text(yaml.safe_dump(doc))
    problem = load(path)
    _, states = run_sweep(problem, np.array([[0.001], [0.002], [0.001]]))
    fig = sweep_figure(problem, states, "pull")
    try:
        ax = fig.axes[0]
        assert ax.get_xlabel() == "contraction of pull [m]" and ax.get_ylabel() == "displacement [m]"
        assert ax.get_legend().get_texts()[0].get_text().endswith(" m$^2$")
    finally:
        plt.close(fig)


def test_the_posing_window_status_says_metres_and_newtons(metres):
    from plush_opt.apps.gui.session import PosingSession, status_line
    from plush_opt.problem import from_scene
    session = PosingSession(from_scene(load_scene(metres)))
    line = status_line(session)
    assert " m\u00b2 (rms " in line and "residual " in line and "T [N]: top " in line and "mm" not in line


@pytest.mark.parametrize("units, key, message", [
    ("{length: meter}", "units.length", "'meter' is not one of um, mm, cm, m, in"),
    ("{force: newton}", "units.force", "'newton' is not one of uN, mN, N, kN"),
    ("{length: m, stress: MPa}", "units.stress",
     "'MPa' does not follow from N and m: stress is force/length^2, Pa (units are labels: give length and force)"),
    ("{length: m, time: s}", "units.time", "unknown key; allowed keys: length, force, stress"),
    ("{length: 1}", "units.length", "expected a string, got number 1 (put it in quotes to make it a string)"),
    ("metres", "units", "expected a mapping, got string 'metres'"),
])
def test_a_bad_unit_is_one_line_naming_file_and_key(tmp_path, units, key, message):
    path = tmp_path / "bad.yaml"
    path.write_text(METRES.format(smoothing="1.0e-4").replace("units: {length: m, force: N}", f"units: {units}"))
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert str(err.value) == f"bad.yaml: {key}: {message}"


def test_a_bad_unit_exits_2_from_the_command_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(METRES.format(smoothing="1.0e-4").replace("length: m,", "length: meter,"))
    line = one_error_line(cli("solve", path))
    assert line == "plush-opt: error: bad.yaml: units.length: 'meter' is not one of um, mm, cm, m, in"


def test_a_result_file_with_a_bad_unit_is_refused_on_reading(tmp_path, metres):
    from plush_opt.solve.result_file import read_result
    out = tmp_path / "r.json"
    assert cli("solve", metres, "-c", "pull=0.002", "--method", "forward", "--out", out).returncode == 0
    assert read_result(out)["units"]["length"] == "m"
    doc = json.loads(out.read_text())
    doc["units"]["force"] = "lbf"
    out.write_text(json.dumps(doc))
    with pytest.raises(SceneError, match=r"r.json: units.force: 'lbf' is not one of uN, mN, N, kN$"):
        read_result(out)


def test_the_trace_and_run_pictures_take_the_problems_units(monkeypatch):
    from types import SimpleNamespace

    from plush_opt.apps import plot
    figures = []
    monkeypatch.setattr(plot, "save_figure", lambda fig, path, **kw: figures.append(fig))
    history = [SimpleNamespace(iteration=k, objective=1.0 / (k + 1), t_wall=0.1 * k) for k in range(3)]
    plot.plot_trace("t.png", history, units=Units(length="m", force="N"))
    rows = [{"t": t, "commanded": {"pull": t}, "measured": {"pull": t}, "step": 0, "kind": "move"} for t in (0.0, 1.0)]
    plot.plot_run_log("r.png", rows, length="m")
    plot.plot_trace("d.png", history)
    try:
        assert [ax.get_ylabel() for ax in figures[0].axes] == ["objective O [m$^2$]"] * 2
        assert figures[1].axes[0].get_ylabel() == "pull [m]"
        assert figures[2].axes[0].get_ylabel() == "objective O [mm$^2$]"
    finally:
        for fig in figures:
            plt.close(fig)


BOARD_M = """\
format: plush-board/1
name: strip_m
winches:
  - {name: pull, axis: 0, spool_radius: 0.006, ticks_per_rev: 12, gear_ratio: 100, direction: 1,
     limits: [0.0, 0.02], max_speed: 0.015}
"""


def test_a_run_of_a_metres_file_speaks_metres(metres, tmp_path, caplog):
    """The run's log messages and progress line use the problem's length unit
    (the board file's lengths are in it too)."""
    from plush_opt.apps.planner import ControlPlanner
    from plush_opt.apps.runs import run_script
    (tmp_path / "board.yaml").write_text(BOARD_M)
    script = tmp_path / "run.yaml"
    script.write_text(f"format: plush-opt-run/1\nproblem: {metres.name}\nboard: board.yaml\nrate: 20\n"
                      "steps:\n  - set: {pull: 0.005}\n  - hold: 0.1\n")
    with caplog.at_level(logging.INFO, logger="plush_opt"):
        run_script(script, dry_run=True, log_path=tmp_path / "run.jsonl", planner=ControlPlanner(metres))
    said = "\n".join(r.getMessage() for r in caplog.records)
    assert "pull 0.005 m" in said
    assert " mm" not in said
