"""Time a friction sweep: the gripper with friction at its via points
(problems/gripper_friction.yaml) at about 1,000 nodes, winch ``grip`` from
0 to 15 mm in 10 steps and back to 0 in 10 more, each step from the state
the previous one reached.

    OPENBLAS_NUM_THREADS=1 python tools/bench_friction.py [--repeats 3] [--out FILE]

The model and the start state are built once (not timed); each repeat
follows the 20 steps from the start state again. Reports the median of the
repeats, wall-clock and process CPU time (the CPU time is the figure to
quote on a shared machine: wall-clock there includes other processes' time),
the number of factorisations and evaluations, the loop area of the bar's
left tip, and the same path's time without friction (one warm-started
equilibrium per step); writes them as JSON to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from plush_opt import load
from plush_opt.fem.friction import FrictionModel
from plush_opt.solve.equilibrium import solve_equilibrium
from plush_opt.solve.friction_path import FrictionOptions, follow, start_state

ROOT = Path(__file__).resolve().parent.parent
PROBLEM = ROOT / "problems" / "gripper_friction.yaml"
MAX_AREA = 8.0      # mm^2: about 1,000 nodes on the gripper
TO, STEPS = 15.0, 10


def sweep_path(problem) -> np.ndarray:
    w = problem.winch_names.index("grip")
    values = np.r_[np.linspace(0, TO, STEPS + 1)[1:], np.linspace(TO, 0, STEPS + 1)[1:]]
    path = np.zeros((len(values), problem.model.n_winches))
    path[:, w] = values
    return path


class Counter:
    """Counts the factorisations and evaluations of one friction model."""

    def __init__(self, fm: FrictionModel):
        self.factor = self.evaluate = 0
        factor, evaluate = fm.factorizer.factor, fm.evaluate_held     # every evaluation goes through it

        def counted_factor(*a, **k):
            self.factor += 1
            return factor(*a, **k)

        def counted_evaluate(*a, **k):
            self.evaluate += 1
            return evaluate(*a, **k)

        fm.factorizer.factor, fm.evaluate_held = counted_factor, counted_evaluate
        self._fm = fm

    def close(self) -> None:
        """Back to the uncounted methods (the instance attributes go)."""
        del self._fm.factorizer.factor, self._fm.evaluate_held


def loop_area(problem, states) -> float:
    """|area| of the (grip contraction, y of the bar's left tip) loop (mm^2)."""
    node = problem.mesh.point_nodes[0]
    w = problem.winch_names.index("grip")
    c = np.array([s.contraction[w] for s in states])
    y = np.array([s.nodes[node, 1] for s in states])
    return abs(0.5 * float(np.sum(c * np.roll(y, -1) - np.roll(c, -1) * y)))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("bench_friction.json"))
    args = parser.parse_args(argv)
    problem = load(PROBLEM, max_area=MAX_AREA)
    fm = FrictionModel(problem.model)
    t0 = time.perf_counter()
    start = start_state(fm)
    t_start = time.perf_counter() - t0
    path = sweep_path(problem)
    walls, cpus, runs = [], [], []
    for _ in range(args.repeats):
        count = Counter(fm)
        w0, c0 = time.perf_counter(), time.process_time()
        states = follow(fm, start, path)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
        runs.append({"steps_converged": sum(s.converged for s in states), "factorisations": count.factor,
                     "evaluations": count.evaluate})
        count.close()
    # the same path without friction: one warm-started equilibrium per step
    plain_cpu = []
    for _ in range(args.repeats):
        x, c0 = None, time.process_time()
        for c in path:
            x = solve_equilibrium(problem.model, c, x, FrictionOptions().equilibrium).x
        plain_cpu.append(time.process_time() - c0)
    result = {
        "problem": PROBLEM.name, "nodes": problem.mesh.n_nodes, "steps": len(path),
        "path": f"grip 0 -> {TO:g} -> 0 mm in {len(path)} steps",
        "repeats": args.repeats, "median_wall_s": statistics.median(walls),
        "median_cpu_s": statistics.median(cpus), "wall_s": walls, "cpu_s": cpus,
        "start_state_s": t_start, "frictionless_median_cpu_s": statistics.median(plain_cpu), "runs": runs, "all_converged": all(s.converged for s in states),
        "loop_area_mm2": loop_area(problem, [start] + states),
        "python": platform.python_version(), "machine": platform.machine(),
    }
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"{result['nodes']} nodes, {len(path)} steps: median {result['median_cpu_s']:.2f} s CPU, "
          f"{result['median_wall_s']:.2f} s wall of {args.repeats} (without friction "
          f"{result['frictionless_median_cpu_s']:.2f} s CPU); {runs[-1]}; wrote {args.out}")
    return 0 if result["all_converged"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
