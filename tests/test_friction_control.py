"""Control and export of a friction scene keep the robot's history: the
Controller drives the path-dependent plant the one factory chose, the
posing window's drag loop follows the friction state on screen, and an
export uses the state a result recorded (or says which history it assumed).

problems/gripper_friction.yaml on a coarse mesh (COARSE) keeps them fast.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from plush_opt import load
from shipped import ROOT, with_max_area

FRICTION = ROOT / "problems" / "gripper_friction.yaml"
COARSE = 150.0          # max_area (mm^2): ~140 nodes, enough for the stick/slip paths
SAME = 1e-6             # poses reached the same way agree to solver tolerance (mm)
HISTORY = 1e-3          # poses reached by other histories differ by more (mm)


@pytest.fixture(scope="module")
def friction_problem():
    return load(FRICTION, max_area=COARSE)


@pytest.fixture
def coarse_file(tmp_path):
    """gripper_friction.yaml with the coarse mesh, for the command line."""
    return with_max_area(FRICTION, tmp_path, COARSE, "gripper_friction.yaml")


def run(*args):
    return subprocess.run([sys.executable, "-m", "plush_opt", *args], capture_output=True, text=True,
                          timeout=300)


def round_trip(p):
    """The robot driven left 0 -> 15 -> 8 mm: a state a fresh path to
    left = 8 does not reach."""
    from plush_opt.solve.friction_path import start_state
    from plush_opt.solve.friction_solve import drive
    fm = p.plant.friction_model
    up = drive(fm, start_state(fm), p.contraction_vector({"left": 15.0}))
    return drive(fm, up.friction, p.contraction_vector({"left": 8.0}))


# -- the low-level loop --------------------------------------------------------

def test_controller_follows_the_plant_the_one_factory_chose(friction_problem):
    """The loop does not choose: the plant made from the model (by the one
    factory) is path-dependent for a friction scene, history-free without."""
    from plush_opt.control import Controller
    from plush_opt.solve.plant import ElasticPlant, FrictionPlant
    p = friction_problem
    assert type(Controller(p.model, p.targets).plant) is FrictionPlant and p.plant.path_dependent
    plain = load(ROOT / "problems" / "gripper.yaml", max_area=COARSE)
    assert type(Controller(plain.model, plain.targets).plant) is ElasticPlant
    assert not plain.plant.path_dependent


# -- the posing window's drag loop ---------------------------------------------

@pytest.mark.slow
def test_gui_drag_loop_follows_the_friction_state_on_screen(friction_problem):
    from plush_opt.apps.gui.session import PosingSession
    from plush_opt.solve.friction_path import check_state
    from plush_opt.solve.friction_solve import drive
    p = friction_problem
    fm = p.plant.friction_model
    session = PosingSession(p)
    for c in (15.0, 8.0):
        session.set_contraction("left", c)
    before = session.equilibrium.friction
    assert np.max(np.abs(before.x - round_trip(p).x)) <= SAME
    fresh = p.equilibrium({"left": 8.0})
    assert np.max(np.abs(fresh.x - before.x)) > HISTORY          # the history matters here
    session.move_target(0, p.targets.to[0] + [-5.0, 0.0])         # a drag runs the loop
    shown = [it for it in (session.tick() for _ in range(4)) if it is not None]
    assert len(shown) >= 3 and session.controller.plant is session.pose.plant
    assert session.controller.plant.path_dependent
    # the loop started from the state on screen, and every iterate shown is
    # the robot driven there from the one before
    assert np.max(np.abs(shown[0].x - before.x)) <= SAME
    for prev, it in zip(shown, shown[1:]):
        eq = drive(fm, prev.equilibrium.friction, it.contraction)
        assert eq.converged and np.max(np.abs(eq.x - it.x)) <= SAME
        assert not check_state(fm, it.equilibrium.friction)
    assert shown[-1].objective < shown[0].objective
    # a slider move continues from the state the loop left
    session.set_contraction("grip", 3.0)
    after = drive(fm, shown[-1].equilibrium.friction, session.contraction)
    assert np.max(np.abs(session.x - after.x)) <= SAME
    # the saved result is that pose, certified at its segment rest lengths
    from spec_checker import check_result
    doc = check_result(session.result())
    assert np.max(np.abs(np.asarray(doc["nodes"]).reshape(-1) - session.x)) <= SAME
    assert doc["min_hessian_eigenvalue"] > 0 and doc["friction_path"]["from"] == "the pose on screen before"
    left = next(t for t in doc["model"]["tendons"]["list"] if t["name"] == "left")
    k = [fm.model.scene.tendons[t].name for t in fm.tendons].index("left")
    seg = np.flatnonzero(fm.seg_tendon == fm.tendons[k])
    assert np.allclose(left["segment_rest_lengths"], session.equilibrium.friction.rest[seg])


# -- export ----------------------------------------------------------------------

def _result_file(p, eq, path):
    from plush_opt.solve.result_file import result_dict
    doc = result_dict(p.model, p.targets, eq, method="forward", converged=eq.converged, status=eq.status,
                      total_s=0.0, solve_s=0.0, iterations=eq.iterations)
    path.write_text(json.dumps(doc))
    return doc


def _tensions(pose):
    return pose.cell_data["tension"][1]


@pytest.mark.slow
def test_export_of_a_result_keeps_its_recorded_state(friction_problem, coarse_file, tmp_path):
    meshio = pytest.importorskip("meshio")
    p = friction_problem
    eq = round_trip(p)
    result = tmp_path / "r.json"
    doc = _result_file(p, eq, result)
    out = run("export", str(coarse_file), "--result", str(result), "--out", str(tmp_path / "r"))
    assert out.returncode == 0, out.stderr
    assert "the state recorded (segment rest lengths)" in out.stderr and "recorded state:" not in out.stderr
    pose = meshio.read(tmp_path / "r" / "pose.vtu")
    X = p.model.X.reshape(-1, 2)
    assert np.max(np.abs(pose.points[:, :2] - np.asarray(doc["nodes"]))) <= SAME
    assert np.max(np.abs(pose.point_data["displacement"][:, :2] - (eq.x.reshape(-1, 2) - X))) <= SAME
    recorded = [T for t in doc["model"]["tendons"]["list"] for T in t["segment_tensions"]]
    assert np.allclose(_tensions(pose), recorded, rtol=1e-5, atol=1e-9)
    assert np.ptp(_tensions(pose)[:4]) > 0                          # friction: the segments differ
    # the problem file alone: a fresh path from the start state, and it says so
    fresh = run("export", str(coarse_file), "-c", "left=8", "--out", str(tmp_path / "f"))
    assert fresh.returncode == 0, fresh.stderr
    assert "from the scene's start state along a straight path" in fresh.stderr
    pose_f = meshio.read(tmp_path / "f" / "pose.vtu")
    assert np.max(np.abs(pose_f.points - pose.points)) > HISTORY
    # a result without the state: the fresh path, said
    for entry in doc["model"]["tendons"]["list"]:
        del entry["segment_rest_lengths"]
    result.write_text(json.dumps(doc))
    bare = run("export", str(coarse_file), "--result", str(result), "--out", str(tmp_path / "b"))
    assert bare.returncode == 0, bare.stderr
    assert "records no segment rest lengths" in bare.stderr and "start state" in bare.stderr
    assert np.max(np.abs(meshio.read(tmp_path / "b" / "pose.vtu").points - pose_f.points)) <= SAME


@pytest.mark.slow
def test_export_of_a_result_refuses_another_problem_or_a_result_as_source(coarse_file, tmp_path):
    pytest.importorskip("meshio")
    p = load(coarse_file)
    result = tmp_path / "r.json"
    _result_file(p, p.equilibrium(), result)
    other = run("export", str(ROOT / "problems" / "gripper.yaml"), "--result", str(result), "--out", str(tmp_path))
    assert other.returncode == 2 and "problem: 'gripper_friction', but gripper.yaml is 'gripper'" in other.stderr
    swapped = run("export", str(result), "--out", str(tmp_path))
    assert swapped.returncode == 2 and "--result" in swapped.stderr and "Traceback" not in swapped.stderr
    assert not (tmp_path / "pose.vtu").exists()


@pytest.mark.slow
def test_export_of_a_result_solved_on_another_mesh_uses_the_mesh_it_recorded(coarse_file, tmp_path):
    meshio = pytest.importorskip("meshio")
    p = load(coarse_file)              # the friction gripper on a coarser mesh than FRICTION's own
    result = tmp_path / "r.json"
    doc = _result_file(p, p.equilibrium({"left": 8.0}), result)
    out = run("export", str(FRICTION), "--result", str(result), "--out", str(tmp_path / "e"))
    assert out.returncode == 0, out.stderr
    pose = meshio.read(tmp_path / "e" / "pose.vtu")
    assert len(pose.points) == p.mesh.n_nodes != load(FRICTION).mesh.n_nodes
    assert np.max(np.abs(pose.points[:, :2] - np.asarray(doc["nodes"]))) <= SAME
    # a recorded mesh that is not one: one clear error naming the key
    doc["model"]["triangles"] = [[0, 1]]
    result.write_text(json.dumps(doc))
    bad = run("export", str(FRICTION), "--result", str(result), "--out", str(tmp_path / "b"))
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert "r.json: model.triangles[0]: expected three node indices" in bad.stderr


def test_run_log_export_drives_the_robot_command_by_command(friction_problem, tmp_path):
    from plush_opt.apps.export import run_frames
    p = friction_problem
    log = tmp_path / "run.jsonl"
    rows = [{"kind": "start", "event": "start", "t": 0.0, "commanded": {"left": 0.0, "right": 0.0, "grip": 0.0}}]
    rows += [{"kind": "set", "event": "command", "t": float(k + 1), "commanded": {"left": c, "right": 0.0, "grip": 0.0}}
             for k, c in enumerate((15.0, 8.0))]
    log.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    frames = run_frames(log, p)
    assert len(frames) == 3
    assert np.max(np.abs(frames[-1][1] - round_trip(p).x)) <= SAME
