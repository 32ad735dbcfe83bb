"""plush-opt sweep on scenes it used to refuse or crash on: friction at
contacts (the path's history kept), and tendons without interior via points."""

import csv
import subprocess
import sys

import numpy as np
import yaml

from shipped import ROOT


def _sweep(tmp_path, problem, *args):
    out = tmp_path / "s.csv"
    p = subprocess.run([sys.executable, "-m", "plush_opt", "-q", "sweep", str(problem), *args, "--out", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr and "internal error" not in p.stderr
    with open(out) as fh:
        return list(csv.DictReader(fh))


def test_a_sweep_of_a_tendon_without_interior_via_points(tmp_path):
    rows = _sweep(tmp_path, ROOT / "problems" / "cantilever.yaml", "--winch", "unused", "--to", "0.5",
                  "--steps", "2")
    assert [float(r["c_unused"]) for r in rows] == [0.0, 0.25, 0.5]
    assert all(float(r["T_unused_winch"]) == float(r["T_unused_stopper"]) for r in rows)


def test_a_sweep_with_friction_at_contacts_keeps_its_history(tmp_path):
    doc = yaml.safe_load((ROOT / "problems" / "hexapod_stand.yaml").read_text())
    doc["contact"]["friction"] = 0.5
    doc["points"] = [[-100.0, 2.0]]            # the front foot's tip, on the floor
    problem = tmp_path / "hexapod_friction.yaml"
    problem.write_text(yaml.safe_dump(doc))
    rows = _sweep(tmp_path, problem, "--winch", "a", "--to", "12", "--back", "0", "--steps", "4")
    assert len(rows) == 9
    foot = np.array([[float(r["x_0"]), float(r["y_0"])] for r in rows])
    # back at zero contraction the foot does not return where it started: friction held it
    # while the legs curled and uncurled (the frictionless body would come back)
    assert np.linalg.norm(foot[-1] - foot[0]) > 1e-3
