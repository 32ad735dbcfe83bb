"""The method comparison: a coarse run writes its report, table and plots,
every returned pose is within bounds and stable; the Pareto front; the
command-line entry."""

import argparse
import csv

import pytest

from plush_opt.apps.compare import (CompareSettings, add_compare_parser, cmd_compare, pareto_front,
                               run_compare)
from plush_opt.base.errors import SceneError
from shipped import ROOT


@pytest.mark.slow
def test_coarse_comparison_on_two_shipped_problems(tmp_path):
    # (its run time is not asserted here: figures live in benchmarks; this
    # run takes about 30 s on the 2-core CI machine)
    lines = []
    run_compare([ROOT / "problems" / "gripper.yaml", ROOT / "problems" / "hexapod_leg.yaml"],
                tmp_path, coarse=True, progress=lines.append)
    for name in ("report.md", "results.csv", "curves.csv", "anytime.png", "speed_error.png"):
        path = tmp_path / name
        assert path.is_file() and path.stat().st_size > 0, name
    assert lines and all(line.startswith("compare:") for line in lines)

    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    settings = CompareSettings.coarse()
    per_problem = 3 * (len(settings.tolerances) + len(settings.mesh_factors) - 1)
    assert len(rows) == 2 * per_problem
    assert {r["method"] for r in rows} == {"reparam", "clip", "bilevel"}
    for r in rows:
        assert float(r["bound_violation"]) == 0.0, r
        assert r["stable"] == "1", r
    main = {(r["problem"], r["method"]): r for r in rows if r["sweep"] == "main"}
    for problem in ("gripper", "hexapod_leg"):
        o = [float(main[(problem, m)]["objective"]) for m in ("reparam", "clip", "bilevel")]
        assert o[0] == pytest.approx(o[1], rel=0.01)
        # the bilevel method is as good as the loop (the leg's trap included)
        assert o[2] <= 1.01 * o[0]
    assert any(r["pareto"] == "1" for r in rows)
    # errors against a P2 reference whose own check is far below them
    for problem in ("gripper", "hexapod_leg"):
        mine = [r for r in rows if r["problem"] == problem]
        assert {r["element"] for r in mine} == {"P1"}
        errors = [float(r["model_error"]) for r in mine]
        checks = [float(r["reference_difference"]) for r in mine]
        assert all(e > 0 for e in errors)           # no run scores zero by construction
        assert max(checks) < min(errors)

    report = (tmp_path / "report.md").read_text()
    for word in ("## gripper", "## hexapod_leg", "| reparam |", "| clip |", "| bilevel |",
                 "bound violation", "Pareto front", "anytime.png", "speed_error.png",
                 "## Bilevel against the gradient loop", "against a P2 reference of",
                 "Least solve time"):
        assert word in report
    curves = list(csv.DictReader((tmp_path / "curves.csv").open()))
    kinds = {(c["method"], c["kind"], c["dispatchable"]) for c in curves}
    # the reduced-space bilevel method's iterates are certified equilibria
    assert ("bilevel", "certified", "1") in kinds
    assert not any(k[0] == "bilevel" and k[2] == "0" for k in kinds)
    assert ("reparam", "iterate", "1") in kinds


def test_pareto_front():
    points = [(1.0, 5.0), (2.0, 3.0), (2.5, 4.0), (0.5, 9.0), (3.0, 1.0), (float("nan"), 0.0),
              (4.0, 1.0 - 1e-9)]
    assert pareto_front(points) == [3, 0, 1, 4]


@pytest.mark.slow
def test_command_line_entry(tmp_path, capsys):
    parser = argparse.ArgumentParser(prog="plush-opt")
    sub = parser.add_subparsers(dest="command")
    add_compare_parser(sub)
    args = parser.parse_args(["compare", str(ROOT / "problems" / "compare" / "finger_near_zero.yaml"),
                              "--out", str(tmp_path / "cmp"), "--coarse"])
    assert args.func is cmd_compare and args.coarse
    assert cmd_compare(args) == 0
    out, err = capsys.readouterr()
    assert "report.md" in out and "compare:" in err
    assert (tmp_path / "cmp" / "report.md").is_file()


def test_problem_without_targets_is_refused(tmp_path):
    text = (ROOT / "problems" / "compare" / "finger_near_zero.yaml").read_text()
    path = tmp_path / "no_targets.yaml"
    path.write_text(text[:text.index("targets:")])
    with pytest.raises(SceneError, match="targets"):
        run_compare([path], tmp_path / "out", coarse=True)


def test_settings_are_validated():
    with pytest.raises(ValueError, match="main_factor"):
        CompareSettings(mesh_factors=(4.0, 2.0), main_factor=1.0)
    with pytest.raises(ValueError, match="tolerances"):
        CompareSettings(tolerances=("loose",))


@pytest.mark.slow
def test_a_reference_that_creases_measures_no_errors():
    """finger_bound's answer (flex at its bound 20) is not folded on the
    file's P1 mesh, but P2 levels crease there: the finger's phalanges pass
    through each other at the joint. The run gets where, and no errors
    (there is no converged answer to measure them against); a run at a
    small flex is measured as before."""
    import numpy as np

    from plush_opt.apps.compare.runner import _Problem, _reference
    from plush_opt.apps.compare.settings import Run
    from plush_opt.io import load_scene
    from plush_opt.problem import from_scene

    path = ROOT / "problems" / "compare" / "finger_bound.yaml"
    scene = load_scene(path)
    p = from_scene(scene)
    runs = []
    for flex in (20.0, 2.0):
        c = np.array([flex, 0.0])
        eq = p.equilibrium(dict(zip(scene.winch_names, c)))
        run = Run(scene.name, "reparam", "main", "default", scene.element, 1.0, scene.max_area,
                  p.mesh.n_nodes, len(p.mesh.triangles), contraction=c, x=eq.x, mesh=p.mesh)
        runs.append(run)
    problem = _Problem(path, scene, {}, scene.contraction.copy(), scene.frozen.copy())
    _reference(problem, runs, CompareSettings(reference_factor=1.0, check_factor=2.0))
    folded, modest = runs
    assert "creases" in folded.reference_crease and "boundary segments" in folded.reference_crease
    assert np.isnan(folded.model_error) and np.isnan(folded.fine_target_error)
    assert np.isnan(folded.reference_difference)
    assert modest.reference_crease == ""
    assert 0 < modest.model_error < 1 and modest.reference_difference < modest.model_error


@pytest.mark.slow
def test_crease_scan_names_the_fold_and_refuses_an_unknown_winch(capsys):
    """tools/crease_scan.py (the command the notes quote for where a scene
    folds): finger_bound curled to its bound crosses itself on a P2 mesh
    finer than its file's, not at a tenth of the way; a winch it does not
    have is named."""
    import sys
    sys.path.insert(0, str(ROOT / "tools"))
    import crease_scan
    crease_scan.main([str(ROOT / "problems" / "compare" / "finger_bound.yaml"), "flex=20",
                      "--factors", "1", "--uniform", "--steps", "10"])
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 10 and lines[0].endswith("  -")
    assert "a crease" in lines[-1] and lines[-1].startswith("927 nodes  1.00  O ")
    with pytest.raises(SystemExit, match="no winch named thumb"):
        crease_scan.main([str(ROOT / "problems" / "compare" / "finger_bound.yaml"), "thumb=1"])
