"""Side-by-side comparison of the control methods: speed against error.

For every problem file, three methods start from the same certified
equilibrium (the file's contractions):

* ``reparam`` - method 1, the sensitivity-driven gradient loop with
  reparametrised bounds (the paper's method);
* ``clip``    - the same loop with plain clipping of c to the bounds;
* ``bilevel`` - IPOPT on the KKT formulation, certified by Newton.

Runs: each method at its default tolerances on the problem's mesh (the
main table and the anytime curves), a sweep over solver tolerances on that
mesh, and a sweep over mesh resolutions at the default tolerances. Errors:

* ``rms_target_error`` - RMS distance of the targets on the run's own mesh;
* ``model_error``      - RMS distance between the run's target points and
  the finest mesh's at the same contractions (the discretisation error);
* ``fine_target_error``- RMS target error of the finest mesh's pose at the
  run's contractions: the best available prediction of what the robot
  would do. The speed-against-error Pareto front uses this one.

Times are wall-clock seconds of the solve (from the starting equilibrium to
the returned pose). Building the model and IPOPT's solver (CasADi
derivative generation, once per model, frozen set and IPOPT options) is
setup, reported separately. The gradient loop's iterates are all certified
equilibria within bounds (dispatchable to the robot); IPOPT's iterates are
not (the equilibrium constraint holds only at convergence), and the curves
mark them differently.

Writes ``report.md``, ``results.csv``, ``curves.csv``, ``anytime.png`` and
``speed_error.png`` to the output folder. :func:`add_compare_parser` adds
``plush-opt compare`` to the command line.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..accuracy import base_area, equilibrium_at, transfer_pose
from ..control import BilevelOptions, ControlOptions, run_control
from ..equilibrium import EquilibriumOptions, solve_equilibrium
from ..errors import PlushError, SceneError
from ..problem import from_scene
from ..results import write_text_atomic
from ..scene import load_scene

log = logging.getLogger(__name__)

METHODS = ("reparam", "clip", "bilevel")
TOLERANCES = ("loose", "default", "tight")

#: Tolerance presets per method family (options fields).
GRADIENT_TOL = {"loose": {"ftol": 1e-3, "gtol": 1e-3}, "default": {},
                "tight": {"ftol": 1e-12, "gtol": 1e-10}}
BILEVEL_TOL = {"loose": {"tol": 1e-4, "acceptable_tol": 1e-3, "constr_viol_tol": 1e-6,
                         "residual_tol": 1e-4, "pose_tol_rel": 1e-3},
               "default": {}, "tight": {"tol": 1e-10, "constr_viol_tol": 1e-12}}


@dataclass(frozen=True)
class CompareSettings:
    """What :func:`run_compare` runs.

    Attributes
    ----------
    mesh_factors : max_area multipliers of the problem's own mesh, coarse to
        fine; must contain ``main_factor``.
    main_factor : the mesh of the main table and the tolerance sweep.
    tolerances : tolerance presets swept on the main mesh (names of
        GRADIENT_TOL / BILEVEL_TOL).
    max_time : seconds per run at most (None: no limit).
    resolve_bilevel_iterates : after the main bilevel run, solve the
        equilibrium at each IPOPT iterate's contractions (not timed) to show
        what sending IPOPT's iterates to the robot would do.
    repeat : run each case this many times and keep the fastest (wall
        times of runs this short are noisy on a shared machine); setup is
        taken from the first run, which pays it.
    """

    mesh_factors: tuple = (4.0, 1.0, 0.25)
    main_factor: float = 1.0
    tolerances: tuple = TOLERANCES
    max_time: float | None = 120.0
    resolve_bilevel_iterates: bool = True
    repeat: int = 3

    def __post_init__(self):
        if not (isinstance(self.repeat, int) and self.repeat >= 1):
            raise ValueError(f"repeat: expected an integer >= 1, got {self.repeat!r}")
        f = tuple(float(v) for v in self.mesh_factors)
        if not f or any(b >= a for a, b in zip(f, f[1:])) or any(v <= 0 for v in f):
            raise ValueError(f"mesh_factors: expected decreasing numbers > 0, got {self.mesh_factors!r}")
        if float(self.main_factor) not in f:
            raise ValueError(f"main_factor: {self.main_factor!r} is not one of mesh_factors {f}")
        bad = [t for t in self.tolerances if t not in TOLERANCES]
        if bad or "default" not in self.tolerances:
            raise ValueError(f"tolerances: expected a subset of {TOLERANCES} with 'default', "
                             f"got {self.tolerances!r}")
        object.__setattr__(self, "mesh_factors", f)

    @classmethod
    def full(cls) -> "CompareSettings":
        return cls()

    @classmethod
    def coarse(cls) -> "CompareSettings":
        """A quick smoke run: coarser meshes, two tolerance presets."""
        return cls(mesh_factors=(8.0, 4.0, 2.0), main_factor=4.0, tolerances=("loose", "default"),
                   max_time=30.0, resolve_bilevel_iterates=False, repeat=1)


@dataclass
class Run:
    """One method on one problem, mesh and tolerance."""

    problem: str
    method: str
    sweep: str                 # 'main', 'tolerance' or 'mesh'
    tolerance: str
    mesh_factor: float
    max_area: float | None
    n_nodes: int
    n_elems: int
    converged: bool = False
    status: str = ""
    objective: float = math.nan
    rms_target_error: float = math.nan
    contraction: np.ndarray | None = None
    t_solve: float = math.nan
    t_setup: float = 0.0
    iterations: int = 0
    equilibrium_solves: int = 0
    bound_violation: float = math.nan
    stable: bool = False
    saddle_flagged: bool = False
    model_error: float = math.nan
    fine_target_error: float = math.nan
    pareto: bool = False
    curve: list = field(default_factory=list)      # (t, O, dispatchable)
    resolved: list = field(default_factory=list)   # bilevel iterates re-solved: (t, O)
    ipopt_history: tuple | None = None              # (t_start, IPOPT iterations)
    x: np.ndarray | None = None
    mesh: object = None


@dataclass
class _Problem:
    path: Path
    scene: object
    levels: dict                # factor -> (Problem, t_build)
    start: np.ndarray
    frozen: np.ndarray


# --------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------

def _level(scene, factor):
    t0 = time.perf_counter()
    p = from_scene(scene, max_area=None if scene.outline is None else base_area(scene) * factor)
    # the first factorisation does CHOLMOD's symbolic analysis: setup, not solve
    solve_equilibrium(p.model, scene.contraction, options=EquilibriumOptions(eigenvalue=False))
    return p, time.perf_counter() - t0


def _bound_violation(model, c) -> float:
    c = np.asarray(c, dtype=np.float64)
    return float(max(0.0, np.max(model.lower - c), np.max(c - model.upper)))


def _run(problem: _Problem, method: str, tol: str, factor: float, sweep: str,
         settings: CompareSettings) -> Run:
    runs = [_run_once(problem, method, tol, factor, sweep, settings) for _ in range(settings.repeat)]
    best = min(runs, key=lambda r: r.t_solve if math.isfinite(r.t_solve) else math.inf)
    best.t_setup = runs[0].t_setup
    if best.ipopt_history is not None and settings.resolve_bilevel_iterates and sweep == "main":
        p, _ = problem.levels[factor]
        best.resolved = _resolve_iterates(p.model, p.targets, *best.ipopt_history)
    return best


def _run_once(problem: _Problem, method: str, tol: str, factor: float, sweep: str,
              settings: CompareSettings) -> Run:
    p, _ = problem.levels[factor]
    mesh, model, targets = p.mesh, p.model, p.targets
    scene = problem.scene
    run = Run(scene.name, method, sweep, tol, factor,
              None if scene.outline is None else base_area(scene) * factor,
              mesh.n_nodes, mesh.n_elems, mesh=mesh)
    try:
        if method in ("reparam", "clip"):
            opts = ControlOptions(bounds=method, max_time=settings.max_time, **GRADIENT_TOL[tol])
            res = run_control(model, targets, method, problem.start, problem.frozen, options=opts)
            eq = res.equilibrium
            run.converged, run.status = res.converged, res.status
            run.t_solve = res.history[-1].t_wall
            run.iterations = res.stats.iterations
            run.equilibrium_solves = res.stats.equilibrium_solves
            run.curve = [(h.t_wall, h.objective, True) for h in res.history]
        else:
            kw = dict(BILEVEL_TOL[tol])
            rel = kw.pop("pose_tol_rel", None)
            if rel is not None:
                kw["pose_tol"] = rel * mesh.diameter
            opts = BilevelOptions(max_time=settings.max_time, **kw)
            res = run_control(model, targets, "bilevel", problem.start, problem.frozen,
                              options=opts, bilevel=p.bilevel_solver)
            eq = res.equilibrium
            info = res.stats.details
            run.converged, run.status = res.converged, res.status
            run.t_setup = res.stats.t_setup
            run.t_solve = res.stats.t_wall - run.t_setup
            run.iterations = res.stats.iterations
            run.equilibrium_solves = res.stats.equilibrium_solves
            pose = info.ipopt_pose
            run.saddle_flagged = bool(pose is not None and pose["admissible"]
                                      and not pose["positive_definite"])
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


def _reference(problem: _Problem, runs: list, cache: dict) -> None:
    """Model error and fine-mesh target error of each run (finest level)."""
    finest = min(problem.levels)
    fine, _ = problem.levels[finest]
    fmesh, fmodel, ftargets = fine.mesh, fine.model, fine.targets
    for run in runs:
        if run.contraction is None:
            continue
        key = tuple(np.round(run.contraction, 12))
        if run.mesh_factor == finest:
            run.model_error = 0.0
            run.fine_target_error = run.rms_target_error
            cache.setdefault(key, run.x)
            continue
        if key not in cache:
            x0 = transfer_pose(run.mesh, run.x, fmesh)
            eq = equilibrium_at(fmodel, run.contraction, x0)
            cache[key] = eq.x if eq.converged else None
        xf = cache[key]
        if xf is None:
            continue
        targets = problem.levels[run.mesh_factor][0].targets
        d = targets.y(run.x) - ftargets.y(xf)
        run.model_error = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))
        run.fine_target_error = float(ftargets.rms_error(xf))


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
        factors = settings.mesh_factors if scene.outline is not None else (settings.main_factor,)
        say(f"compare: [{k + 1}/{len(paths)}] {scene.name}: meshing {len(factors)} resolution(s)")
        levels = {f: _level(scene, f) for f in factors}
        problem = _Problem(path, scene, levels, scene.contraction.copy(), scene.frozen.copy())
        problems.append(problem)
        plan = [(m, "default", settings.main_factor, "main") for m in METHODS]
        plan += [(m, t, settings.main_factor, "tolerance") for m in METHODS
                 for t in settings.tolerances if t != "default"]
        plan += [(m, "default", f, "mesh") for m in METHODS for f in factors
                 if f != settings.main_factor]
        runs = []
        for j, (method, tol, factor, sweep) in enumerate(plan):
            run = _run(problem, method, tol, factor, sweep, settings)
            runs.append(run)
            say(f"compare: {scene.name} [{j + 1}/{len(plan)}] {method:8s} {sweep:9s} tol={tol:7s} "
                f"nodes={run.n_nodes:5d}  O={run.objective:.6g}  t={run.t_solve:.3f} s"
                f"{'' if run.converged else '  (not converged)'}")
        _reference(problem, runs, {})
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

CSV_FIELDS = ("problem", "method", "sweep", "tolerance", "mesh_factor", "max_area", "n_nodes",
              "n_elems", "converged", "stable", "saddle_flagged", "objective", "rms_target_error",
              "model_error", "fine_target_error", "t_solve_s", "t_setup_s", "iterations",
              "equilibrium_solves", "bound_violation", "pareto", "contractions", "status")


def _fmt(v, spec=".6g"):
    if v is None:
        return ""
    if isinstance(v, float) and not math.isfinite(v):
        return "nan"
    return format(v, spec)


def _contraction_text(problem, run) -> str:
    if run.contraction is None:
        return ""
    return " ".join(f"{n}={v:.4f}" for n, v in zip(problem.scene.winch_names, run.contraction))


def write_outputs(out: Path, problems, runs, settings, t_total) -> list[Path]:
    by_name = {p.scene.name: p for p in problems}
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(CSV_FIELDS)
    for r in runs:
        w.writerow([r.problem, r.method, r.sweep, r.tolerance, r.mesh_factor, _fmt(r.max_area),
                    r.n_nodes, r.n_elems, int(r.converged), int(r.stable), int(r.saddle_flagged),
                    repr(r.objective), repr(r.rms_target_error), repr(r.model_error),
                    repr(r.fine_target_error), f"{r.t_solve:.6f}", f"{r.t_setup:.6f}", r.iterations,
                    r.equilibrium_solves, repr(r.bound_violation), int(r.pareto),
                    _contraction_text(by_name[r.problem], r), r.status])
    files = [write_text_atomic(out / "results.csv", buf.getvalue())]

    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(("problem", "method", "kind", "t_wall_s", "objective", "dispatchable"))
    for r in runs:
        if r.sweep != "main":
            continue
        for t, o, d in r.curve:
            kind = "iterate" if r.method != "bilevel" else ("ipopt_iterate" if not d else "certified")
            w.writerow((r.problem, r.method, kind, f"{t:.6f}", repr(o), int(d)))
        for t, o in r.resolved:
            w.writerow((r.problem, r.method, "ipopt_iterate_resolved_post_hoc", f"{t:.6f}", repr(o), 1))
    files.append(write_text_atomic(out / "curves.csv", buf.getvalue()))

    files.append(plot_anytime(out / "anytime.png", problems, runs))
    files.append(plot_speed_error(out / "speed_error.png", problems, runs))
    files.append(write_text_atomic(out / "report.md", report_text(problems, runs, settings, t_total)))
    return files


# -- plots (matplotlib's object API: no pyplot, no global backend) ----------

COLORS = {"reparam": "#1f77b4", "clip": "#2ca02c", "bilevel": "#d62728"}
MARKERS = {"main": "o", "tolerance": "s", "mesh": "^"}


def _grid(n):
    from matplotlib.figure import Figure
    cols = min(n, 3)
    rows = int(math.ceil(n / cols))
    fig = Figure(figsize=(5.0 * cols, 3.8 * rows), dpi=110)
    axes = [fig.add_subplot(rows, cols, i + 1) for i in range(n)]
    return fig, axes


def plot_anytime(path: Path, problems, runs) -> Path:
    """Objective against wall time, one panel per problem."""
    fig, axes = _grid(len(problems))
    for ax, p in zip(axes, problems):
        name = p.scene.name
        for r in runs:
            if r.problem != name or r.sweep != "main" or not r.curve:
                continue
            c = COLORS[r.method]
            t = np.array([q[0] for q in r.curve])
            o = np.maximum(np.array([q[1] for q in r.curve]), 1e-12)
            d = np.array([q[2] for q in r.curve], dtype=bool)
            if r.method == "bilevel":
                ax.plot(t, o, "--", color=c, lw=1, label="bilevel: IPOPT iterates (not equilibria)")
                ax.plot(t[~d], o[~d], "x", color=c, ms=4)
                ax.plot(t[d], o[d], "D", color=c, ms=6, label="bilevel: certified start / result")
                if r.resolved:
                    tr = [q[0] for q in r.resolved]
                    orr = np.maximum([q[1] for q in r.resolved], 1e-12)
                    ax.plot(tr, orr, ":", color="#777777", lw=1,
                            label="bilevel: equilibria at IPOPT's c (post hoc)")
            else:
                ax.plot(t, o, "-", color=c, lw=1.2, marker="o" if r.method == "reparam" else "s",
                        ms=3.5, label=f"{r.method}: iterates (all dispatchable)")
        ax.set_yscale("log")
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel("objective O [length$^2$]")
        nodes = [r.n_nodes for r in runs if r.problem == name and r.sweep == "main"]
        ax.set_title(f"{name} ({nodes[0]} nodes)" if nodes else name, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path)
    return path


def plot_speed_error(path: Path, problems, runs) -> Path:
    """Solve time against fine-mesh target error, with the Pareto front."""
    fig, axes = _grid(len(problems))
    for ax, p in zip(axes, problems):
        mine = [r for r in runs if r.problem == p.scene.name
                and math.isfinite(r.t_solve) and math.isfinite(r.fine_target_error)]
        for r in mine:
            ax.plot(r.t_solve, r.fine_target_error, MARKERS[r.sweep], color=COLORS[r.method],
                    ms=6, mfc=COLORS[r.method] if r.stable and r.converged else "none",
                    label=f"{r.method}")
        front = sorted((r for r in mine if r.pareto), key=lambda r: r.t_solve)
        if front:
            ax.step([r.t_solve for r in front], [r.fine_target_error for r in front], where="post",
                    color="black", lw=1, label="Pareto front")
        ax.set_xscale("log")
        errs = [r.fine_target_error for r in mine if r.fine_target_error > 0]
        if errs and max(errs) > 20 * min(errs):
            ax.set_yscale("log")
        from matplotlib.ticker import NullFormatter
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("solve time [s]")
        ax.set_ylabel("RMS target error, finest mesh [length]")
        ax.set_title(p.scene.name, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], ls="", marker="o", color=c, label=m) for m, c in COLORS.items()]
    handles += [Line2D([], [], ls="", marker=mk, color="grey", label=f"{s} sweep") for s, mk in MARKERS.items()]
    handles += [Line2D([], [], ls="", marker="o", mfc="none", color="grey", label="not converged / unstable"),
                Line2D([], [], color="black", label="Pareto front")]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path)
    return path


# -- report ---------------------------------------------------------------

def _ratio_text(value: float, best: float) -> str:
    if best > 0 and value > 2 * best:
        return f"{value / best:.3g} times"
    return f"{100 * (value - best) / max(best, 1e-300):.3g} % above"


def _differences(problem, runs) -> list[str]:
    """Why the main runs' objectives differ by more than 1 %."""
    main = [r for r in runs if r.sweep == "main" and math.isfinite(r.objective)]
    if len(main) < 2:
        return []
    best = min(main, key=lambda r: r.objective)
    start = max((r.curve[0][1] for r in main if r.curve), default=0.0)
    floor = 1e-9 * start
    span = problem.scene.upper - problem.scene.lower
    names = problem.scene.winch_names
    notes = []
    for r in main:
        if r is best:
            continue
        if (r.objective - best.objective) <= 0.01 * max(best.objective, floor):
            continue
        dc = np.max(np.abs(r.contraction - best.contraction) / span)
        why = []
        if r.saddle_flagged:
            why.append("IPOPT's KKT point was a saddle of E (flagged); the returned pose is "
                       "Newton's stable equilibrium from it")
        if not r.converged:
            why.append(f"it stopped without converging ({r.status})")
        if "all tendons slack" in r.status:
            slack = r.status.split("winch ")[-1].split(":")[0]
            why.append(f"it stopped with every tendon of winch {slack} slack: a zero gradient, "
                       "so a flat stationary point rather than a minimum")
        on_bound = [names[w] for w in range(len(names))
                    if min(r.contraction[w] - problem.scene.lower[w],
                           problem.scene.upper[w] - r.contraction[w]) <= 1e-6 * span[w]
                    and abs(r.contraction[w] - best.contraction[w]) > 0.01 * span[w]]
        if on_bound:
            why.append(f"it stopped with {', '.join(on_bound)} on a bound where "
                       f"{best.method} is not: a local minimum on the bound (the first "
                       "millimetres of pull make O worse)")
        if dc > 0.01 and not why:
            why.append("it ended at other contractions: another local minimum")
        elif dc <= 0.01:
            why.append("the contractions agree within 1 % of the range: a stop short of the "
                       "same minimum")
        notes.append(f"- **{r.method}** ends {_ratio_text(r.objective, best.objective)} "
                     f"**{best.method}**'s objective (O = {r.objective:.6g} against "
                     f"{best.objective:.6g}; contractions {_contraction_text(problem, r)} against "
                     f"{_contraction_text(problem, best)}): " + "; ".join(why) + ".")
    return notes


def report_text(problems, runs, settings, t_total) -> str:
    L = ["# Control methods compared: speed against error", ""]
    L.append("Reproduce with `plush-opt compare PROBLEM.yaml [...] --out DIR"
             + (" --coarse`" if settings.mesh_factors == CompareSettings.coarse().mesh_factors else "`")
             + ".")
    L += ["", f"Settings: mesh factors {list(settings.mesh_factors)} x each problem's max_area "
          f"(main runs on {settings.main_factor:g} x), tolerance presets {list(settings.tolerances)}, "
          f"at most {settings.max_time} s per run. Total wall time {t_total:.1f} s.", "",
          "Methods: **reparam** = gradient loop with reparametrised bounds (method 1), **clip** = "
          "the same loop clipping c, **bilevel** = IPOPT on the KKT formulation, certified by Newton. "
          "Times are solve times in seconds from the starting equilibrium; *setup* is building "
          "IPOPT's solver (once per model, frozen set and options). *Eq. solves*: certified "
          "equilibrium solves (bilevel: the start and the certification; IPOPT's own function "
          "evaluations are not equilibrium solves). Objective O in length^2, errors in length units.",
          "", "![objective against wall time](anytime.png)", "",
          "![speed against error](speed_error.png)", ""]
    L += ["## Summary", "", "| problem | nodes | best O | fastest within 1 % of best O | "
          "lowest fine-mesh error on the Pareto front |", "|---|---|---|---|---|"]
    for p in problems:
        rs = [r for r in runs if r.problem == p.scene.name]
        main = [r for r in rs if r.sweep == "main" and r.stable and math.isfinite(r.objective)]
        if not main:
            L.append(f"| {p.scene.name} | | no stable result | | |")
            continue
        best = min(r.objective for r in main)
        ok = [r for r in main if r.objective <= best * 1.01 + 1e-12]
        fast = min(ok, key=lambda r: r.t_solve)
        front = [r for r in rs if r.pareto]
        low = min(front, key=lambda r: r.fine_target_error) if front else None
        L.append(f"| {p.scene.name} | {main[0].n_nodes} | {best:.6g} | {fast.method} "
                 f"({fast.t_solve:.3f} s) | "
                 + (f"{low.method} on {low.n_nodes} nodes ({low.sweep} sweep, {low.tolerance} "
                    f"tolerances): {low.fine_target_error:.4g} in {low.t_solve:.3f} s |"
                    if low else " |"))
    L.append("")
    for p in problems:
        name = p.scene.name
        rs = [r for r in runs if r.problem == name]
        main = [r for r in rs if r.sweep == "main"]
        L += [f"## {name}", "", f"File `{p.path.name}`; winches "
              + ", ".join(f"{n} [{lo:g}, {hi:g}]" for n, lo, hi in
                          zip(p.scene.winch_names, p.scene.lower, p.scene.upper))
              + f"; start contractions {p.start.tolist()}"
              + (f"; frozen {[n for n, f in zip(p.scene.winch_names, p.frozen) if f]}" if p.frozen.any() else "")
              + ".", ""]
        L += ["| method | converged | final O | RMS target error | time s | setup s | iterations "
              "| eq. solves | bound violation | stable | contractions | status |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in main:
            L.append(f"| {r.method} | {'yes' if r.converged else 'no'} | {_fmt(r.objective)} | "
                     f"{_fmt(r.rms_target_error, '.4g')} | {r.t_solve:.3f} | {r.t_setup:.2f} | "
                     f"{r.iterations} | {r.equilibrium_solves} | {_fmt(r.bound_violation, '.3g')} | "
                     f"{'yes' if r.stable else 'no'}{' (saddle flagged)' if r.saddle_flagged else ''} | "
                     f"{_contraction_text(p, r)} | {r.status} |")
        notes = _differences(p, rs)
        L += [""] + (["Objectives differing by more than 1 %:", ""] + notes if notes
                     else ["The final objectives agree within 1 %."]) + [""]
        tol_runs = [r for r in rs if r.sweep in ("main", "tolerance")]
        if len(tol_runs) > len(main):
            L += ["Tolerance sweep (main mesh):", "",
                  "| method | tolerance | converged | final O | time s | iterations |",
                  "|---|---|---|---|---|---|"]
            for r in sorted(tol_runs, key=lambda r: (METHODS.index(r.method), TOLERANCES.index(r.tolerance))):
                L.append(f"| {r.method} | {r.tolerance} | {'yes' if r.converged else 'no'} | "
                         f"{_fmt(r.objective)} | {r.t_solve:.3f} | {r.iterations} |")
            L.append("")
        mesh_runs = [r for r in rs if r.sweep in ("main", "mesh")]
        if len(mesh_runs) > len(main):
            L += ["Mesh sweep (default tolerances; model error = RMS distance of the target points "
                  "from the finest mesh's at the same contractions):", "",
                  "| method | max_area | nodes | final O (own mesh) | model error | fine-mesh target "
                  "error | time s | setup s |", "|---|---|---|---|---|---|---|---|"]
            for r in sorted(mesh_runs, key=lambda r: (METHODS.index(r.method), -r.mesh_factor)):
                L.append(f"| {r.method} | {_fmt(r.max_area, '.4g')} | {r.n_nodes} | {_fmt(r.objective)} | "
                         f"{_fmt(r.model_error, '.3g')} | {_fmt(r.fine_target_error, '.4g')} | "
                         f"{r.t_solve:.3f} | {r.t_setup:.2f} |")
            L.append("")
        front = sorted((r for r in rs if r.pareto), key=lambda r: r.t_solve)
        if front:
            L += ["Pareto front (solve time, fine-mesh target error): "
                  + "; ".join(f"{r.method} {r.sweep}/{r.tolerance}/{r.n_nodes} nodes "
                              f"({r.t_solve:.3f} s, {r.fine_target_error:.4g})" for r in front) + ".", ""]
        bad = [r for r in rs if r.contraction is not None and (r.bound_violation > 0 or not r.stable)]
        if bad:
            L += ["**Warning**: returned poses outside the bounds or not stable: "
                  + ", ".join(f"{r.method} ({r.sweep}/{r.tolerance})" for r in bad), ""]
    return "\n".join(L) + "\n"


# --------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------

def add_compare_parser(subparsers):
    """Add ``compare`` to the ``plush-opt`` subcommands."""
    p = subparsers.add_parser(
        "compare", help="compare the control methods (speed against error) on problem files",
        description="Run the gradient loop (reparametrised and clipped bounds) and the bilevel "
        "IPOPT method on each problem, sweep solver tolerances and mesh resolutions, and write "
        "report.md, results.csv, curves.csv and plots to --out.")
    p.add_argument("problem", type=Path, nargs="+", help="problem files with targets")
    p.add_argument("--out", "-o", type=Path, default=Path("out/compare"),
                   help="output folder (default out/compare)")
    p.add_argument("--coarse", action="store_true",
                   help="a quick run: coarser meshes, two tolerance presets")
    p.set_defaults(func=cmd_compare)
    return p


def cmd_compare(args) -> int:
    """``plush-opt compare``: progress on stderr, the files written on stdout.
    Exit status 0, or 3 if a method returned a pose outside the bounds or not
    stable (which would be a bug)."""
    import sys

    def progress(line):
        print(line, file=sys.stderr, flush=True)

    res = run_compare(args.problem, args.out, coarse=args.coarse, progress=progress)
    for f in res["files"]:
        print(f)
    bad = [r for r in res["runs"] if r.contraction is not None
           and (r.bound_violation > 0 or not r.stable)]
    if bad:
        print("plush-opt: compare: " + ", ".join(f"{r.problem}/{r.method}" for r in bad)
              + " returned poses outside the bounds or not stable", file=sys.stderr)
        return 3
    return 0
