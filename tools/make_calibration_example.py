"""Make examples/hexapod_leg_measurements.yaml, the measurements of
docs/calibration.md, and print the story's numbers.

    .venv/bin/python tools/make_calibration_example.py

The "real" leg is problems/hexapod_leg.yaml sewn unevenly: felt 30 % stiffer
than the data sheet, `upper_half` tied 0.6 mm tight, `outer_half` 1.2 mm
slack. Ten markers are seen (sigma 0.3 mm, seeded noise) at ten
contractions. The script then poses the foot with the controller on the
nominal model and on the fitted one, and says where the real leg's foot
lands in each case.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

import plush_opt
from plush_opt.solve.equilibrium import solve_equilibrium
from plush_opt.fit.parameters import scene_with
from plush_opt.fit.synthetic import synthesize, true_values
from plush_opt.fem.model import build_model

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "hexapod_leg.yaml"
OUT = ROOT / "examples" / "hexapod_leg_measurements.yaml"
SEED = 2026
SIGMA = 0.3
MARKERS = [[12, -9], [24, 9], [36, -9], [48, 9], [60, -9], [72, 9], [84, -9], [96, 9], [100, -9],
           [50, 0]]
CONTRACTIONS = [0.0, 9.0, 3.0, 12.0, 6.0, 15.0, 1.5, 10.5, 4.5, 13.5]
HEADER = """\
# Markers on a sewn hexapod leg (docs/calibration.md): ten felt dots, seen
# by a camera at ten contractions of the `leg` winch, in mm (sigma 0.3 mm).
# Made by tools/make_calibration_example.py (synthetic, seeded).
"""


def main() -> None:
    p = plush_opt.load(PROBLEM)
    truth = true_values(p.scene, youngs_modulus=0.026,
                        assembly_offset={"upper_half": -0.6, "outer_half": 1.2})
    doc = synthesize(p.scene, p.mesh, truth, MARKERS, np.array(CONTRACTIONS)[:, None], sigma=SIGMA,
                     seed=SEED, problem="../problems/hexapod_leg.yaml")
    for pose in doc["poses"]:
        pose["positions"] = [None if q is None else [round(v, 2) for v in q] for q in pose["positions"]]
    text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)
    OUT.write_text(HEADER + text)
    print(f"wrote {OUT.relative_to(ROOT)}")

    real = build_model(scene_with(p.scene, truth), p.mesh)
    with tempfile.TemporaryDirectory() as tmp:
        fitted = Path(tmp) / "hexapod_leg_fitted.yaml"
        subprocess.run([sys.executable, "-m", "plush_opt", "calibrate", str(OUT), "--out", str(fitted),
                        "--holdout", "8,9"], check=True)
        for name, path in (("nominal", PROBLEM), ("fitted", fitted)):
            q = plush_opt.load(path)
            r = q.control()
            eq = solve_equilibrium(real, r.equilibrium.contraction)
            foot = q.targets.y(eq.x)[0]
            miss = float(np.linalg.norm(foot - q.targets.to[0]))
            print(f"{name}: leg = {r.equilibrium.contraction[0]:.3f}; model's foot misses by "
                  f"{q.targets.errors(r.equilibrium.x)[0]:.3f} mm; the real leg's foot lands at "
                  f"({foot[0]:.2f}, {foot[1]:.2f}), {miss:.2f} mm from the target")


if __name__ == "__main__":
    main()
