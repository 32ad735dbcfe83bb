"""``plush-opt bench --contact``: what contact costs (docs/benchmarks.md, "Contact").

Three measurements, medians of ``repeats`` runs, written to
``contact.json`` and ``contact.md``:

* a slab lying on the floor (no pins) against the same slab pinned along
  its underside without contact, forward solve from rest, at each size
  (the two solves in turn, one of each per round): the ratio is what
  resting on a floor costs;
* at each size, the contact term alone: boundary nodes, one evaluation
  with its Hessian, and one step bound (CCD), so that how the cost grows
  with the boundary can be read off;
* ``problems/hexapod_stand.yaml``'s control run: time per iterate.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .timing import median_time
from ..base.data_files import data_file
from ..base.files import write_text_atomic
from ..fem.mesh import area_for_nodes
from ..fem.model import Model
from ..io.problem_file import scene_from_dict
from ..problem import load
from ..solve.equilibrium import EquilibriumOptions, solve_equilibrium

NO_EIG = EquilibriumOptions(eigenvalue=False)
#: the slab: 200 x 20 mm felt, 30 mm thick, under its weight (its one tendon,
#: which the format asks for, is a thread: it carries nothing)
SLAB = {
    "format": "plush-opt/1", "name": "slab",
    "mesh": {"outline": [[0, 0.5], [200, 0.5], [200, 20.5], [0, 20.5]], "min_angle": 28.0},
    "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                 "thickness": 30.0, "density": 1e-10},
    "gravity": [0.0, -9810.0],
    "winches": [{"name": "w", "bounds": [0.0, 10.0]}],
    "tendons": {"stiffness": 1e-6, "smoothing": 0.01,
                "list": [{"name": "t", "winch": "w", "path": [[10, 18], [100, 18], [190, 18]]}]},
}


def slab(on_floor: bool):
    """The slab scene: lying on a frictionless floor (no pins), or pinned
    along its underside without contact."""
    doc = json.loads(json.dumps(SLAB))
    if on_floor:
        doc["contact"] = {"ground": {"height": 0.0}, "distance": 0.5}
    else:
        doc["pins"] = {"stiffness": 10.0, "box": [0, 0.5, 200, 0.5]}
    return scene_from_dict(doc, "slab.yaml")


def median_times(fns: dict, repeats: int) -> dict:
    """Per key of ``fns`` (name -> function of no arguments): (median wall
    seconds, median CPU seconds of this process, last result) of
    ``repeats`` calls, the functions called in turn (one call of each per
    round), so that on a shared machine a burst of other jobs' load falls
    on both sides of a ratio alike; the CPU time says what the work costs,
    the wall time what a user waits."""
    wall = {key: [] for key in fns}
    cpu = {key: [] for key in fns}
    out = dict.fromkeys(fns)
    for _ in range(repeats):
        for key, fn in fns.items():
            t, c = time.perf_counter(), time.process_time()
            out[key] = fn()
            cpu[key].append(time.process_time() - c)
            wall[key].append(time.perf_counter() - t)
    return {key: (float(np.median(wall[key])), float(np.median(cpu[key])), out[key]) for key in fns}


def floor_row(nodes: int, repeats: int) -> dict:
    """The slab at about ``nodes`` nodes: forward solve on the floor and
    pinned (in turn), and the contact term's own costs."""
    row = {"target_nodes": nodes}
    solves, meshes = {}, {}
    for key, on_floor in (("floor", True), ("pinned", False)):
        scene = slab(on_floor)
        _, meshes[key] = area_for_nodes(scene, nodes)
        model = Model(scene, meshes[key])
        c = scene.contraction
        solve_equilibrium(model, c, options=NO_EIG)                # warm the kernels
        solves[key] = (model, c)
    timed = median_times({key: (lambda m=m, c=c: solve_equilibrium(m, c, options=NO_EIG))
                          for key, (m, c) in solves.items()}, repeats)
    for key, (seconds, cpu, eq) in timed.items():
        row[key] = {"nodes": meshes[key].n_nodes, "solve_s": seconds, "solve_cpu_s": cpu,
                    "newton_iterations": eq.iterations, "converged": bool(eq.converged)}
    model, c = solves["floor"]
    term = model.contact
    x = timed["floor"][2].x
    row["boundary_nodes"] = int(len(term.boundary.nodes))
    row["contact_eval_s"], _ = median_time(lambda: term.evaluate(x, c, 2), repeats)
    dx = np.random.default_rng(0).standard_normal(x.size) * 0.1
    row["contact_step_bound_s"], _ = median_time(lambda: model.max_step(x, dx), repeats)
    row["full_eval_s"], _ = median_time(lambda: model.evaluate(x, c, 2), repeats)
    row["ratio"] = row["floor"]["solve_s"] / row["pinned"]["solve_s"]
    row["cpu_ratio"] = row["floor"]["solve_cpu_s"] / row["pinned"]["solve_cpu_s"]
    return row


def hexapod_row(repeats: int) -> dict:
    """``hexapod_stand``'s control run from rest: time per iterate."""
    problem = load(data_file("problems") / "hexapod_stand.yaml")
    problem.control()                                              # warm the kernels
    seconds, result = median_time(problem.control, repeats)
    iterations = max(result.stats.iterations, 1)
    return {"nodes": problem.model.n_nodes, "control_s": seconds, "iterations": result.stats.iterations,
            "per_iterate_s": seconds / iterations, "certified": bool(result.equilibrium.converged)}


def render(report: dict) -> str:
    lines = ["# What contact costs", "", f"Reproduce with `{report['command']}`.", "",
             "A 200 x 20 mm slab under its weight lying on a frictionless floor (no pins), against "
             "the same slab pinned along its underside without contact; forward solve from rest, the two in turn, "
             f"medians of {report['repeats']} runs (wall time, and this process's CPU time); the contact term's own "
             "evaluation (with its Hessian) and step bound (CCD) at the floor's equilibrium.", "",
             "| nodes | boundary nodes | floor solve | pinned solve | ratio | CPU floor / pinned | CPU ratio "
             "| Newton its floor / pinned | contact eval | whole eval | step bound |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["floor"]:
        f, p = r["floor"], r["pinned"]
        lines.append(f"| {f['nodes']:,} | {r['boundary_nodes']:,} | {1e3 * f['solve_s']:.1f} ms | "
                     f"{1e3 * p['solve_s']:.1f} ms | {r['ratio']:.2f} | {1e3 * f['solve_cpu_s']:.1f} / "
                     f"{1e3 * p['solve_cpu_s']:.1f} ms | {r['cpu_ratio']:.2f} | {f['newton_iterations']} / "
                     f"{p['newton_iterations']} | {1e3 * r['contact_eval_s']:.2f} ms | "
                     f"{1e3 * r['full_eval_s']:.2f} ms | {1e3 * r['contact_step_bound_s']:.2f} ms |")
    h = report["hexapod_stand"]
    lines += ["", f"`hexapod_stand` ({h['nodes']:,} nodes): control from rest {1e3 * h['control_s']:.0f} ms "
              f"over {h['iterations']} iterates, {1e3 * h['per_iterate_s']:.1f} ms per iterate "
              f"(certified: {h['certified']}).", ""]
    return "\n".join(lines)


def run_contact_bench(sizes, out: Path, repeats: int, command: str, progress=print) -> Path:
    """Measure, write ``out/contact.json`` and ``out/contact.md``; returns the markdown's path."""
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in sizes:
        progress(f"contact: slab at about {n} nodes")
        rows.append(floor_row(int(n), repeats))
    progress("contact: hexapod_stand control")
    report = {"command": command, "repeats": repeats, "floor": rows, "hexapod_stand": hexapod_row(repeats)}
    write_text_atomic(out / "contact.json", json.dumps(report, indent=2) + "\n")
    write_text_atomic(out / "contact.md", render(report))
    return out / "contact.md"
