"""The public API of docs/api.md, as a user calls it."""

from __future__ import annotations

import json
import runpy

import numpy as np
import pytest

import plush_opt
from shipped import ROOT
from spec_checker import check_result


@pytest.mark.slow
def test_the_documented_example_runs_and_writes_a_valid_result(tmp_path, capsys):
    tour = runpy.run_path(str(ROOT / "examples" / "api_tour.py"))
    result = tour["main"](str(tmp_path / "r.json"))
    assert isinstance(result, plush_opt.ControlResult)
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["method"] == "reparam" and doc["contractions"] == result.contractions
    assert doc["objective"] == pytest.approx(result.objective, rel=1e-12)
    check_result(doc)
    assert "control: stationary" in capsys.readouterr().out


def test_load_equilibrium_control_save():
    p = plush_opt.load(ROOT / "problems" / "gripper.yaml")
    assert p.winch_names == ("left", "right", "grip")
    eq = p.equilibrium({"left": 10.0})
    assert eq.converged and eq.contraction.tolist() == [10.0, 0.0, 0.0]
    assert eq.x.shape == (2 * p.mesh.n_nodes,)
    r = p.control(method="clip", contraction={"grip": 5.0}, frozen=["grip"])
    assert r.method == "clip" and r.contractions["grip"] == 5.0 and r.frozen == ("grip",)
    assert np.array_equal(r.x, r.equilibrium.x)
    assert r.history[0].dispatchable and all(h.dispatchable for h in r.history)


@pytest.mark.parametrize("call, match", [
    (lambda p: p.equilibrium({"lfet": 1.0}), r"contraction lfet=1: no winch named 'lfet'"),
    (lambda p: p.equilibrium({"left": 99.0}), r"left=99: outside the winch's bounds"),
    (lambda p: p.control(frozen=["nope"]), r"frozen nope: no winch named"),
    (lambda p: p.control(method="newton"), r"method: expected one of"),
])
def test_bad_names_and_values_are_clear_errors(call, match):
    p = plush_opt.load(ROOT / "problems" / "gripper.yaml")
    with pytest.raises((plush_opt.SceneError, ValueError), match=match):
        call(p)


def test_control_without_targets_is_an_input_error():
    p = plush_opt.load(ROOT / "problems" / "hexapod.yaml")
    p = p.with_targets(p.targets.empty())
    with pytest.raises(plush_opt.SceneError, match="control needs targets"):
        p.control()


@pytest.mark.slow
def test_every_method_returns_the_same_result_shape():
    p = plush_opt.load(ROOT / "problems" / "gripper.yaml")
    for method in ("reparam", "clip", "bilevel"):
        r = p.control(method=method)
        assert r.method == method and r.reason in plush_opt.control.REASONS
        assert r.converged == (r.reason in plush_opt.control.CONVERGED_REASONS)
        assert r.equilibrium.min_eigenvalue is not None
        assert r.stats.t_wall > 0 and r.stats.iterations == (
            len(r.history) - 1 if method != "bilevel" else r.stats.iterations)
        doc = r.to_dict()
        assert doc["method"] == method and doc["reason"] == r.reason
        json.dumps(doc, allow_nan=False)
