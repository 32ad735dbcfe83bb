"""Time a calibration on about 1,000 nodes, median of several runs.

    .venv/bin/python tools/bench_calibration.py [--nodes 1000] [--repeats 5]

The robot is the tentacle of the calibration tests (problems/calib/
tentacle.yaml) sewn unevenly (Young's modulus and the three tendons'
assembly offsets off), seen at 8 poses by 10 markers with seeded noise
(sigma 0.2 mm), the measurements made on the same mesh; the fit is the
default one (Young's modulus and every assembly offset) from the file's
values. The time is the fit's (every equilibrium, sensitivity and step),
from loaded measurements and a built mesh; the budget is 5 s. Both the
wall-clock and the process's CPU time are printed: on a busy machine the
first overstates what the fit costs.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from plush_opt.fit.job import calibrate
from plush_opt.fit.synthetic import synthesize, true_values
from plush_opt.io import load_scene
from plush_opt.io.measurement import load_measurements
from plush_opt.fem.mesh import mesh_for_nodes

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "calib" / "tentacle.yaml"
MARKERS = [[10 * i + 10, 4.5 if i % 2 == 0 else -4.5] for i in range(9)] + [[100, 0]]
POSES = [[0, 0], [6, 0], [12, 0], [0, 6], [0, 12], [4, 4], [8, 3], [2, 10]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    scene = load_scene(PROBLEM)
    mesh = mesh_for_nodes(scene, args.nodes)
    truth = true_values(scene, youngs_modulus=0.012,
                        assembly_offset={"top": -0.8, "under_inner": 0.5, "under_outer": -0.3})
    doc = synthesize(scene, mesh, truth, MARKERS, POSES, sigma=0.2, seed=1, problem=str(PROBLEM))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "measurements.yaml"
        path.write_text(yaml.safe_dump(doc))
        meas = load_measurements(path)
    times, cpu = [], []
    for _ in range(args.repeats):
        t0 = time.process_time()
        res = calibrate(meas, mesh=mesh)
        cpu.append(time.process_time() - t0)
        times.append(res.t_wall)
        print(f"  {res.t_wall:.3f} s ({cpu[-1]:.3f} s CPU): {res.status}, {res.iterations} iterations, "
              f"{res.solves} equilibrium solves; E = {res.after.values.youngs_modulus:.5g}, "
              f"offsets {np.round(res.after.values.assembly_offset, 3).tolist()}")
    print(f"calibration, {mesh.n_nodes} nodes, {meas.n_poses} poses, {meas.n_markers} markers: "
          f"median {statistics.median(times):.3f} s ({statistics.median(cpu):.3f} s CPU) "
          f"over {args.repeats} runs")


if __name__ == "__main__":
    main()
