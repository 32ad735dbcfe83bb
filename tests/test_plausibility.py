"""Valid values that are unlikely meant (issue 35): a file written in metres
and pascals with the docs' mm-sized smoothing, an attachment disc as wide as
the body, a max_area that builds a huge mesh. Each is a warning naming the
key, never a refusal or a repair; the shipped problems give none."""

import glob
import logging

import pytest

from cli_helpers import cli
from plush_opt.fem.mesh import build_mesh
from plush_opt.io import load_scene
from plush_opt.io.plausibility import (LARGE_MESH_NODES, SOLVE_SECONDS_PER_NODE, estimated_nodes,
                                      plausibility_warnings)
from shipped import ROOT

# the docs' finger in metres and pascals, with the docs' smoothing 0.05 (mm-sized)
METRES = """\
format: plush-opt/1
name: strip_in_metres
mesh:
  outline: [[0, -0.005], [0.1, -0.005], [0.1, 0.005], [0, 0.005]]
  max_area: 1.0e-6
material: {model: neo_hookean, youngs_modulus: 2.0e+4, poisson_ratio: 0.3, thickness: 0.03}
pins: {stiffness: 1.0e+7, at: [[0, -0.005], [0, 0.005]], box: [0, -0.005, 0, 0.005]}
winches: [{name: pull, bounds: [0.0, 0.02]}]
tendons:
  stiffness: 100.0
  smoothing: 0.05
  list:
    - {name: top, winch: pull, path: [[0.09, 0.003], [0.0, 0.003]]}
"""


def test_a_file_in_metres_and_pascals_is_warned_about_key_by_key(tmp_path, caplog):
    path = tmp_path / "m.yaml"
    path.write_text(METRES)
    with caplog.at_level(logging.WARNING, logger="plush_opt"):
        scene = load_scene(path)
    lines = plausibility_warnings(scene)
    assert [line.split(":")[0] for line in lines] == ["mesh", "tendons.smoothing", "material"]
    assert "the body is 0.1 across" in lines[0] and "is the file in other units?" in lines[0]
    assert lines[1].startswith("tendons.smoothing: 0.05 is 49.8 % of the body's size (0.1)")
    assert lines[2].startswith("material: Young's modulus 2e+04 is stiffer than any soft body in MPa")
    assert [r.getMessage() for r in caplog.records] == [f"m.yaml: {line}" for line in lines]


def test_the_warnings_reach_the_command_line_and_the_solve_still_runs(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(METRES)
    p = cli("solve", path, "-c", "pull=0.001", "--out", tmp_path / "r.json")
    assert p.returncode == 0, p.stderr
    warned = [line for line in p.stderr.splitlines() if line.startswith("plush-opt: warning: m.yaml: ")]
    assert len(warned) == 3, p.stderr


def test_an_attachment_disc_as_wide_as_the_body_is_named(tmp_path):
    text = (ROOT / "problems" / "cantilever.yaml").read_text()
    assert "  smoothing: 0.01\n" in text
    path = tmp_path / "c.yaml"
    path.write_text(text.replace("  smoothing: 0.01\n", "  smoothing: 0.01\n  attachment_radius: 60\n"))
    lines = plausibility_warnings(load_scene(path))
    assert lines == ["tendons.list[0].attachment_radius: 60 is 30 % of the body's size (200): a disc that "
                     "wide is not a stopper or a felt hole"]


def test_no_shipped_problem_is_warned_about():
    files = [f for f in glob.glob(str(ROOT / "problems" / "**" / "*.yaml"), recursive=True)
             if "/invalid/" not in f and "/bad/" not in f]
    assert len(files) > 10
    for f in files:
        assert plausibility_warnings(load_scene(f)) == [], f


def test_a_large_mesh_is_announced_with_its_size(caplog):
    scene = load_scene(ROOT / "problems" / "gripper.yaml")
    area = 0.12                             # about 62,000 P1 nodes on the gripper
    assert estimated_nodes(scene, area) > LARGE_MESH_NODES
    with caplog.at_level(logging.WARNING, logger="plush_opt"):
        mesh = build_mesh(scene, max_area=area)
    (record,) = caplog.records
    n = estimated_nodes(scene, area)
    assert record.getMessage() == (f"gripper.yaml: mesh.max_area: 0.12 gives about {n:,} P1 nodes (more than "
                                   f"{LARGE_MESH_NODES:,}): each equilibrium solve from rest takes about "
                                   f"{SOLVE_SECONDS_PER_NODE * n:.0f} s on one core, and control or --accuracy "
                                   "solves many (minutes); a larger max_area is faster")
    assert abs(mesh.n_nodes - n) <= 0.15 * mesh.n_nodes         # the estimate is close
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="plush_opt"):
        build_mesh(scene)                   # the file's own mesh: nothing to say
    assert not caplog.records


@pytest.mark.parametrize("name", ["mesh_over_cap.yaml"])
def test_a_mesh_over_the_cap_is_one_error_line(name):
    from cli_helpers import one_error_line
    line = one_error_line(cli("solve", ROOT / "problems" / "hard" / "invalid" / name))
    assert "limit 4000000" in line and "warning" not in line
