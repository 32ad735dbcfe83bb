"""Element and mesh from a tolerance: the error estimate, choose_mesh,
transfer_pose, and --accuracy on the command line."""

import dataclasses
import json
import math
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from plush_opt.solve.accuracy import (EXPECTED_ORDER, MAX_RATIO, SAFETY, Level, Resolution, bound_errors,
                                choose_mesh, default_levels, estimate_errors, estimate_levels, probe_contractions,
                                sweep, transfer_pose)
from plush_opt.apps.cantilever import beam_deflection
from plush_opt.solve.equilibrium import EquilibriumOptions
from plush_opt.base.errors import SceneError
from plush_opt.io import load_scene, scene_from_dict
from plush_opt.fem.mesh import build_mesh
from plush_opt.problem import load
from shipped import ROOT, with_max_area

CANTILEVER = ROOT / "problems" / "cantilever.yaml"
TIP = np.array([[200.0, 0.0]])


def _leg():
    return load_scene(ROOT / "problems" / "hexapod_leg.yaml")


def _coarse_leg(tmp_path, max_area=24.0):
    """The leg with a coarser own mesh, so that a whole level sweep is cheap."""
    return with_max_area(ROOT / "problems" / "hexapod_leg.yaml", tmp_path, max_area, "leg.yaml")


def run(*args):
    return subprocess.run([sys.executable, "-m", "plush_opt", *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=600)


# --- the estimate itself -------------------------------------------------

def test_estimate_of_a_geometric_sequence_is_its_true_error_times_the_safety_factor():
    # y_k = y* + C r^k along a line; nodes double per level
    r = 0.3
    ys = [np.array([[1.0 + 0.5 * r**k, 2.0]]) for k in range(5)]
    nodes = [100 * 2**k for k in range(5)]
    est = estimate_errors(ys, nodes, "P1")
    assert est[0]["estimate"] is None and est[-1]["estimate"] is None
    theory = 0.5 ** (EXPECTED_ORDER["P1"] / 2)          # 0.5: r = 0.3 is faster than P1's order
    for k in (1, 2, 3):
        true = 0.5 * r**k
        assert est[k]["ratio"] == pytest.approx(max(r, theory))
        assert est[k]["estimate"] >= true
        assert est[k]["estimate"] == pytest.approx(SAFETY * 0.5 * r**k * (1 - r) / (1 - max(r, theory)))
    # confirmed by the next level's estimate; the last estimate has none to confirm it
    assert [e["confirmed"] for e in est] == [False, True, True, False, False]


def test_a_coincidental_agreement_is_not_confirmed():
    # two coarse levels agree, the next difference is large again
    ys = [np.array([[0.0, v]]) for v in (0.0, 1.0, 1.05, 2.5, 2.9, 3.0)]
    nodes = [100 * 2**k for k in range(6)]
    early = estimate_errors(ys[:3], nodes[:3], "P2")      # before the next level is known
    assert math.isfinite(early[1]["estimate"]) and early[1]["estimate"] < 0.2
    assert not early[1]["confirmed"]
    est = estimate_errors(ys, nodes, "P2")
    assert not est[1]["confirmed"] and est[1]["estimate"] == est[2]["estimate"] == math.inf


def test_nested_levels_estimate_from_the_coarse_side_alone():
    # y_k = y* + C r^k, nodes 4x per level (a nested family): the estimate
    # needs levels k - 1 and k + 1 only, and stands without confirmation
    r = 0.2
    ys = [np.array([[1.0 + 0.5 * r**k, 2.0]]) for k in range(4)]
    nodes = [100 * 4**k for k in range(4)]
    est = estimate_errors(ys, nodes, "P2", nested=True)
    theory = 0.25 ** (EXPECTED_ORDER["P2"] / 2)          # 1/8: r = 0.2 is slower, observed wins
    for k in (1, 2):
        assert est[k]["ratio"] == pytest.approx(max(r, theory)) and est[k]["confirmed"]
        assert est[k]["estimate"] == pytest.approx(SAFETY * 0.5 * r**k * (1 - r) / (1 - r))
        # the true error, and within 2x of the error against the next level (4x the nodes)
        true, four = 0.5 * r**k, 0.5 * r**k * (1 - r)
        assert true <= est[k]["estimate"] <= 2 * four
    early = estimate_errors(ys[:3], nodes[:3], "P2", nested=True)
    assert early[1]["estimate"] == pytest.approx(est[1]["estimate"]) and early[1]["confirmed"]
    # a coincidentally small difference is never taken below the theory's ratio
    flat = [np.array([[0.0, v]]) for v in (0.0, 1.0, 1.0 + 1e-9, 1.1)]
    low = estimate_errors(flat, nodes, "P2", nested=True)
    assert low[1]["ratio"] == pytest.approx(theory)


def test_differences_that_do_not_shrink_give_no_estimate():
    # a point load in 2D: the displacement grows like log(1/h), differences stay put
    ys = [np.array([[0.0, math.log(2.0) * k]]) for k in range(4)]
    est = estimate_errors(ys, [100 * 2**k for k in range(4)], "P2")
    assert est[1]["ratio"] >= MAX_RATIO and est[1]["estimate"] == math.inf


def _level(y, estimate=None, confirmed=False):
    return Level("P2", Resolution(1.0), None, 0.0, 0.0, 0, [], np.array([[y]], dtype=np.float64),
                 estimate=estimate, confirmed=confirmed)


def test_a_level_without_its_own_estimate_is_bounded_through_a_confirmed_one():
    levels = [_level([0.0, 0.0], math.inf),          # coarse, differences too uneven to estimate
              _level([0.0, 0.2], 0.10, True),
              _level([0.0, 0.3], 0.05, True),
              _level([0.0, 0.31], 0.04, False)]       # its estimate is not confirmed: no anchor
    bound_errors(levels)
    # |y0 - y1| + 0.10 = 0.30 beats |y0 - y2| + 0.05 = 0.35
    assert levels[0].bound == pytest.approx(0.30) and levels[0].bound_via == 1
    # a confirmed level keeps its own estimate unless another level bounds it tighter
    assert levels[1].bound == pytest.approx(0.10) and levels[1].bound_via == 1
    assert levels[2].bound == pytest.approx(0.05) and levels[2].bound_via == 2
    assert levels[3].bound == pytest.approx(0.06) and levels[3].bound_via == 2
    assert levels[0].meets(0.3 + 1e-12) and not levels[0].meets(0.29)
    # never below the estimate it rests on
    assert all(lv.bound >= levels[lv.bound_via].estimate for lv in levels)
    # no confirmed level: no bound at all
    alone = [_level([0.0, 0.0], 0.1), _level([0.0, 0.1], math.inf)]
    bound_errors(alone)
    assert all(lv.bound is None and not lv.meets(1e9) for lv in alone)


def _nested(family, nodes, heights):
    return [Level("P2", Resolution(1.0, k, family), SimpleNamespace(n_nodes=n, n_elems=n // 2), 0.0, 0.0, 0, [],
                  np.array([[[0.0, h]]])) for k, (n, h) in enumerate(zip(nodes, heights))]


def test_an_estimate_is_withdrawn_where_finer_nested_levels_grow_again():
    # gripper_object at 0.25: family A steps 2.0 then 0.118 (its estimate at
    # 4,349 nodes from the theory ratio), family B grows 0.063 -> 0.093 at
    # 8,977 nodes and finer
    a = _nested(1.0, [1135, 4349, 17017], [0.0, 2.0, 2.118])
    b = _nested(2.0, [2317, 8977, 35329], [2.05, 2.113, 2.206])
    estimate_levels(a + b)
    assert a[1].estimate == pytest.approx(SAFETY * 0.118 / (1 - (4349 / 17017) ** 1.5))
    assert a[1].withdrawn and not a[1].confirmed
    assert b[1].estimate == math.inf and b[1].bound is None     # nothing left to bound the answer through
    assert a[1].row()["withdrawn"] is True
    # where B keeps shrinking, A's estimate stands (B's own is tighter)
    b = _nested(2.0, [2317, 8977, 35329], [2.05, 2.113, 2.133])
    estimate_levels(a + b)
    assert a[1].confirmed and not a[1].withdrawn and b[1].bound_via == 4
    # a growth far below the estimate (round-off) says nothing
    b = _nested(2.0, [2317, 8977, 35329], [2.1, 2.100001, 2.100003])
    estimate_levels(a + b)
    assert a[1].confirmed and not a[1].withdrawn
    # nor does one coarser than the estimated level
    b = _nested(2.0, [800, 3000, 12000], [2.05, 2.113, 2.206])
    estimate_levels(a[:2] + b[:2] + a[2:] + b[2:])
    assert not a[1].withdrawn


@pytest.mark.slow
def test_cantilever_estimate_bounds_the_error_against_a_fine_p2_solve():
    scene = load_scene(CANTILEVER)
    cs = probe_contractions(scene)
    opts = EquilibriumOptions(eigenvalue=False)
    levels = sweep(scene, "P2", [32.0, 16.0, 8.0, 4.0, 2.0, 1.0, 0.5], cs, TIP, 0.0, opts)
    fine = sweep(scene, "P2", [0.25], cs, TIP, 0.0, opts)[-1]   # 2x finer than the finest above
    deflection = -(fine.y[0, 0, 1] - 0.0)
    # the fine solve is beam theory's tip deflection to within the theory's own error
    assert deflection == pytest.approx(beam_deflection(scene), rel=0.02)
    estimated = [lv for lv in levels if lv.estimate is not None and math.isfinite(lv.estimate)]
    assert len(estimated) >= 2
    for lv in estimated:
        true = float(np.linalg.norm(lv.y - fine.y, axis=-1).max())
        assert true <= lv.estimate <= 4 * true, (lv.mesh.n_nodes, true, lv.estimate)
    # the bounds the pick uses hold too, also where a level has none of its own
    bounded = [lv for lv in levels if lv.bound is not None]
    assert len(bounded) == len(levels) and len([lv for lv in estimated if lv.confirmed]) < len(levels)
    for lv in bounded:
        true = float(np.linalg.norm(lv.y - fine.y, axis=-1).max())
        assert true <= lv.bound, (lv.mesh.n_nodes, true, lv.bound)
    # (every other area: with the root graded to the floor, halving P1's area
    # from 8 adds too few nodes to count as a finer level)
    p1 = sweep(scene, "P1", [8.0, 2.0, 0.5], cs, TIP, 0.0, opts)[1]
    true = float(np.linalg.norm(p1.y - fine.y, axis=-1).max())
    assert true <= p1.estimate                         # P1 locks in bending: large, but bounded


@pytest.mark.slow
def test_cantilever_nested_estimates_hold_and_are_within_2x_of_the_error_against_4x_finer():
    scene = load_scene(CANTILEVER)
    cs = probe_contractions(scene)
    opts = EquilibriumOptions(eigenvalue=False)
    levels = sweep(scene, "P2", default_levels(scene, "P2", refinements=2), cs, TIP, 0.0, opts)
    ref = sweep(scene, "P2", [Resolution(levels[0].max_area, 3, levels[0].max_area)], cs, TIP, 0.0,
                opts)[-1]
    checked = 0
    for k, lv in enumerate(levels):
        if lv.estimate is None:
            continue
        assert math.isfinite(lv.estimate)
        four = next(m for m in levels[k + 1:] if m.resolution.family == lv.resolution.family)
        true = float(np.linalg.norm(lv.y - ref.y, axis=-1).max())
        error_4x = float(np.linalg.norm(lv.y - four.y, axis=-1).max())
        assert true <= lv.estimate <= 2 * error_4x, (lv.mesh.n_nodes, true, error_4x, lv.estimate)
        checked += 1
    assert checked >= 1


@pytest.mark.slow
def test_tighter_tolerances_pick_finer_levels_and_a_met_one_is_within_it():
    scene = load_scene(CANTILEVER)
    tip = 0.214                                  # mm, the tip deflection
    reports = {}
    for rel in (1e-2, 1e-3):
        mesh, report = choose_mesh(scene, rel * tip, points=TIP)
        reports[rel] = report
        assert report["reached"] and report["status"] == "met"
        assert report["estimated_error"] <= rel * tip
        assert mesh.element.name == report["element"] and mesh.n_nodes == report["nodes"]
        picked = report["levels"][report["picked"]]
        assert picked["n_nodes"] == report["nodes"] and picked["element"] == report["element"]
    assert reports[1e-2]["t_solve_s"] <= reports[1e-3]["t_solve_s"] * 1.5 or \
        reports[1e-2]["nodes"] <= reports[1e-3]["nodes"]
    # both element types were tried where P1 could still be cheaper
    assert {row["element"] for row in reports[1e-2]["levels"]} == {"P1", "P2"}


@pytest.mark.slow
def test_unreachable_tolerance_says_so(tmp_path):
    scene = load_scene(_coarse_leg(tmp_path))
    levels = [scene.max_area * f for f in (4, 2, 1)]
    mesh, report = choose_mesh(scene, 1e-9, levels=levels)
    assert not report["reached"] and report["status"] == "tolerance_not_met"
    assert "NOT met" in report["summary"]
    assert report["element"] == "P2" and mesh.n_nodes == max(
        row["n_nodes"] for row in report["levels"] if row["element"] == "P2")


@pytest.mark.slow
def test_levels_solved_before_are_reused_not_solved_again(tmp_path, monkeypatch):
    import plush_opt.solve.accuracy as accuracy
    scene = load_scene(_coarse_leg(tmp_path))
    levels = [scene.max_area * f for f in (4, 2, 1)]
    calls = []
    solve_level = accuracy._solve_level
    monkeypatch.setattr(accuracy, "_solve_level", lambda *a, **k: calls.append(a[1]) or solve_level(*a, **k))
    solved = {}
    _, first = choose_mesh(scene, 1e-9, levels=levels, solved=solved)
    n_first = len(calls)
    assert n_first == len(solved) > 0
    assert {(e, res.max_area) for e, res in solved} == {(row["element"], row["max_area"])
                                                        for row in first["levels"]}
    _, again = choose_mesh(scene, 1e-9, levels=levels, solved=solved)
    assert len(calls) == n_first                       # nothing solved twice
    assert again["levels"] == first["levels"] and again["nodes"] == first["nodes"]


@pytest.mark.slow
def test_levels_that_are_not_finer_are_skipped():
    scene = load_scene(ROOT / "problems" / "gripper.yaml")
    # 400 and 200 give the same mesh (forced points and the angle bound rule)
    _, report = choose_mesh(scene, 100.0, levels=[400.0, 200.0, 50.0, 25.0], elements=("P1",))
    nodes = [row["n_nodes"] for row in report["levels"]]
    assert all(b >= 1.3 * a for a, b in zip(nodes, nodes[1:]))


def test_transfer_pose_reproduces_affine_motions_exactly():
    scene = _leg()
    A = np.array([[0.9, 0.2], [-0.1, 1.1]])
    b = np.array([3.0, -2.0])
    for element in ("P1", "P2"):
        s = dataclasses.replace(scene, element=element)
        coarse = build_mesh(s, max_area=24.0)
        fine = build_mesh(s, max_area=3.0)
        x_coarse = (coarse.X @ A.T + b).reshape(-1)
        x_fine = transfer_pose(coarse, x_coarse, fine)
        assert np.abs(x_fine - (fine.X @ A.T + b).reshape(-1)).max() <= 1e-9
        # onto the same mesh it is the identity
        assert np.abs(transfer_pose(coarse, x_coarse, coarse) - x_coarse).max() <= 1e-9


def test_control_problems_are_also_compared_mid_range():
    scene = _leg()
    cs = probe_contractions(scene)
    assert cs.shape == (2, 1) and cs[1, 0] == pytest.approx(7.5)


def test_default_levels_are_two_nested_families_at_twice_the_nodes_per_level():
    scene = _leg()
    levels = default_levels(scene, "P2")
    assert [res.refinements for res in levels] == [0, 0, 1, 1, 2, 2, 3]
    families = [res.family for res in levels]
    assert families[0::2] == [levels[0].max_area] * 4 and families[1::2] == [levels[1].max_area] * 3
    assert all(res.max_area == res.family for res in levels)
    s = dataclasses.replace(scene, element="P2")
    nodes = [build_mesh(s, max_area=res.max_area, graded=True, refinements=res.refinements).n_nodes
             for res in levels[:4]]
    growth = [b / a for a, b in zip(nodes, nodes[1:])]
    assert all(1.6 <= g <= 2.5 for g in growth), (nodes, growth)
    # within a family each level has about 4x the nodes of the one before
    assert nodes[2] / nodes[0] == pytest.approx(4.0, rel=0.1)


@pytest.mark.parametrize("tol", [-1.0, 0.0, float("nan"), float("inf"), True, "1"])
def test_bad_tolerance_is_refused(tol):
    with pytest.raises(SceneError, match=r"hexapod_leg.yaml: accuracy: the tolerance"):
        load(ROOT / "problems" / "hexapod_leg.yaml", accuracy=tol)


def test_bad_levels_are_refused():
    with pytest.raises(SceneError, match="levels"):
        choose_mesh(_leg(), 1.0, levels=[2.0, 4.0, 8.0])
    with pytest.raises(SceneError, match="levels"):
        choose_mesh(_leg(), 1.0, levels=[4.0, 2.0])


def test_explicit_mesh_is_returned_as_is():
    doc = {"format": "plush-opt/1", "name": "square",
           "mesh": {"nodes": [[0, 0], [10, 0], [10, 10], [0, 10]], "triangles": [[0, 1, 2], [0, 2, 3]]},
           "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                        "thickness": 1.0},
           "pins": {"stiffness": 1000.0, "at": [[0, 0], [10, 0]]},
           "winches": [{"name": "w", "bounds": [0.0, 1.0]}],
           "tendons": {"stiffness": 50.0, "smoothing": 0.01,
                       "list": [{"name": "t", "winch": "w", "path": [[10, 10], [0, 0]]}]}}
    mesh, report = choose_mesh(scene_from_dict(doc), 0.1)
    assert mesh.n_nodes == 4 and "explicit" in report["summary"] and not report["reached"]


# --- the command line ----------------------------------------------------

@pytest.mark.slow
def test_result_json_records_the_accuracy(tmp_path):
    out = tmp_path / "r.json"
    p = run("solve", str(CANTILEVER), "--method", "forward", "--accuracy", "0.002", "--out", str(out))
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    acc = doc["accuracy"]
    assert {"tolerance", "estimated_error", "element", "nodes"} <= set(acc)
    assert acc["tolerance"] == 0.002 and acc["element"] in ("P1", "P2") and acc["reached"]
    assert acc["estimated_error"] <= 0.002
    assert acc["nodes"] == len(doc["model"]["rest_nodes"])
    assert acc["graded"] is True            # the levels are graded towards the clamped end
    # max_area, graded and refinements rebuild the mesh the pose was solved on
    scene = dataclasses.replace(load_scene(CANTILEVER), element=acc["element"])
    again = build_mesh(scene, max_area=acc["max_area"], graded=True, refinements=acc["refinements"])
    assert again.n_nodes == acc["nodes"]
    assert np.allclose(again.X, np.array(doc["model"]["rest_nodes"]))
    assert acc["summary"] in p.stderr and "warning" not in p.stderr


#: the command line in a child whose default ladder is short: one refinement
#: of each family instead of three (what the command does with the levels is
#: the same, and the finest level has 4x, not 64x, the coarsest's nodes)
SHORT_LADDER = """
import sys
import plush_opt.solve.accuracy as accuracy
default_levels = accuracy.default_levels
accuracy.default_levels = lambda scene, element="P2": default_levels(scene, element, refinements=1)
from plush_opt.apps.cli import main
sys.exit(main(sys.argv[1:]))
"""


def run_with_short_ladder(*args):
    return subprocess.run([sys.executable, "-c", SHORT_LADDER, *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=600)


@pytest.mark.slow
def test_cli_warns_when_the_tolerance_is_not_met(tmp_path):
    out = tmp_path / "r.json"
    p = run_with_short_ladder("solve", str(_coarse_leg(tmp_path, max_area=200.0)), "--method", "forward",
                              "--accuracy", "1e-12", "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert "warning" in p.stderr and "NOT met" in p.stderr
    acc = json.loads(out.read_text())["accuracy"]
    assert acc["reached"] is False and acc["status"] == "tolerance_not_met"


@pytest.mark.slow
@pytest.mark.parametrize("value, message", [("-1", "the tolerance must be a finite number > 0"),
                                            ("nan", "the tolerance must be a finite number > 0"),
                                            ("abc", "--accuracy")])
def test_cli_refuses_a_bad_tolerance(value, message):
    p = run("solve", str(ROOT / "problems" / "hexapod_leg.yaml"), "--accuracy", value)
    assert p.returncode == 2 and message in p.stderr and "Traceback" not in p.stderr
