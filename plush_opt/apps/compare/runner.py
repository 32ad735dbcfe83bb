"""Running the comparison: every method on every problem, element, mesh and
tolerance, errors against a converged P2 reference, and the Pareto front."""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...solve.accuracy import base_area, equilibrium_at, transfer_pose
from ...control import BilevelOptions, ControlOptions, run_control
from ...solve.equilibrium import EquilibriumOptions, solve_equilibrium
from ...base.errors import PlushError, SceneError
from ...problem import from_scene
from ...io import load_scene
from ...fem.mesh import build_mesh
from .report import write_outputs
from .settings import BILEVEL_TOL, GRADIENT_TOL, LARGE_SHORTFALL, METHODS, CompareSettings, Run

log = logging.getLogger(__name__)


@dataclass
class _Problem:
    path: Path
    scene: object
    levels: dict                # (element, factor) -> (Problem, t_build)
    start: np.ndarray
    frozen: np.ndarray
    reference: object = None    # the P2 reference Problem
    check: object = None        # the coarser P2 level that checks the reference


# --------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------

def _level(scene, factor, element=None, graded=False):
    t0 = time.perf_counter()
    if element is not None and element != scene.element:
        scene = dataclasses.replace(scene, element=element)
    max_area = None if scene.outline is None else base_area(scene) * factor
    p = from_scene(scene, build_mesh(scene, max_area, graded=graded))
    # the first factorisation does CHOLMOD's symbolic analysis: setup, not solve
    solve_equilibrium(p.model, scene.contraction, options=EquilibriumOptions(eigenvalue=False))
    return p, time.perf_counter() - t0


def _levels(scene, settings: CompareSettings) -> dict:
    """(element, factor) -> (Problem, t_build): the file's element at every
    factor (and the large level), each other element of the sweep at every
    factor. An explicit mesh has one level."""
    if scene.outline is None:
        return {(scene.element, settings.main_factor): _level(scene, settings.main_factor)}
    own = {f: _level(scene, f) for f in settings.mesh_factors}
    large = _large_factor(own, settings)
    if large is not None:
        own[large] = _level(scene, large)
    levels = {(scene.element, f): v for f, v in own.items()}
    for element in settings.elements:
        if element != scene.element:
            levels.update({(element, f): _level(scene, f, element) for f in settings.mesh_factors})
    return levels


def _large_factor(levels: dict, settings: CompareSettings) -> float | None:
    """The max_area factor of a level with about ``settings.large_nodes``
    nodes (nodes scale as 1 / max_area), or None if the finest is close."""
    if settings.large_nodes is None:
        return None
    finest = min(levels)
    n = levels[finest][0].mesh.n_nodes
    if len(levels) < 2 or n >= LARGE_SHORTFALL * settings.large_nodes:
        return None
    return finest * n / settings.large_nodes


def _bound_violation(model, c) -> float:
    c = np.asarray(c, dtype=np.float64)
    return float(max(0.0, np.max(model.lower - c), np.max(c - model.upper)))


def _run(problem: _Problem, method: str, tol: str, level: tuple, sweep: str,
         settings: CompareSettings) -> Run:
    runs = [_run_once(problem, method, tol, level, sweep, settings) for _ in range(settings.repeat)]
    # the run of median time (the lower median of an even count): one fast outlier is not the method's speed
    ranked = sorted(runs, key=lambda r: r.t_solve if math.isfinite(r.t_solve) else math.inf)
    best = ranked[(len(ranked) - 1) // 2]
    best.t_setup = runs[0].t_setup
    if best.ipopt_history is not None and settings.resolve_bilevel_iterates and sweep == "main":
        p, _ = problem.levels[level]
        best.resolved = _resolve_iterates(p.model, p.targets, *best.ipopt_history)
    return best


def _run_once(problem: _Problem, method: str, tol: str, level: tuple, sweep: str,
              settings: CompareSettings) -> Run:
    p, _ = problem.levels[level]
    mesh, model, targets = p.mesh, p.model, p.targets
    scene = problem.scene
    element, factor = level
    run = Run(scene.name, method, sweep, tol, element, factor,
              None if scene.outline is None else base_area(scene) * factor,
              mesh.n_nodes, mesh.n_elems, mesh=mesh)
    try:
        if method in ("reparam", "clip"):
            opts = ControlOptions(bounds=method, max_time=settings.max_time, **GRADIENT_TOL[tol])
            t0 = time.perf_counter()
            res = run_control(model, targets, method, problem.start, problem.frozen, options=opts)
            # the whole call, as for bilevel: the last iterate is not the end
            # (look-further probes that find nothing, the final certification)
            run.t_solve = time.perf_counter() - t0
            eq = res.equilibrium
            run.converged, run.reason, run.status = res.converged, res.reason, res.status
            run.iterations = res.stats.iterations
            run.equilibrium_solves = res.stats.equilibrium_solves
            run.curve = [(h.t_wall, h.objective, True) for h in res.history]
        else:
            opts = BilevelOptions(max_time=settings.max_time, **BILEVEL_TOL[tol])
            t0 = time.perf_counter()
            res = run_control(model, targets, "bilevel", problem.start, problem.frozen,
                              options=opts, bilevel=p.bilevel_solver)
            t_call = time.perf_counter() - t0
            eq = res.equilibrium
            info = res.stats.details
            run.converged, run.reason, run.status = res.converged, res.reason, res.status
            run.t_setup = res.stats.t_setup
            run.t_solve = t_call - run.t_setup
            run.iterations = res.stats.iterations
            run.equilibrium_solves = res.stats.equilibrium_solves
            pose = info.ipopt_pose
            run.saddle_flagged = bool(pose is not None and pose["admissible"]
                                      and not pose["positive_definite"])
            if info.formulation == "reduced":
                # every iterate is a certified equilibrium: nothing to re-solve
                run.curve = [(h.t_wall, h.objective, h.dispatchable) for h in res.history]
            else:
                t_start = info.start["t_wall"]
                run.curve = ([(t_start, info.start["objective"], True)]
                             + [(t_start + h.t_wall, h.objective, False) for h in res.history]
                             + [(run.t_solve, targets.value(eq.x), True)])
                run.ipopt_history = (t_start, res.history)
        run.x = eq.x
        run.contraction = eq.contraction.copy()
        run.objective = float(targets.value(eq.x))
        run.rms_target_error = float(targets.rms_error(eq.x))
        run.bound_violation = _bound_violation(model, eq.contraction)
        run.stable = bool(eq.converged and eq.positive_definite)
    except PlushError as exc:
        run.status = f"error: {exc}"
    return run


def _resolve_iterates(model, targets, t_start, history) -> list:
    """Certified equilibria at IPOPT's iterate contractions (post hoc)."""
    out = []
    x = None
    for h in history:
        c = np.clip(h.contraction, model.lower, model.upper)
        eq = equilibrium_at(model, c, x)
        if eq.converged:
            x = eq.x
            out.append((t_start + h.t_wall, float(targets.value(eq.x))))
    return out


def _reference(problem: _Problem, runs: list, settings: CompareSettings) -> None:
    """Model error, reference target error and the reference's own check of
    each run: the P2 reference's pose (and its coarser check level's) at the
    run's contractions, from the run's pose carried over."""
    scene = problem.scene
    if problem.reference is None:
        if scene.outline is None:       # an explicit mesh cannot be refined: it is its own reference
            problem.reference = problem.check = problem.levels[(scene.element, settings.main_factor)][0]
        else:
            # graded: uniform meshes converge slowly at reentrant corners (docs/accuracy.md)
            problem.reference = _level(scene, settings.reference_factor, "P2", graded=True)[0]
            problem.check = _level(scene, settings.check_factor, "P2", graded=True)[0]
    ref, chk = problem.reference, problem.check
    cache: dict = {}
    for run in runs:
        if run.contraction is None:
            continue
        key = tuple(np.round(run.contraction, 12))
        if key not in cache:
            xs = []
            for p in (ref, chk):
                eq = equilibrium_at(p.model, run.contraction, transfer_pose(run.mesh, run.x, p.mesh))
                xs.append(eq.x if eq.converged else None)
            cache[key] = xs
        x_ref, x_chk = cache[key]
        if x_ref is None:
            continue
        own = problem.levels[(run.element, run.mesh_factor)][0].targets
        run.model_error = _rms(own.y(run.x) - ref.targets.y(x_ref))
        run.fine_target_error = float(ref.targets.rms_error(x_ref))
        if x_chk is not None:
            run.reference_difference = _rms(ref.targets.y(x_ref) - chk.targets.y(x_chk))


def _rms(d) -> float:
    return float(np.sqrt(np.mean(np.sum(np.asarray(d) ** 2, axis=1))))


def pareto_front(points, rel: float = 1e-3) -> list[int]:
    """Indices of the non-dominated (time, error) pairs (both minimised),
    sorted by time. A slower point joins the front only if it lowers the
    error by more than ``rel`` (relative): errors that differ in the last
    digits are the same answer."""
    pts = [(t, e, i) for i, (t, e) in enumerate(points) if math.isfinite(t) and math.isfinite(e)]
    pts.sort()
    front, best = [], math.inf
    for t, e, i in pts:
        if e < best * (1 - rel) or (best == math.inf):
            front.append(i)
            best = e
    return front


def run_compare(problem_paths, out_dir, coarse: bool = False, progress=None,
                settings: CompareSettings | None = None) -> dict:
    """Run the comparison on every problem and write the report.

    Parameters
    ----------
    problem_paths : problem files (YAML) with targets.
    out_dir : output folder (created).
    coarse : use :meth:`CompareSettings.coarse` (a quick run).
    progress : callable(str) called with one line per run (default: log).
    settings : overrides ``coarse``.

    Returns
    -------
    dict with ``runs`` (list of :class:`Run`), ``problems`` (names) and
    ``files`` (paths written).
    """
    settings = settings or (CompareSettings.coarse() if coarse else CompareSettings.full())
    say = progress or log.info
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [Path(p) for p in problem_paths]
    if not paths:
        raise SceneError("compare: no problem files given")
    t_all = time.perf_counter()
    all_runs, problems = [], []
    for k, path in enumerate(paths):
        scene = load_scene(path)
        if not scene.targets:
            raise SceneError(f"{scene.source}: targets: compare needs a control problem; the file has none")
        names = [p.scene.name for p in problems]
        if scene.name in names:
            raise SceneError(f"{scene.source}: name: {scene.name!r} is used by another problem file")
        levels = _levels(scene, settings)
        say(f"compare: [{k + 1}/{len(paths)}] {scene.name}: meshed {len(levels)} level(s)")
        problem = _Problem(path, scene, levels, scene.contraction.copy(), scene.frozen.copy())
        problems.append(problem)
        main = (scene.element, settings.main_factor)
        plan = [(m, "default", main, "main") for m in METHODS]
        plan += [(m, t, main, "tolerance") for m in METHODS
                 for t in settings.tolerances if t != "default"]
        plan += [(m, "default", lv, "mesh") for m in METHODS for lv in levels if lv != main]
        runs = []
        for j, (method, tol, level, sweep) in enumerate(plan):
            run = _run(problem, method, tol, level, sweep, settings)
            runs.append(run)
            say(f"compare: {scene.name} [{j + 1}/{len(plan)}] {method:8s} {sweep:9s} tol={tol:7s} "
                f"{run.element} nodes={run.n_nodes:5d}  O={run.objective:.6g}  t={run.t_solve:.3f} s"
                f"{'' if run.converged else '  (not converged)'}")
        say(f"compare: {scene.name}: errors against the P2 reference")
        _reference(problem, runs, settings)
        # only poses a robot may be sent to belong on the front
        front = pareto_front([(r.t_solve, r.fine_target_error) if r.stable and r.bound_violation == 0
                              else (float("nan"), float("nan")) for r in runs])
        for i in front:
            runs[i].pareto = True
        all_runs += runs
    files = write_outputs(out, problems, all_runs, settings, time.perf_counter() - t_all)
    say(f"compare: wrote {', '.join(str(f) for f in files)}")
    return {"runs": all_runs, "problems": [p.scene.name for p in problems], "files": files}


# --------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------
