"""Calibration fits: recovery of known parameters from synthetic noisy
markers, honest standard errors, held-out poses, refusal of a set the data
cannot identify, a robust loss, and the command with its fitted file."""

from __future__ import annotations

import functools
import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from plush_opt.fit import FitOptions, Values
from plush_opt.fit.job import calibrate, fitted_text
from plush_opt.fit.synthetic import synthesize, true_values
from plush_opt.io import load_scene
from plush_opt.io.measurement import load_measurements
from plush_opt.fem.mesh import build_mesh
from shipped import ROOT

TENTACLE = ROOT / "problems" / "calib" / "tentacle.yaml"
SIGMA = 0.2
TRUE_E = 0.012                    # the file says 0.01
TRUE_OFFSETS = {"top": -0.8, "under_inner": 0.5, "under_outer": -0.3}
# 10 markers along both edges and the tip; 8 fitted poses, 2 held out
MARKERS = [[10, 4.5], [20, -4.5], [30, 4.5], [40, -4.5], [50, 4.5], [60, -4.5], [70, 4.5],
           [80, -4.5], [90, 4.5], [100, 0]]
POSES = [[0, 0], [6, 0], [12, 0], [0, 6], [0, 12], [4, 4], [8, 3], [2, 10], [10, 1], [3, 8]]
HELD_OUT = (8, 9)


@functools.lru_cache(maxsize=None)
def clean_positions(max_area):
    """Noise-free marker positions of the true robot, (n_poses, n_markers, 2)."""
    scene = load_scene(TENTACLE)
    truth = true_values(scene, youngs_modulus=TRUE_E, assembly_offset=TRUE_OFFSETS)
    doc = synthesize(scene, build_mesh(scene, max_area), truth, MARKERS, POSES, sigma=0.0, seed=0,
                     problem=str(TENTACLE))
    return doc, truth


def write_measurements(path, max_area, seed, hidden=0.0):
    doc, truth = clean_positions(max_area)
    rng = np.random.default_rng(seed)
    doc = json.loads(json.dumps(doc))
    for pose in doc["poses"]:
        noisy = np.asarray(pose["positions"]) + rng.normal(0.0, SIGMA, (len(MARKERS), 2))
        pose["positions"] = [p if rng.random() >= hidden else None for p in noisy.tolist()]
    doc["sigma"] = SIGMA
    path.write_text(yaml.safe_dump(doc))
    return truth


@pytest.mark.slow
def test_synthetic_recovery_and_held_out_prediction(tmp_path):
    truth = write_measurements(tmp_path / "m.yaml", None, seed=7)
    meas = load_measurements(tmp_path / "m.yaml")
    res = calibrate(meas, options=FitOptions(holdout=HELD_OUT))
    assert res.identifiable and res.converged, res.status
    values = res.after.values
    assert abs(values.youngs_modulus / TRUE_E - 1) < 0.05
    np.testing.assert_allclose(values.assembly_offset, truth.assembly_offset, atol=0.1)
    for i in HELD_OUT:                      # predicted, never fitted: within 1.5 sigma RMS
        d = (res.after.y[i] - meas.positions[i]) / SIGMA
        assert np.sqrt(np.mean(d**2)) < 1.5
    assert not res.warnings


@pytest.mark.slow
def test_standard_errors_cover_the_truth_at_the_usual_rate(tmp_path):
    """Over seeded repeats, |fitted - true| <= 1.96 standard errors about
    95% of the time, and the normalised errors have unit variance."""
    z = []
    for seed in range(16):
        truth = write_measurements(tmp_path / f"m{seed}.yaml", 16.0, seed=100 + seed)
        res = calibrate(load_measurements(tmp_path / f"m{seed}.yaml"), max_area=16.0)
        assert res.identifiable and res.converged, res.status
        for p, se in zip(res.params, res.standard_errors):
            z.append((res.after.values.get(p) - truth.get(p)) / se)
    z = np.array(z)
    inside = np.mean(np.abs(z) <= 1.96)
    assert inside >= 0.85, (inside, z)
    assert 0.5 < np.mean(z**2) < 1.6, z


def test_a_non_identifiable_set_is_refused_naming_the_combination(tmp_path):
    """A winch's zero offset against its only tendon's assembly offset: the
    data see only their difference."""
    write_measurements(tmp_path / "m.yaml", 16.0, seed=3)
    meas = load_measurements(tmp_path / "m.yaml")
    res = calibrate(meas, "youngs_modulus,assembly_offset,winch_offset:lift", max_area=16.0)
    assert not res.identifiable and res.covariance is None
    assert "winch_offset:lift" in res.combination and "assembly_offset:top" in res.combination
    assert "under_inner" not in res.combination
    assert res.after is res.before            # nothing was fitted to noise


def test_a_tendon_slack_in_every_pose_is_not_identifiable(tmp_path):
    write_measurements(tmp_path / "m.yaml", 16.0, seed=3)
    doc = yaml.safe_load((tmp_path / "m.yaml").read_text())
    # lifting only: the tendons under the body go slack
    doc["poses"] = [p for p in doc["poses"] if p["contractions"] in ({"lift": 6, "curl": 0},
                                                                     {"lift": 12, "curl": 0})]
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    res = calibrate(load_measurements(tmp_path / "m.yaml"), max_area=16.0)
    assert not res.identifiable
    assert res.combination == "assembly_offset:under_inner (moves no marker in any fitted pose)"


def test_winch_offset_alone_is_fitted_and_folded_into_the_offsets(tmp_path):
    scene = load_scene(TENTACLE)
    mesh = build_mesh(scene, 16.0)
    truth = true_values(scene, winch_offset={"curl": 0.6})
    doc = synthesize(scene, mesh, truth, MARKERS, POSES[:8], sigma=SIGMA, seed=5, problem=str(TENTACLE))
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    meas = load_measurements(tmp_path / "m.yaml")
    res = calibrate(meas, "winch_offset:curl", max_area=16.0)
    z, se = res.after.values.winch_offset[1], res.standard_errors[0]
    assert abs(z - 0.6) < 4 * se and se < 0.05
    fitted = yaml.safe_load(fitted_text(meas, res))
    written = [t.get("assembly_offset") for t in fitted["tendons"]["list"]]
    assert written[0] is None and written[1] == written[2] == pytest.approx(-z, rel=1e-9)


def test_huber_loss_resists_an_outlier_marker(tmp_path):
    truth = write_measurements(tmp_path / "m.yaml", 16.0, seed=11)
    doc = yaml.safe_load((tmp_path / "m.yaml").read_text())
    doc["poses"][3]["positions"][9][1] += 8.0          # one marker mistracked by 40 sigma
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    meas = load_measurements(tmp_path / "m.yaml")
    plain = calibrate(meas, max_area=16.0)
    robust = calibrate(meas, options=FitOptions(huber=2.0), max_area=16.0)

    def error(res):
        return np.max(np.abs(res.after.values.assembly_offset - truth.assembly_offset))
    assert error(robust) < 0.1 < error(plain)


def test_unseen_markers_are_skipped(tmp_path):
    truth = write_measurements(tmp_path / "m.yaml", 16.0, seed=21, hidden=0.25)
    meas = load_measurements(tmp_path / "m.yaml")
    assert 0 < meas.seen.mean() < 1
    res = calibrate(meas, max_area=16.0)
    np.testing.assert_allclose(res.after.values.assembly_offset, truth.assembly_offset, atol=0.15)


# -- the command ------------------------------------------------------------------

def run(*args):
    return subprocess.run([sys.executable, "-m", "plush_opt", *args], capture_output=True,
                          text=True, timeout=600)


@pytest.mark.slow
def test_calibrate_command_writes_fitted_file_and_report(tmp_path):
    write_measurements(tmp_path / "m.yaml", None, seed=7)
    out, rep = tmp_path / "fitted.yaml", tmp_path / "rep.json"
    p = run("calibrate", str(tmp_path / "m.yaml"), "--out", str(out), "--report", str(rep),
            "--holdout", "8,9")
    assert p.returncode == 0, p.stderr
    assert "youngs_modulus" in p.stdout and "(held out)" in p.stdout and "chi^2" in p.stdout
    doc = json.loads(rep.read_text())
    assert doc["identifiable"] and doc["dof"] == 2 * 10 * 8 - 4
    assert [q["held_out"] for q in doc["poses"]] == [False] * 8 + [True] * 2
    assert all(q["rms_after"] < q["rms_before"] for q in doc["poses"])
    assert len(doc["correlation"]) == 4 and doc["parameters"][0]["standard_error"] > 0
    # the fitted file is the input with only the fitted keys changed
    before, after = TENTACLE.read_text().splitlines(), out.read_text().splitlines()
    assert [line for line in before if line not in after] == ["  youngs_modulus: 0.01"]
    added = [line.strip().split(":")[0] for line in after if line not in before]
    assert added == ["youngs_modulus"] + ["assembly_offset"] * 3
    assert [line for line in after if not line.strip().startswith("assembly_offset")] == [
        line if line != "  youngs_modulus: 0.01" else after[before.index(line)] for line in before]
    scene = load_scene(out)
    assert Values.of_scene(scene).youngs_modulus == pytest.approx(doc["parameters"][0]["fitted"])


@pytest.mark.slow
def test_calibrate_command_draws_each_pose(tmp_path):
    write_measurements(tmp_path / "m.yaml", 16.0, seed=7)
    doc = yaml.safe_load((tmp_path / "m.yaml").read_text())
    doc["poses"] = doc["poses"][:3]
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    plots = tmp_path / "plots"
    p = run("calibrate", str(tmp_path / "m.yaml"), "--out", str(tmp_path / "f.yaml"),
            "--max-area", "16", "--plot", str(plots), "--holdout", "2", "--fit", "youngs_modulus")
    assert p.returncode == 0, p.stderr
    pngs = sorted(plots.iterdir())
    assert [f.name for f in pngs] == ["pose_00.png", "pose_01.png", "pose_02.png"]
    assert all(f.read_bytes()[:4] == b"\x89PNG" and f.stat().st_size > 20_000 for f in pngs)


@pytest.mark.slow
def test_calibrate_command_refuses_a_non_identifiable_set(tmp_path):
    write_measurements(tmp_path / "m.yaml", 16.0, seed=3)
    out, rep = tmp_path / "fitted.yaml", tmp_path / "rep.json"
    p = run("calibrate", str(tmp_path / "m.yaml"), "--out", str(out), "--max-area", "16",
            "--fit", "assembly_offset:top,winch_offset:lift", "--report", str(rep))
    assert p.returncode == 3
    assert "not identifiable" in p.stderr and "winch_offset:lift" in p.stderr
    assert not out.exists()
    doc = json.loads(rep.read_text())
    assert doc["identifiable"] is False and doc["fitted_file"] is None
    assert [q["fitted"] for q in doc["parameters"]] == [None, None]
    assert "winch_offset:lift" in doc["warnings"][0]


@pytest.mark.slow
@pytest.mark.parametrize("args, message", [
    (("--fit", "stiffness"), "--fit: unknown parameter 'stiffness'"),
    (("--fit", "assembly_offset:nope"), "--fit: 'assembly_offset:nope': no tendon named 'nope'"),
    (("--holdout", "12"), "--holdout: pose 12 does not exist"),
    (("--huber", "0"), "--huber: expected a threshold > 0"),
])
def test_calibrate_command_bad_options(tmp_path, args, message):
    write_measurements(tmp_path / "m.yaml", 16.0, seed=3)
    p = run("calibrate", str(tmp_path / "m.yaml"), "--out", str(tmp_path / "f.yaml"), *args)
    assert p.returncode == 2 and message in p.stderr and "Traceback" not in p.stderr
