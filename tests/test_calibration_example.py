"""The shipped calibration example (examples/hexapod_leg_measurements.yaml)
recovers the leg it was made from, and docs/calibration.md's story is the
current output of the script that makes both (issue 35)."""

import subprocess
import sys

import pytest

from plush_opt.fit import FitOptions
from plush_opt.fit.job import calibrate
from plush_opt.fit.report import report_dict
from plush_opt.io.measurement import load_measurements
from shipped import ROOT

sys.path.insert(0, str(ROOT / "tools"))
import make_calibration_example as example  # noqa: E402

pytestmark = pytest.mark.slow      # a calibration of ten poses, and the doc's story made again


@pytest.fixture(scope="module")
def fitted():
    meas = load_measurements(ROOT / "examples" / "hexapod_leg_measurements.yaml")
    result = calibrate(meas, "youngs_modulus,assembly_offset", FitOptions(holdout=(8, 9)))
    assert result.identifiable and result.converged, result.status
    return meas, result


@pytest.fixture(scope="module")
def report(fitted):
    return report_dict(*fitted)


def test_the_calibration_pictures_have_labelled_axes(fitted):
    from matplotlib.figure import Figure
    from plush_opt.apps.calibrate_plot import _panel
    meas, result = fitted
    ax = Figure().subplots()
    _panel(ax, result.after, 5, meas.positions[5], meas.seen[5], "k", "after")
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (mm)", "y (mm)")
    assert ax.get_title().startswith("after: RMS marker error ") and ax.get_title().endswith(" mm")


def test_the_fit_recovers_the_truth_within_its_standard_errors(report):
    truth = {"youngs_modulus": example.TRUE_E,
             **{f"assembly_offset:{k}": v for k, v in example.TRUE_OFFSETS.items()}}
    fitted = {p["name"]: p for p in report["parameters"]}
    assert set(fitted) == set(truth)
    for name, value in truth.items():
        p = fitted[name]
        assert abs(p["fitted"] - value) <= p["standard_error"], (name, p, value)
    # the model explains the data to the noise: reduced chi^2 near 1
    assert 0.7 <= report["reduced_chi2"] <= 1.5, report["reduced_chi2"]


def test_held_out_poses_are_predicted_to_about_one_sigma(report):
    held = [p for p in report["poses"] if p["held_out"]]
    assert [p["index"] for p in held] == [8, 9]
    for p in held:
        assert p["rms_sigma_after"] <= 1.5, p          # sigma per coordinate


def test_the_example_and_the_docs_story_are_current():
    p = subprocess.run([sys.executable, str(ROOT / "tools" / "make_calibration_example.py"), "--check"],
                       capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
