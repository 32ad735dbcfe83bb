"""Running the comparison: every method on every problem, element, mesh and
tolerance, errors against a converged P2 reference, and the Pareto front."""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...solve.accuracy import base_area, equilibrium_at, transfer_pose
from ...control import BilevelOptions, ControlOptions, run_control
from ...solve.equilibrium import EquilibriumOptions, solve_equilibrium
from ...solve.result_file import crossing_of
from ...base.errors import PlushError, SceneError
from ...batch import run_batch
from ...problem import from_scene
from ...io import load_scene
from ...fem.mesh import build_mesh
from ...fem.objective import Targets
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

def _level(scene, factor, element=None, graded=False, timed=True):
    t0 = time.perf_counter()
    if element is not None and element != scene.element:
        scene = dataclasses.replace(scene, element=element)
    max_area = None if scene.outline is None else base_area(scene) * factor
    p = from_scene(scene, build_mesh(scene, max_area, graded=graded))
    if timed:
        # the first factorisation does CHOLMOD's symbolic analysis: setup, not the timed solve
        solve_equilibrium(p.model, scene.contraction, options=EquilibriumOptions(eigenvalue=False))
    return p, time.perf_counter() - t0


def level_plan(scene, settings: CompareSettings) -> list[tuple[str, float, int]]:
    """(element, factor, nodes) of every level of the comparison, by meshing
    alone: the file's element at every factor (and the large level), each
    other element of the sweep at every factor. An explicit mesh has one."""
    if scene.outline is None:
        return [(scene.element, settings.main_factor, build_mesh(scene).n_nodes)]
    own = {f: build_mesh(scene, base_area(scene) * f).n_nodes for f in settings.mesh_factors}
    large = _large_factor(own, settings)
    if large is not None:
        own[large] = build_mesh(scene, base_area(scene) * large).n_nodes
    plan = [(scene.element, f, n) for f, n in own.items()]
    for element in settings.elements:
        if element != scene.element:
            other = dataclasses.replace(scene, element=element)
            plan += [(element, f, build_mesh(other, base_area(scene) * f).n_nodes)
                     for f in settings.mesh_factors]
    return plan


def _large_factor(nodes: dict, settings: CompareSettings) -> float | None:
    """The max_area factor of a level with about ``settings.large_nodes``
    nodes (nodes scale as 1 / max_area), or None if the finest is close."""
    if settings.large_nodes is None:
        return None
    finest = min(nodes)
    n = nodes[finest]
    if len(nodes) < 2 or n >= LARGE_SHORTFALL * settings.large_nodes:
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
    run's contractions, from the run's pose carried over. Where either
    creases (the body folded through itself: no converged answer to measure
    against) the run gets ``reference_crease`` and no errors."""
    scene = problem.scene
    if problem.reference is None:
        if scene.outline is None:       # an explicit mesh cannot be refined: it is its own reference
            problem.reference = problem.check = _level(scene, settings.main_factor, timed=False)[0]
        else:
            # graded: uniform meshes converge slowly at reentrant corners (docs/accuracy.md)
            # nothing is timed on them: no setup solve
            problem.reference = _level(scene, settings.reference_factor, "P2", graded=True, timed=False)[0]
            problem.check = _level(scene, settings.check_factor, "P2", graded=True, timed=False)[0]
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
            cache[key] = xs + [_crease(ref, xs[0]) or _crease(chk, xs[1])]
        x_ref, x_chk, crease = cache[key]
        if x_ref is None:
            continue
        if crease:
            run.reference_crease = crease
            continue
        own = Targets.from_mesh(run.mesh, scene)
        run.model_error = _rms(own.y(run.x) - ref.targets.y(x_ref))
        run.fine_target_error = float(ref.targets.rms_error(x_ref))
        if x_chk is not None:
            run.reference_difference = _rms(ref.targets.y(x_ref) - chk.targets.y(x_chk))


def _crease(level, x) -> str:
    """Where the P2 level's pose ``x`` creases (none: \"\"), in words."""
    where = crossing_of(level.model, x, creases_only=True) if x is not None else None
    return f"the P2 level of {level.mesh.n_nodes} nodes creases ({where})" if where else ""


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


@dataclass(frozen=True)
class _MeshOf:
    """What the report needs of a reference level: its mesh (the solvers stay in the worker)."""

    mesh: object


def level_runs(job: tuple, settings: CompareSettings) -> tuple[list, list[str]]:
    """One input of the comparison's first batch: build one level of one
    problem file and make its runs. ``job`` is (path, element, factor,
    plan) with plan a list of (method, tolerance, sweep). Returns the runs
    (without their solvers) and their progress lines."""
    path, element, factor, plan = job
    scene = load_scene(path)
    level = (element, factor)
    problem = _Problem(Path(path), scene, {level: _level(scene, factor, element)},
                       scene.contraction.copy(), scene.frozen.copy())
    runs, lines = [], []
    for method, tol, sweep in plan:
        run = _run(problem, method, tol, level, sweep, settings)
        run.ipopt_history = None        # its iterates hold factorisations: used above, not reported
        runs.append(run)
        lines.append(f"compare: {scene.name} {method:8s} {sweep:9s} tol={tol:7s} "
                     f"{run.element} nodes={run.n_nodes:5d}  O={run.objective:.6g}  t={run.t_solve:.3f} s"
                     f"{'' if run.converged else '  (not converged)'}")
    return runs, lines


def reference_errors(job: tuple, settings: CompareSettings) -> tuple[list, tuple]:
    """One input of the comparison's second batch: the P2 reference of one
    problem file and the errors against it of runs (path, runs) that ended
    at the same contractions. Returns per run (model_error,
    fine_target_error, reference_difference, reference_crease) and the
    (reference, check) meshes."""
    path, runs = job
    scene = load_scene(path)
    problem = _Problem(Path(path), scene, {}, scene.contraction.copy(), scene.frozen.copy())
    _reference(problem, runs, settings)
    return ([(r.model_error, r.fine_target_error, r.reference_difference, r.reference_crease) for r in runs],
            (_MeshOf(problem.reference.mesh), _MeshOf(problem.check.mesh)))


def _plan(scene, settings: CompareSettings) -> list[tuple[str, float, int, list]]:
    """(element, factor, nodes, [(method, tolerance, sweep), ...]) per level,
    the runs of each level in the order of the report."""
    main = (scene.element, settings.main_factor)
    out = []
    for element, factor, nodes in level_plan(scene, settings):
        if (element, factor) == main:
            runs = [(m, "default", "main") for m in METHODS]
            runs += [(m, t, "tolerance") for m in METHODS for t in settings.tolerances if t != "default"]
        else:
            runs = [(m, "default", "mesh") for m in METHODS]
        out.append((element, factor, nodes, runs))
    return out


def _largest_first(jobs: list, size) -> tuple[list, list[int]]:
    """The jobs by decreasing size (a long job started last would leave the
    other workers idle) and, per job, its position in that order."""
    order = sorted(range(len(jobs)), key=lambda i: -size(jobs[i]))
    where = [0] * len(jobs)
    for k, i in enumerate(order):
        where[i] = k
    return [jobs[i] for i in order], where


def run_compare(problem_paths, out_dir, coarse: bool = False, progress=None,
                settings: CompareSettings | None = None, *, jobs: int | None = 1, scheduler=None,
                batch_progress=None) -> dict:
    """Run the comparison on every problem and write the report.

    Parameters
    ----------
    problem_paths : problem files (YAML) with targets.
    out_dir : output folder (created).
    coarse : use :meth:`CompareSettings.coarse` (a quick run).
    progress : callable(str) called with the progress lines, each problem's
        in file order once it finished (default: log).
    settings : overrides ``coarse``.
    jobs, scheduler : the levels and references run as batches
        (:func:`~plush_opt.batch.run_batch`): ``jobs`` worker processes (1:
        one after the other here; None: the cores) or a Dask scheduler.
        The results do not depend on them (the times do: runs share the
        machine, and ``settings.max_time`` stops a run by the clock).
    batch_progress : the batch's progress display (see
        :class:`~plush_opt.batch.progress.Progress`), or None.

    Returns
    -------
    dict with ``runs`` (list of :class:`Run`), ``problems`` (names),
    ``files`` (paths written), ``failed`` ((file, error) of problems whose
    runs could not be made) and ``batches`` (the two BatchResults: one
    input per problem and mesh level, then one per problem and contractions
    reached, for the errors against its reference).
    Interrupted: the problems that finished are written, then the
    interruption is raised.
    """
    settings = settings or (CompareSettings.coarse() if coarse else CompareSettings.full())
    say = progress or log.info
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [Path(p) for p in problem_paths]
    if not paths:
        raise SceneError("compare: no problem files given")
    scenes = []
    for path in paths:          # refused before any work: a bad file is the user's to fix
        scene = load_scene(path)
        if not scene.targets:
            raise SceneError(f"{scene.source}: targets: compare needs a control problem; the file has none")
        if scene.name in [s.name for s in scenes]:
            raise SceneError(f"{scene.source}: name: {scene.name!r} is used by another problem file")
        scenes.append(scene)
    t_all = time.perf_counter()
    first, runs_of, failed = _run_levels(paths, scenes, settings, say, jobs, scheduler, batch_progress)
    if first.interrupted:       # what finished, without the errors against the references
        second = None
        problems = [_Problem(paths[k], scenes[k], {}, scenes[k].contraction.copy(), scenes[k].frozen.copy())
                    for k in range(len(paths)) if k not in failed and runs_of[k]]
        all_runs = [r for k in range(len(paths)) if k not in failed for r in runs_of[k]]
    else:
        second, problems, all_runs = _run_references(paths, scenes, runs_of, failed, settings, jobs,
                                                     scheduler, batch_progress)
    for k in sorted(failed):
        say(f"compare: {paths[k].name}: {failed[k]}")
    files = write_outputs(out, problems, all_runs, settings, time.perf_counter() - t_all) if problems else []
    if files:
        say(f"compare: wrote {', '.join(str(f) for f in files)}")
    for batch in (first, second):
        if batch is not None:
            batch.raise_if_interrupted()
    return {"runs": all_runs, "problems": [p.scene.name for p in problems], "files": files,
            "failed": [(paths[k], failed[k]) for k in sorted(failed)], "batches": (first, second)}


def _run_levels(paths, scenes, settings, say, jobs, scheduler, progress):
    """The first batch: one input per (problem, level), largest meshes
    first. Returns (batch, runs per problem in the report's order,
    {problem index: why it failed})."""
    jobs_1 = [(k, (path, element, factor, plan), nodes) for k, (path, scene) in enumerate(zip(paths, scenes))
              for element, factor, nodes, plan in _plan(scene, settings)]
    say(f"compare: {len(paths)} problem(s), {len(jobs_1)} level(s)")
    ordered, where = _largest_first(jobs_1, lambda j: j[2])
    first = _batch(functools.partial(level_runs, settings=settings), [j[1] for j in ordered],
                   jobs, scheduler, progress, "compare: levels",
                   lambda i: f"{ordered[i][1][0].name} {ordered[i][1][1]} x{ordered[i][1][2]:g}")
    failed: dict[int, str] = {}
    runs_of: list[list] = [[] for _ in paths]
    for j, (k, job, _) in enumerate(jobs_1):
        item = first.items[where[j]]
        if item.status == "failed":
            failed.setdefault(k, f"failed: {item.error}")
        if not item.ok:
            continue
        runs, lines = item.value
        runs_of[k] += runs
        for line in lines:
            say(line)
    for k, scene in enumerate(scenes):
        runs_of[k].sort(key=_report_order(scene, settings))
    return first, runs_of, failed


def _groups(runs: list) -> list[list[int]]:
    """Indices of the runs that ended at the same contractions, in run
    order (the reference solves once per group, from the first one's pose)."""
    groups: dict = {}
    for i, r in enumerate(runs):
        if r.contraction is not None:
            groups.setdefault(tuple(np.round(r.contraction, 12)), []).append(i)
    return list(groups.values())


def _run_references(paths, scenes, runs_of, failed, settings, jobs, scheduler, progress):
    """The second batch: one input per problem and set of runs that ended
    at the same contractions (largest meshes first), their errors against
    the problem's reference. Returns (batch, problems, their runs);
    ``failed`` gets the problems whose reference failed."""
    work = [(k, g) for k in range(len(paths)) if k not in failed for g in _groups(runs_of[k])]
    size = {k: max((r.n_nodes for r in runs_of[k]), default=0) for k in range(len(paths))}
    ordered, where = _largest_first(work, lambda w: size[w[0]])
    second = _batch(functools.partial(reference_errors, settings=settings),
                    [(paths[k], [runs_of[k][i] for i in g]) for k, g in ordered], jobs, scheduler,
                    progress, "compare: references", lambda i: paths[ordered[i][0]].name)
    meshes: dict = {}
    for j, (k, group) in enumerate(work):
        item = second.items[where[j]]
        if not item.ok:
            failed.setdefault(k, f"{item.status}" + (f": {item.error}" if item.error else ""))
            continue
        errors, meshes[k] = item.value
        for i, (model_error, fine, difference, crease) in zip(group, errors):
            run = runs_of[k][i]
            run.model_error, run.fine_target_error, run.reference_difference = model_error, fine, difference
            run.reference_crease = crease
    all_runs, problems = [], []
    for k, scene in enumerate(scenes):
        if k in failed:
            continue
        runs = runs_of[k]
        # only poses a robot may be sent to belong on the front
        front = pareto_front([(r.t_solve, r.fine_target_error) if r.stable and r.bound_violation == 0
                              else (float("nan"), float("nan")) for r in runs])
        for i in front:
            runs[i].pareto = True
        reference, check = meshes.get(k, (None, None))
        problems.append(_Problem(paths[k], scene, {}, scene.contraction.copy(), scene.frozen.copy(),
                                 reference, check))
        all_runs += runs
    return second, problems, all_runs


def _batch(fn, inputs, jobs, scheduler, progress, label, describe):
    if progress is not None:
        progress.label, progress.describe = label, describe
    return run_batch(fn, inputs, jobs=jobs, scheduler=scheduler, progress=progress)


def _report_order(scene, settings: CompareSettings):
    """Sort key of a problem's runs: main runs, then the tolerance sweep,
    then the mesh sweep by method and level (the report's order)."""
    main = (scene.element, settings.main_factor)
    levels = [(e, f) for e, f, _ in level_plan(scene, settings)]
    order = [(m, "default", main, "main") for m in METHODS]
    order += [(m, t, main, "tolerance") for m in METHODS for t in settings.tolerances if t != "default"]
    order += [(m, "default", lv, "mesh") for m in METHODS for lv in levels if lv != main]
    index = {key: i for i, key in enumerate(order)}
    return lambda r: index[(r.method, r.tolerance, (r.element, r.mesh_factor), r.sweep)]


# --------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------
