"""Contact forces per patch ("per finger"): each connected stretch of the
boundary touching one thing is one patch, and the patches add up."""

from pathlib import Path

import numpy as np
import pytest

from plush_opt.fem import contact_report
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import Model
from plush_opt.io import load_scene
from plush_opt.solve.equilibrium import solve_equilibrium

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"


@pytest.fixture(scope="module")
def hexapod():
    scene = load_scene(PROBLEMS / "hexapod_stand.yaml")
    return Model(scene, build_mesh(scene))


def _report(model, contraction):
    eq = solve_equilibrium(model, np.array(contraction, dtype=float))
    assert eq.converged, eq.status
    return eq.x, contact_report.report(model.contact, eq.x)


def test_lying_on_its_back_is_one_patch_and_standing_is_one_per_foot(hexapod):
    _, lying = _report(hexapod, [0.0, 0.0])
    assert [p["with"] for p in lying["patches"]] == ["ground"]
    x, standing = _report(hexapod, [10.0, 10.0])
    feet = standing["patches"]
    assert len(feet) == 2
    # one foot on each side, each carrying half of the (symmetric) body's weight
    assert feet[0]["at"][0] < 0 < feet[1]["at"][0]
    for foot in feet:
        assert all(x.reshape(-1, 2)[n][1] < 2.0 for n in foot["nodes"])   # its nodes are at the floor
    # the triangulation is not mirror-symmetric, nor then the discs the tendons
    # pull on: the split tends to half as the mesh is refined
    coarse, fine = _weight_split(feet, standing), _weight_split(*_feet_on(hexapod.scene, 2.5))
    assert fine < coarse < 1e-2
    assert fine < 1e-3


def _feet_on(scene, max_area: float):
    model = Model(scene, build_mesh(scene, max_area=max_area, announce=False))
    _, standing = _report(model, [10.0, 10.0])
    return standing["patches"], standing


def _weight_split(feet, report) -> float:
    """The largest relative departure of a foot's load from half the weight."""
    half = report["total_force"][1] / 2
    return max(abs(foot["force"][1] / half - 1) for foot in feet)


def test_patches_partition_the_nodes_and_add_up_to_the_totals(hexapod):
    _, rep = _report(hexapod, [20.0, 20.0])
    touched = sorted((e["node"], e["with"]) for e in rep["nodes"])
    in_patches = sorted((n, p["with"]) for p in rep["patches"] for n in p["nodes"])
    assert in_patches == touched
    for name, total in rep["total_by"].items():
        summed = np.sum([p["force"] for p in rep["patches"] if p["with"] == name], axis=0)
        assert np.allclose(summed, total, rtol=1e-12, atol=1e-15)


def test_the_gripper_reports_its_grip_on_the_ball_per_patch():
    scene = load_scene(PROBLEMS / "gripper_object.yaml")
    model = Model(scene, build_mesh(scene))
    _, rep = _report(model, [25.0, 0.0, 20.0])
    assert rep["patches"] and {p["with"] for p in rep["patches"]} == {"ball"}
    assert rep["patches"][0]["force"][1] > 0      # the ball pushes the arm up
