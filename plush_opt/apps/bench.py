"""``plush-opt bench``: where the time goes, measured.

For each problem and mesh size: model build (a fresh process with an empty
kernel cache, and one with the cache populated), one Hessian evaluation,
one factorisation, a forward solve from rest, a warm re-solve after a
0.5 mm contraction change (first-order predictor), one control iterate, and
a full inverse solve with each method. Times are medians over repeats in
the same run; every timed solve is also checked (residual, positive
definite Hessian). Writes ``bench.json`` and ``bench.md``.
"""

from __future__ import annotations

import functools
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..control import BilevelOptions, BilevelSolver, run_control
from ..solve.equilibrium import EquilibriumOptions, solve_equilibrium
from ..base.linalg import Factorizer
from ..base.low_rank import LowRankHessian
from ..fem.mesh import build_mesh, mesh_for_nodes
from ..problem import from_scene
from .timing import median_time, timed_into
from ..base.files import write_json_atomic, write_text_atomic
from ..io import load_scene
from ..solve.sensitivity import state_sensitivity

NO_EIG = EquilibriumOptions(eigenvalue=False)


def machine() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import casadi
    import scipy
    from .. import __version__
    try:
        from importlib.metadata import version
        sksparse = version("scikit-sparse")
    except Exception:  # noqa: BLE001 - version is informative only
        sksparse = "?"
    from ..base.linalg import BACKEND
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "numpy": np.__version__, "scipy": scipy.__version__, "casadi": casadi.__version__,
            "scikit-sparse": sksparse, "linear_solver": BACKEND, "plush_opt": __version__,
            "platform": platform.platform()}


_BUILD_SNIPPET = """
import sys, time, json
from plush_opt.io import load_scene
from plush_opt.fem.mesh import build_mesh, mesh_for_nodes
from plush_opt.fem.model import build_model
scene = load_scene(sys.argv[1]).replace(element=sys.argv[3])
mesh = build_mesh(scene) if sys.argv[2] == "0" else mesh_for_nodes(scene, int(sys.argv[2]))
t = time.perf_counter(); build_model(scene, mesh); print(json.dumps(time.perf_counter() - t))
"""


def _build_in_fresh_process(problem: Path, nodes: int, element: str, cache: str) -> float:
    env = dict(os.environ, PLUSH_OPT_CACHE=cache)
    p = subprocess.run([sys.executable, "-c", _BUILD_SNIPPET, str(problem), str(nodes), element],
                       capture_output=True, text=True, env=env, timeout=600, check=True)
    return float(json.loads(p.stdout.strip().splitlines()[-1]))


def _default_contraction(model, name: str) -> np.ndarray:
    if name == "gripper":
        return np.full(model.n_winches, 10.0)      # the figure the targets were set against
    return model.lower + 0.4 * (model.upper - model.lower)


def _certified(eq) -> bool:
    return bool(eq.converged and eq.positive_definite and eq.relative_residual <= 1e-9)


def _build_times(problem: Path, nodes: int, element: str, repeats: int) -> dict:
    """Model build in a fresh process, with an empty and a populated kernel cache."""
    runs = max(1, min(repeats, 3))
    with tempfile.TemporaryDirectory() as cache:
        uncached = [_build_in_fresh_process(problem, nodes, element, tempfile.mkdtemp(dir=cache))
                    for _ in range(runs)]
        _build_in_fresh_process(problem, nodes, element, cache)   # populate
        cached = [_build_in_fresh_process(problem, nodes, element, cache) for _ in range(runs)]
    return {"build_uncached_s": float(np.median(uncached)), "build_cached_s": float(np.median(cached))}


def _solve_with_parts(model, c, x0, options, repeats: int) -> tuple[dict, object]:
    """One solve timed whole and by parts inside it (CPU seconds: one BLAS
    thread, so other processes on a shared machine do not count): the
    model's evaluations and the factorisations (each factorisation's
    call, pivot test and low-rank set-up included), and how many. The run
    of median total time among ``repeats``; (parts, its equilibrium)."""
    fz = model.factorizer
    plain = {"evaluate": model.evaluate, "evaluate_moved": getattr(model, "evaluate_moved", None),
             "factor": fz.factor}
    runs = []
    for _ in range(repeats):
        parts = {"evaluate_s": 0.0, "factorise_s": 0.0, "evaluations": 0, "factorisations": 0}
        model.evaluate = timed_into(parts, plain["evaluate"], "evaluate_s", "evaluations")
        if plain["evaluate_moved"] is not None:     # (a falling body's end: an evaluation too)
            model.evaluate_moved = timed_into(parts, plain["evaluate_moved"], "evaluate_s", "evaluations")
        fz.factor = timed_into(parts, plain["factor"], "factorise_s", "factorisations")
        try:
            t = time.process_time()
            eq = solve_equilibrium(model, c, x0, options)
            parts["total_s"] = time.process_time() - t
        finally:
            del model.evaluate, fz.factor
            if plain["evaluate_moved"] is not None:
                del model.evaluate_moved
        runs.append((parts, eq))
    runs.sort(key=lambda run: run[0]["total_s"])
    return runs[len(runs) // 2]


def _control_cpu(model, targets) -> dict:
    """A reparam control run's iterates timed in CPU seconds (the starting
    solve left out), with the factorisations inside them counted and timed:
    the median iterate, factorisations per iterate, and the iterates' total
    over the factorisations' (their calls, pivot tests, low-rank set-up);
    the last line search, which ends the run, is none of them."""
    from ..control.gradient import Controller
    fz = model.factorizer
    plain, parts = fz.factor, {"n": 0, "s": 0.0}

    def factor(*args, **kwargs):
        t = time.process_time()
        try:
            return plain(*args, **kwargs)
        finally:
            parts["s"] += time.process_time() - t
            parts["n"] += 1
    steps, times = Controller(model, targets).iterates(), []
    next(steps)                                  # the starting solve
    fz.factor, t = factor, time.process_time()
    inside = dict(parts)
    try:
        for _ in steps:
            times.append(time.process_time() - t)
            inside = dict(parts)     # (the search that finds no next iterate is no iterate's: left out)
            t = time.process_time()
    finally:
        del fz.factor
    return {} if not times else {
        "control_iterate_cpu_s": float(np.median(times)), "control_factorisations": inside["n"] / len(times),
        "control_factor_ratio": float(np.sum(times)) / inside["s"] if inside["s"] else None}


def _factor_times(model, hessian, repeats: int) -> dict:
    """The factorisation the model takes, and CHOLMOD's two modes side by side."""
    row = {"factor_mode": None}
    row["factor_s"], _ = median_time(lambda: model.factorizer.factor(hessian), 5 * repeats)
    row["factor_mode"] = f"{model.factorizer.backend} {model.factorizer.mode_used}"
    if model.factorizer.backend == "cholmod":
        for mode in ("simplicial", "supernodal"):
            fz = Factorizer("cholmod", mode)
            fz.factor(hessian)                          # symbolic analysis, once
            row[f"factor_{mode}_s"], _ = median_time(lambda: fz.factor(hessian), 5 * repeats)
    return row


def bench_one(problem: Path, size, repeats: int, progress, element: str = "P1",
              inverse_max_nodes: int | None = None) -> dict:
    """One problem on one mesh. ``size``: about that many nodes (0: the mesh
    the file asks for), or ``("accuracy", TOL)``: the element and mesh
    ``--accuracy TOL`` picks (then ``element`` is ignored). Inverse solves
    are skipped above ``inverse_max_nodes``."""
    scene = load_scene(problem)
    if isinstance(size, tuple):
        picked = from_scene(scene, accuracy=size[1])
        scene, mesh, nodes = picked.scene, picked.mesh, None
    else:
        nodes = size
        scene = scene.replace(element=element)
        mesh = build_mesh(scene) if nodes == 0 else mesh_for_nodes(scene, nodes)
    name = scene.name
    row = {"problem": name, "target_nodes": nodes, "accuracy": size[1] if isinstance(size, tuple) else None,
           "element": mesh.element.name, "nodes": mesh.n_nodes, "elements": mesh.n_elems}
    label = f"{name} @ {mesh.n_nodes} nodes {mesh.element}"
    if nodes is not None:
        progress(f"{label}: model build")
        row.update(_build_times(problem, nodes, mesh.element.name, repeats))
    problem = from_scene(scene, mesh)
    model = problem.model
    row["friction"] = problem.plant.path_dependent      # the pose depends on the path (marked *)
    c = _default_contraction(model, name)
    row["contraction"] = c.tolist()

    progress(f"{label}: Hessian, factorisation, forward solve")
    eq = solve_equilibrium(model, c, options=NO_EIG)
    ev = model.evaluate(eq.x, c)
    row["hessian_s"], _ = median_time(lambda: model.evaluate(eq.x, c, 2), 5 * repeats)
    row["energy_s"], _ = median_time(lambda: model.evaluate(eq.x, c, 0), 5 * repeats)
    form = ev.hessian_form
    # (a body without pins is gauged on an assembled Hessian, low-rank model or not)
    low_rank = isinstance(form, LowRankHessian)
    row["hessian_form"] = "low_rank" if low_rank else "assembled"
    row["low_rank_k"] = form.M.shape[0] if low_rank else None
    row.update(_factor_times(model, form, repeats))
    row["forward_s"], fwd = median_time(lambda: solve_equilibrium(model, c, options=NO_EIG), repeats)
    row["forward_iterations"] = fwd.iterations
    # the parts timed inside one and the same solve (CPU time)
    parts, _ = _solve_with_parts(model, c, None, NO_EIG, repeats)
    row["forward_parts"] = parts
    row["forward_factorisations"] = parts["factorisations"]
    row["forward_ratio"] = parts["total_s"] / (parts["evaluate_s"] + parts["factorise_s"])
    row["forward_factor_ratio"] = (parts["total_s"] / parts["factorise_s"] if parts["factorisations"] else None)
    row["forward_certified"] = _certified(fwd)
    row["min_eigenvalue"] = fwd.factor.min_eigenvalue() if fwd.factor is not None else None

    progress(f"{label}: warm re-solve")
    dc = np.zeros_like(c)
    dc[0] = 0.5
    dxdc = state_sensitivity(model, fwd)
    x_pred = fwd.x + dxdc @ dc
    row["resolve_s"], warm = median_time(lambda: solve_equilibrium(model, c + dc, x_pred, NO_EIG), repeats)
    row["resolve_iterations"] = warm.iterations
    row["resolve_certified"] = _certified(warm)
    cold = solve_equilibrium(model, c + dc, fwd.x, NO_EIG)
    row["resolve_without_predictor_iterations"] = cold.iterations

    row.update(_bench_inverse(problem, mesh.n_nodes, repeats, progress, label, inverse_max_nodes))
    return row


def _bench_inverse(problem, nodes: int, repeats: int, progress, label: str, inverse_max_nodes) -> dict:
    """The inverse solves of ``problem`` (a Problem on ``nodes`` nodes): the gradient loop with each
    bounds method, the control iterate (wall, CPU), the bilevel method; none above ``inverse_max_nodes``."""
    model, targets, out = problem.model, problem.targets, {}
    if targets.n_targets and inverse_max_nodes is not None and nodes > inverse_max_nodes:
        out["inverse_skipped"] = f"above --inverse-max-nodes {inverse_max_nodes}"
    elif targets.n_targets:
        for method in ("reparam", "clip"):
            progress(f"{label}: inverse solve ({method})")
            t_run, res = median_time(lambda: run_control(model, targets, method), max(1, repeats // 2))
            steps = np.diff([h.t_wall for h in res.history])
            out[f"inverse_{method}_s"] = t_run
            out[f"inverse_{method}_iterates"] = res.stats.iterations
            out[f"inverse_{method}_objective"] = res.objective
            out[f"inverse_{method}_status"] = res.status
            out[f"inverse_{method}_newton_iterations"] = res.stats.newton_iterations
            out[f"inverse_{method}_certified"] = all(_certified(h.equilibrium) for h in res.history)
            if method == "reparam":
                out["control_iterate_s"] = float(np.median(steps)) if steps.size else None
                out["control_iterate_max_s"] = float(np.max(steps)) if steps.size else None
                if not problem.plant.path_dependent:
                    out.update(_control_cpu(model, targets))
        if problem.plant.path_dependent:
            out["inverse_bilevel_skipped"] = "the bilevel method solves for the final pose alone; this pose depends on its path"
        else:
            out.update(_bench_bilevel(model, targets, repeats, progress, label))
    return out


def _bench_bilevel(model, targets, repeats, progress, label) -> dict:
    progress(f"{label}: inverse solve (bilevel)")
    solver = BilevelSolver(model)
    c0 = model.scene.contraction
    frozen = model.scene.frozen
    run = lambda: solver.solve(targets, c0, frozen, options=BilevelOptions())  # noqa: E731
    t_first = time.perf_counter()
    first = run()                      # the reduced space builds its small IPOPT problem per solve
    t_first = time.perf_counter() - t_first
    t_run, res = median_time(run, max(1, repeats // 2))
    info = res.stats.details
    # reduced space (the default): evaluations = the Newton solves and the
    # sensitivities at the points IPOPT asks for (every one certified, so
    # there is no separate certification); IPOPT's own = the rest of its
    # rounds (its n_free-sized algebra and the callbacks' overhead)
    calls = info.calls or {}
    return {"inverse_bilevel_s": t_run, "inverse_bilevel_setup_s": float(first.stats.t_setup),
            "inverse_bilevel_first_s": t_first,
            "inverse_bilevel_objective": float(res.objective),
            "inverse_bilevel_status": res.status, "inverse_bilevel_reason": res.reason,
            "inverse_bilevel_iterations": res.stats.iterations,
            "inverse_bilevel_certified": bool(res.converged and res.equilibrium.converged),
            "inverse_bilevel_formulation": info.formulation,
            "inverse_bilevel_ipopt_s": info.t_ipopt_total,
            "inverse_bilevel_own_s": info.t_inside_ipopt,
            "inverse_bilevel_evaluations_s": info.t_function_evaluations,
            "inverse_bilevel_equilibrium_solves": int(calls.get("equilibrium_solves", 0)),
            "inverse_bilevel_failed_solves": int(calls.get("failed_equilibrium_solves", 0)),
            "inverse_bilevel_rounds": int(calls.get("ipopt_rounds", 1))}


def _all_certified(row) -> bool:
    return all(row.get(f"inverse_{m}_certified", True) for m in ("reparam", "clip", "bilevel"))


def _ms(v):
    return "—" if v is None else f"{1e3 * v:.1f}"


def _s(v, digits):
    return "—" if v is None else f"{v:.{digits}f}"


def _element(r) -> str:
    """P1/P2, and the tolerance for a mesh --accuracy picked."""
    return r["element"] if r.get("accuracy") is None else f"{r['element']} (--accuracy {r['accuracy']:g})"


def _factor_lines(rows) -> list[str]:
    """CHOLMOD's simplicial LDL^T against its supernodal LL^T, where measured."""
    rows = [r for r in rows if "factor_simplicial_s" in r]
    if not rows:
        return []
    lines = ["", "## Factorisation: simplicial against supernodal", "",
             "One numeric factorisation of the Hessian (symbolic analysis reused). `auto` "
             "(what the model takes) is supernodal from linalg.SUPERNODAL_MIN_ENTRIES entries on.", "",
             "| problem | element | nodes | simplicial [ms] | supernodal [ms] | simplicial / supernodal | auto |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        ratio = r["factor_simplicial_s"] / r["factor_supernodal_s"]
        lines.append(f"| {r['problem']} | {_element(r)} | {r['nodes']} | {_ms(r['factor_simplicial_s'])} | "
                     f"{_ms(r['factor_supernodal_s'])} | {ratio:.2f} | {r['factor_mode'].split()[-1]} |")
    return lines


def _status_lines(rows) -> list[str]:
    """Each inverse solve's status, and what was skipped and why."""
    lines = ["", "Statuses:", ""]
    for r in rows:
        for method in ("reparam", "clip", "bilevel"):
            key = f"inverse_{method}_status"
            if key in r:
                lines.append(f"- {r['problem']} @ {r['nodes']} nodes {_element(r)}, {method}: {r[key]}")
        if "inverse_bilevel_skipped" in r:
            lines.append(f"- {r['problem']} @ {r['nodes']} nodes {_element(r)}, bilevel: not run "
                         f"({r['inverse_bilevel_skipped']})")
        if "inverse_skipped" in r:
            lines.append(f"- {r['problem']} @ {r['nodes']} nodes {_element(r)}: inverse solves skipped "
                         f"({r['inverse_skipped']})")
    return lines


def _inverse_lines(rows) -> list[str]:
    """The inverse-control table: the control iterate and each method's run."""
    lines = ["", "## Inverse control", "",
             "Control iterate: wall time median (max) within the reparam run; CPU: the median iterate "
             "of another reparam run in CPU time, its factorisations per iterate and its iterates' "
             "total over their factorisations' (timed inside the same run).", "",
             "| problem | element | nodes | control iterate [ms] median (max) | control iterate CPU [ms] "
             "(factorisations per iterate; iterates / factorisations) | reparam: time [s], iterates, O | "
             "clip: time [s], iterates, O | bilevel: time [s], iterations, O | all iterates certified |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "inverse_reparam_s" not in r:
            continue
        bil = ("not available" if "inverse_bilevel_s" not in r else
               f"{r['inverse_bilevel_s']:.3f}, {r['inverse_bilevel_iterations']}, "
               f"{r['inverse_bilevel_objective']:.4g}")
        lines.append(
            f"| {r['problem']} | {_element(r)} | {r['nodes']} | {_ms(r['control_iterate_s'])} ({_ms(r['control_iterate_max_s'])}) | "
            f"{_ms(r.get('control_iterate_cpu_s'))} ({_s(r.get('control_factorisations'), 2)}; "
            f"{_s(r.get('control_factor_ratio'), 2)}) | "
            f"{r['inverse_reparam_s']:.3f}, {r['inverse_reparam_iterates']}, {r['inverse_reparam_objective']:.4g} | "
            f"{r['inverse_clip_s']:.3f}, {r['inverse_clip_iterates']}, {r['inverse_clip_objective']:.4g} | "
            f"{bil} | {'yes' if _all_certified(r) else 'NO'} |")
    return lines


def render_markdown(report: dict) -> str:
    m = report["machine"]
    lines = [
        "# Benchmarks",
        "",
        f"Command: `{report['command']}`  ",
        f"Machine: {m['cpu']}, {m['cores']} cores; Python {m['python']}, numpy {m['numpy']}, "
        f"scipy {m['scipy']}, CasADi {m['casadi']}, scikit-sparse {m['scikit-sparse']}; sparse LDL^T by {m['linear_solver']}.  ",
        f"Date: {report['date']}. Times are medians over {report['repeats']} repeats (5x that for "
        "single evaluations) in one run; the machine is shared and noisy, so compare figures "
        "within a table, not across runs."
        + (f" {report['jobs']} cases ran at once (--jobs): each time was taken beside the others."
           if report.get("jobs", 1) > 1 else ""),
        *(f"Failed: {line}" for line in report.get("failed", ())),
        "",
        "## Forward model",
        "",
        "The two ratios are timed inside one and the same solve (CPU time): the whole over the "
        "time spent in the model's evaluations and the factorisations (Python overhead, line "
        "search bookkeeping and solves above 1), and the whole over the factorisations alone "
        "(their calls, pivot tests and low-rank set-up).",
        "",
        "A scene with friction at via points (marked *) is timed here without it (its model's "
        "single-spring equilibrium): with friction a pose depends on its path, which "
        "`tools/bench_friction.py` times.",
        "",
        "| problem | element | nodes | elements | build, no cache [s] | build, cached [s] | Hessian [ms] | "
        "factorisation [ms] (mode) | forward from rest [ms] (iterations; factorisations) | "
        "forward / (evaluations + factorisations) | forward / factorisations | "
        "warm re-solve [ms] (its; without predictor) | certified |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        lines.append(
            f"| {r['problem']}{'*' if r.get('friction') else ''} | {_element(r)} | {r['nodes']} | {r['elements']} | "
            f"{_s(r.get('build_uncached_s'), 2)} | "
            f"{_s(r.get('build_cached_s'), 3)} | {_ms(r['hessian_s'])} | {_ms(r['factor_s'])} ({r['factor_mode']}) | "
            f"{_ms(r['forward_s'])} ({r['forward_iterations']}; {r.get('forward_factorisations', '—')}) | "
            f"{_s(r['forward_ratio'], 2)} | {_s(r.get('forward_factor_ratio'), 2)} | "
            f"{_ms(r['resolve_s'])} ({r['resolve_iterations']}; {r['resolve_without_predictor_iterations']}) | "
            f"{'yes' if r['forward_certified'] and r['resolve_certified'] else 'NO'} |")
    lines += _factor_lines(report["rows"])
    lines += _inverse_lines(report["rows"])
    lines += _status_lines(report["rows"])
    bil = [r for r in report["rows"] if "inverse_bilevel_s" in r]
    if bil:
        lines += ["", "## Where the bilevel method's time goes", "",
                  "Reduced space (the default). Setup: building the IPOPT problem on the free "
                  "contractions (nothing is generated or compiled). Evaluations: the Newton solves "
                  "(warm-started, certified) and the sensitivities at the points IPOPT asks for. "
                  "IPOPT's own: the rest of its rounds (its algebra on n_free variables and the "
                  "callbacks' overhead). Solve / reparam: the bilevel time over "
                  "the gradient loop's in the same run.", "",
                  "| problem | element | nodes | setup [s] | solve, set-up included [s] | solve / reparam | IPOPT iterations "
                  "(rounds) | equilibrium solves (failed) | evaluations [s] | IPOPT's own [s] |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r in bil:
            f = lambda v: "—" if v is None else f"{v:.3f}"  # noqa: E731
            ratio = r["inverse_bilevel_s"] / r["inverse_reparam_s"]   # each solve builds its own IPOPT problem
            lines.append(f"| {r['problem']} | {_element(r)} | {r['nodes']} | {r['inverse_bilevel_setup_s']:.3f} | "
                         f"{r['inverse_bilevel_s']:.3f} | {ratio:.2f} | {r['inverse_bilevel_iterations']} "
                         f"({r['inverse_bilevel_rounds']}) | {r['inverse_bilevel_equilibrium_solves']} "
                         f"({r['inverse_bilevel_failed_solves']}) | "
                         f"{f(r['inverse_bilevel_evaluations_s'])} | {f(r['inverse_bilevel_own_s'])} |")
    lines.append("")
    return "\n".join(lines)


def _say(msg: str) -> None:
    print(f"bench: {msg}", file=sys.stderr, flush=True)


def _bench_case(case: tuple, repeats: int, inverse_max_nodes, quiet: bool) -> dict:
    """One input of the bench's batch: (problem, size, element)."""
    problem, size, element = case
    return bench_one(Path(problem), size, repeats, (lambda msg: None) if quiet else _say, element,
                     inverse_max_nodes)


def run_bench(problems, sizes, out: Path, repeats: int = 5, command: str = "", progress=None,
              elements=("P1",), inverse_max_nodes: int | None = None, jobs: int = 1) -> dict:
    """Bench every problem at every size with every element (a size
    ``("accuracy", TOL)`` once: it picks its own element). ``jobs`` > 1
    benches that many cases at once (plush_opt.batch): quicker, but each
    time is then taken beside the others (the report says how many); a case
    that fails is reported and the others run."""
    from ..batch import run_batch
    progress = progress or _say
    cases = [(str(problem), size, element) for problem in problems for size in sizes
             for element in (elements[:1] if isinstance(size, tuple) else elements)]
    batch = run_batch(functools.partial(_bench_case, repeats=repeats, inverse_max_nodes=inverse_max_nodes,
                                        quiet=progress is not _say), cases, jobs=jobs)
    rows = [item.value for item in batch.items if item.ok]
    failed = [f"{Path(c[0]).name} size {c[1]} {c[2]}: {item.status}" + (f": {item.error}" if item.error else "")
              for c, item in zip(cases, batch.items) if not item.ok]
    for line in failed:
        progress(line)
    report = {"command": command, "machine": machine(), "date": time.strftime("%Y-%m-%d %H:%M"),
              "repeats": repeats, "sizes": [list(s) if isinstance(s, tuple) else s for s in sizes],
              "elements": list(elements), "jobs": batch.jobs, "failed": failed, "rows": rows}
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "bench.json", report)
    write_text_atomic(out / "bench.md", render_markdown(report))
    progress(f"wrote {out / 'bench.md'} and {out / 'bench.json'}")
    batch.raise_if_interrupted()
    return report


def add_bench_parser(sub) -> None:
    from .batch_flags import jobs_arg
    p = sub.add_parser("bench", help="measure build, evaluation, factorisation and solve times",
                       description="Benchmark the shipped problems (or those given) at several mesh sizes.")
    p.add_argument("problems", nargs="*", type=Path, help="problem files (default: the shipped problems/*.yaml)")
    p.add_argument("--sizes", default="300,1000,3000",
                   help="approximate node counts, comma separated; 'file' for the mesh the problem asks "
                        "for; 'accuracy=TOL' for the element and mesh --accuracy TOL picks")
    p.add_argument("--elements", default="P1", help="elements to bench each size with: P1, P2 or P1,P2")
    p.add_argument("--inverse-max-nodes", type=int, default=None, metavar="N",
                   help="skip the inverse solves on meshes above N nodes (they take minutes at 30,000)")
    p.add_argument("--repeats", type=int, default=5, help="repeats per timing (median taken)")
    p.add_argument("--out", type=Path, default=Path("out/bench"),
                   help="output folder for bench.md and bench.json (peers.*, contact.*); default out/bench")
    p.add_argument("--contact", action="store_true",
                   help="measure what contact costs instead (contact.md, contact.json): a slab on the floor "
                        "against it pinned, at --sizes (node counts), and hexapod_stand's control iterate")
    p.add_argument("--peers", action="store_true",
                   help="instead: the forward solve against FElupe and scikit-fem (the [bench] extra) on the "
                        "first problem's body and mesh under gravity, at each size; writes peers.md and peers.json")
    p.add_argument("--jobs", "-j", type=jobs_arg, default=1, metavar="N",
                   help="cases benched at once (default 1: every time taken alone on the machine)")
    p.set_defaults(func=cmd_bench)


def _cmd_peers(args, problems, sizes, elements, command, quiet) -> int:
    """``--peers``: our forward solve against FElupe and scikit-fem (apps/bench_peers.py)."""
    from ..base.errors import SceneError
    from .bench_peers import available_peers, bench_peers, render_peers
    if any(not isinstance(s, int) or s == 0 for s in sizes):
        raise SceneError(f"--sizes: --peers takes node counts only, got {args.sizes!r}")
    if elements != ("P1",):
        raise SceneError(f"--elements: --peers compares linear triangles (P1) only, got {args.elements!r}")
    if not available_peers():
        raise SceneError("--peers: neither FElupe nor scikit-fem is installed (`pip install 'plush_opt[bench]'`)")
    progress = quiet or (lambda msg: print(f"bench: {msg}", file=sys.stderr, flush=True))
    if not args.problems:                  # (default: the gripper, the figure the issue of speed is set against)
        from ..base.data_files import data_file
        problems = [data_file("problems") / "gripper.yaml"]
    rows = bench_peers(Path(problems[0]), sizes, args.repeats, progress)
    report = {"command": command, "machine": machine(), "date": time.strftime("%Y-%m-%d %H:%M"),
              "repeats": args.repeats, "rows": rows}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / "peers.json", report)
    m = report["machine"]
    head = ["# Against FElupe and scikit-fem", "", f"Command: `{command}`  ",
            f"Machine: {m['cpu']}, {m['cores']} cores; sparse LDL^T by {m['linear_solver']}.  ",
            f"Date: {report['date']}."]
    write_text_atomic(args.out / "peers.md", "\n".join(head + render_peers(rows, command, args.repeats)) + "\n")
    progress(f"wrote {args.out / 'peers.md'} and {args.out / 'peers.json'}")
    return 0


def _parse_size(token: str):
    token = token.strip()
    if token == "file":
        return 0
    if token.startswith("accuracy="):
        tol = float(token.split("=", 1)[1])
        if not (np.isfinite(tol) and tol > 0):
            raise ValueError(token)
        return ("accuracy", tol)
    nodes = int(token)
    if nodes < 10:
        raise ValueError(token)
    return nodes


def cmd_bench(args) -> int:
    from ..base.errors import SceneError
    from ..io.scene import ELEMENTS
    try:
        sizes = [_parse_size(s) for s in args.sizes.split(",") if s.strip()]
    except ValueError:
        raise SceneError(f"--sizes: every size must be 'file', 'accuracy=TOL' (TOL > 0) or at least "
                         f"10 nodes, got {args.sizes!r}") from None
    if not sizes:
        raise SceneError(f"--sizes: no size given in {args.sizes!r}")
    elements = tuple(e.strip() for e in args.elements.split(",") if e.strip())
    if not elements or any(e not in ELEMENTS for e in elements):
        raise SceneError(f"--elements: expected P1, P2 or P1,P2, got {args.elements!r}")
    if args.repeats < 1:
        raise SceneError(f"--repeats: expected >= 1, got {args.repeats}")
    if args.inverse_max_nodes is not None and args.inverse_max_nodes < 0:
        raise SceneError(f"--inverse-max-nodes: expected >= 0, got {args.inverse_max_nodes}")
    command = "plush-opt bench " + " ".join(sys.argv[2:]) if len(sys.argv) > 2 else "plush-opt bench"
    if args.contact and args.peers:
        raise SceneError("--contact and --peers: give one of them (each is a bench of its own)")
    if args.contact:
        from .bench_contact import run_contact_bench
        if any(not isinstance(n, int) or n == 0 for n in sizes):
            raise SceneError(f"--sizes: --contact takes node counts only, got {args.sizes!r}")
        progress = (lambda msg: None) if getattr(args, "quiet", False) else print
        run_contact_bench(sizes, args.out, args.repeats, command, progress)
        return 0
    if args.problems:
        problems = args.problems
    else:
        from ..base.data_files import data_file
        problems = sorted(data_file("problems").glob("*.yaml"))
    missing = [p for p in problems if not Path(p).is_file()]
    if missing or not problems:
        raise SceneError(f"{missing[0]}: no such problem file" if missing else
                         "no problem files to benchmark (none given, none shipped)")
    quiet = (lambda msg: None) if getattr(args, "quiet", False) else None
    if getattr(args, "peers", False):
        return _cmd_peers(args, problems, sizes, elements, command, quiet)
    report = run_bench(problems, sizes, args.out, args.repeats, command, progress=quiet, elements=elements,
                       inverse_max_nodes=args.inverse_max_nodes, jobs=args.jobs)
    return 3 if report["failed"] else 0
