"""The comparison's files: results.csv, curves.csv, report.md and the plots."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from ...base.files import atomic_path, write_text_atomic
from .settings import METHODS, TOLERANCES, CompareSettings

CSV_FIELDS = ("problem", "method", "sweep", "tolerance", "element", "mesh_factor", "max_area", "n_nodes",
              "n_elems", "converged", "stable", "saddle_flagged", "objective", "rms_target_error",
              "model_error", "fine_target_error", "reference_difference", "t_solve_s", "t_setup_s", "iterations",
              "equilibrium_solves", "bound_violation", "pareto", "contractions", "status", "reference_crease")


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
        w.writerow([r.problem, r.method, r.sweep, r.tolerance, r.element, r.mesh_factor, _fmt(r.max_area),
                    r.n_nodes, r.n_elems, int(r.converged), int(r.stable), int(r.saddle_flagged),
                    repr(r.objective), repr(r.rms_target_error), repr(r.model_error),
                    repr(r.fine_target_error), repr(r.reference_difference), f"{r.t_solve:.6f}", f"{r.t_setup:.6f}", r.iterations,
                    r.equilibrium_solves, repr(r.bound_violation), int(r.pareto),
                    _contraction_text(by_name[r.problem], r), r.status, r.reference_crease])
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
MESH_MARKERS = {"P1": "^", "P2": "v"}      # the mesh sweep, by element


def _marker(run) -> str:
    return MESH_MARKERS[run.element] if run.sweep == "mesh" else MARKERS[run.sweep]


#: mantissas of a log axis' ticks, fewest first: the first set that puts at
#: least LOG_TICKS_MIN labelled ticks in the view is used
LOG_SUBS = ((1.0,), (1.0, 2.0, 5.0), tuple(float(m) for m in range(1, 10)))
LOG_TICKS_MIN = 3


def _log_ticks(lo: float, hi: float, subs) -> list[float]:
    """The ticks m 10^e (m in ``subs``) within [lo, hi], increasing."""
    out = []
    for e in range(math.floor(math.log10(lo)) - 1, math.ceil(math.log10(hi)) + 1):
        out += [t for t in (float(f"{m:g}e{e}") for m in subs) if lo * (1 - 1e-9) <= t <= hi * (1 + 1e-9)]
    return sorted(out)


def readable_log_axis(ax, which: str) -> None:
    """Readable ticks on ``ax``'s log axis ``which`` ('x' or 'y'), its data
    plotted: matplotlib's decades where the view spans enough of them, else
    ticks at 1, 2, 5 or 1..9 times a power of ten, plain numbers, at least
    two of them (a view between two such ticks widens to them)."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter
    axis = ax.xaxis if which == "x" else ax.yaxis
    ax.autoscale_view()
    lo, hi = sorted(axis.get_view_interval())
    if not (lo > 0 and math.isfinite(hi)):
        return
    axis.set_minor_formatter(NullFormatter())
    if len(_log_ticks(lo, hi, LOG_SUBS[0])) >= LOG_TICKS_MIN:
        return                       # several decades: matplotlib labels them
    for subs in LOG_SUBS[1:]:
        ticks = _log_ticks(lo, hi, subs)
        if len(ticks) >= LOG_TICKS_MIN:
            break
    if len(ticks) < 2:               # narrower than two 1..9 ticks: widen to the ticks around it
        around = _log_ticks(lo / 10, hi * 10, LOG_SUBS[-1])
        lo, hi = max(t for t in around if t <= lo), min(t for t in around if t >= hi)
        (ax.set_xlim if which == "x" else ax.set_ylim)(lo, hi)
        ticks = _log_ticks(lo, hi, LOG_SUBS[-1])
    axis.set_major_locator(FixedLocator(ticks))
    shown = _spaced(ax, which, lo, hi, ticks)
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}" if v in shown else ""))


#: room (points) a log axis' tick label takes along its axis: per character
#: on the x axis, per line on the y axis, and a gap between two labels
LABEL_CHAR, LABEL_LINE, LABEL_GAP = 5.8, 10.0, 5.0


def _spaced(ax, which: str, lo: float, hi: float, ticks) -> set:
    """The ``ticks`` (of a log axis viewing [lo, hi]) to label: the powers
    of ten first, then 2 and 5 times them, then the others, each that does
    not run into a label placed before (1..9 times a power of ten crowd at
    the top of a decade: 0.08, 0.09 and 0.1 once printed as "0.080.090.1")."""
    box = ax.get_window_extent()
    length = (box.width if which == "x" else box.height) * 72.0 / ax.figure.dpi
    def rank(t: float) -> tuple[int, float]:           # 1 first, then 2 and 5, then the rest
        mantissa = round(t / 10 ** math.floor(math.log10(t) + 1e-9))
        return {1: 0, 2: 1, 5: 1}.get(mantissa, 2), t

    shown, placed = set(), []          # (the labels placed: their extents along the axis, points)
    for t in sorted(ticks, key=rank):
        at = math.log(t / lo) / math.log(hi / lo) * length
        half = 0.5 * (LABEL_CHAR * len(f"{t:g}") if which == "x" else LABEL_LINE) + 0.5 * LABEL_GAP
        if all(at + half <= a or at - half >= b for a, b in placed):
            shown.add(t)
            placed.append((at - half, at + half))
    return shown


def _grid(n):
    from matplotlib.figure import Figure
    cols = min(n, 3)
    rows = int(math.ceil(n / cols))
    fig = Figure(figsize=(5.0 * cols, 3.8 * rows), dpi=110)
    axes = [fig.add_subplot(rows, cols, i + 1) for i in range(n)]
    return fig, axes


def plot_anytime(path: Path, problems, runs) -> Path:
    """Objective against wall time, one panel per problem."""
    return _save(path, *anytime_figure(problems, runs))


def anytime_figure(problems, runs):
    """(figure, legend) of :func:`plot_anytime`."""
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
        readable_log_axis(ax, "y")
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel("objective O [mm$^2$]")
        nodes = [r.n_nodes for r in runs if r.problem == name and r.sweep == "main"]
        ax.set_title(f"{name} ({nodes[0]} nodes)" if nodes else name, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    legend = fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0), ncol=3, fontsize=8,
                        frameon=False)
    fig.tight_layout()
    return fig, legend


def _save(path: Path, fig, legend) -> Path:
    # The legend hangs below the axes; the tight box takes it in, however narrow the figure.
    with atomic_path(path) as tmp:      # a full disk leaves no partial picture
        fig.savefig(tmp, bbox_inches="tight", bbox_extra_artists=[legend])
    return path


def plot_speed_error(path: Path, problems, runs) -> Path:
    """Solve time against fine-mesh target error, with the Pareto front."""
    return _save(path, *speed_error_figure(problems, runs))


def speed_error_figure(problems, runs):
    """(figure, legend) of :func:`plot_speed_error`."""
    fig, axes = _grid(len(problems))
    for ax, p in zip(axes, problems):
        mine = [r for r in runs if r.problem == p.scene.name
                and math.isfinite(r.t_solve) and math.isfinite(r.fine_target_error)]
        for r in mine:
            ax.plot(r.t_solve, r.fine_target_error, _marker(r), color=COLORS[r.method],
                    ms=6, mfc=COLORS[r.method] if r.stable and r.converged else "none",
                    label=f"{r.method}")
        front = sorted((r for r in mine if r.pareto), key=lambda r: r.t_solve)
        if front:
            ax.step([r.t_solve for r in front], [r.fine_target_error for r in front], where="post",
                    color="black", lw=1, label="Pareto front")
        ax.set_xscale("log")
        readable_log_axis(ax, "x")
        errs = [r.fine_target_error for r in mine if r.fine_target_error > 0]
        if errs and max(errs) > 20 * min(errs):
            ax.set_yscale("log")
            readable_log_axis(ax, "y")
        ax.set_xlabel("solve time [s]")
        ax.set_ylabel(f"RMS target error, P2 reference [{p.scene.units.length}]")
        ax.set_title(p.scene.name, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], ls="", marker="o", color=c, label=m) for m, c in COLORS.items()]
    handles += [Line2D([], [], ls="", marker=mk, color="grey", label=f"{s} sweep") for s, mk in MARKERS.items()
                if s != "mesh"]
    handles += [Line2D([], [], ls="", marker=mk, color="grey", label=f"mesh sweep, {e}")
                for e, mk in MESH_MARKERS.items()]
    handles += [Line2D([], [], ls="", marker="o", mfc="none", color="grey", label="not converged / unstable"),
                Line2D([], [], color="black", label="Pareto front")]
    legend = fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0), ncol=4, fontsize=8,
                        frameon=False)
    fig.tight_layout()
    return fig, legend


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


def timing_note(repeat: int) -> str:
    """What the report's times are: medians of ``repeat`` runs, or one sample."""
    if repeat == 1:
        return ("Times are one sample per run (a quick run): wall times this short vary by a factor of "
                "2 or more on a shared machine, so \"fastest\" compares single noisy samples, not speeds.")
    return f"Times are the median of {repeat} runs of each case (wall seconds)."


def report_text(problems, runs, settings, t_total) -> str:
    L = ["# Control methods compared: speed against error", ""]
    L.append("Reproduce with `plush-opt compare PROBLEM.yaml [...] --out DIR"
             + (" --coarse`" if settings.mesh_factors == CompareSettings.coarse().mesh_factors else "`")
             + ".")
    L += ["", f"Settings: mesh factors {list(settings.mesh_factors)} x each problem's max_area "
          f"(main runs on {settings.main_factor:g} x), tolerance presets {list(settings.tolerances)}, "
          f"at most {settings.max_time} s per run. Total wall time {t_total:.1f} s.", "",
          "Methods: **reparam** = gradient loop with reparametrised bounds (method 1), **clip** = "
          "the same loop clipping c, **bilevel** = IPOPT on the contractions with the pose eliminated "
          "through the certified equilibrium (docs/bilevel.md). "
          "Times are wall seconds of the whole control call (the starting equilibrium, the "
          "iterations, the look-further moves and the final certification); *setup* is building "
          "IPOPT's problem (milliseconds in the reduced space). *Eq. solves*: certified "
          "equilibrium solves. Objective O in length^2, errors in length units.",
          "", "![objective against wall time](anytime.png)", "",
          "![speed against error](speed_error.png)", ""]
    L += ["## Summary", "", timing_note(settings.repeat), "",
          "| problem | nodes | best O | fastest within 1 % of best O | "
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
    L += [""] + _bilevel_table(problems, runs)
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
                  "from the P2 reference's at the same contractions):", "",
                  "| method | element | max_area | nodes | final O (own mesh) | model error | reference "
                  "target error | time s | setup s |", "|---|---|---|---|---|---|---|---|---|"]
            for r in sorted(mesh_runs, key=lambda r: (METHODS.index(r.method), r.element, -r.mesh_factor)):
                errors = ("creases | -" if r.reference_crease else
                          f"{_fmt(r.model_error, '.3g')} | {_fmt(r.fine_target_error, '.4g')}")
                L.append(f"| {r.method} | {r.element} | {_fmt(r.max_area, '.4g')} | {r.n_nodes} | {_fmt(r.objective)} | "
                         f"{errors} | {r.t_solve:.3f} | {r.t_setup:.2f} |")
            L.append("")
        front = sorted((r for r in rs if r.pareto), key=lambda r: r.t_solve)
        if front:
            L += ["Pareto front (solve time, reference target error): "
                  + "; ".join(f"{r.method} {r.sweep}/{r.tolerance}/{r.element} {r.n_nodes} nodes "
                              f"({r.t_solve:.3f} s, {r.fine_target_error:.4g})" for r in front) + ".", ""]
        L += accuracy_section(p, rs)
        bad = [r for r in rs if r.contraction is not None and (r.bound_violation > 0 or not r.stable)]
        if bad:
            L += ["**Warning**: returned poses outside the bounds or not stable: "
                  + ", ".join(f"{r.method} ({r.sweep}/{r.tolerance})" for r in bad), ""]
    return "\n".join(L) + "\n"


def _bilevel_table(problems, runs) -> list[str]:
    """Bilevel against the gradient loop (reparam) per problem and mesh:
    objective ratio and total-time ratio (set-up included)."""
    L = ["## Bilevel against the gradient loop", "",
         "Default tolerances; time = solve + set-up, seconds; ratios bilevel / reparam.", "",
         "| problem | nodes | reparam O | reparam s | bilevel O | bilevel s | O ratio | time ratio "
         "| bilevel status |", "|---|---|---|---|---|---|---|---|---|"]
    for p in problems:
        rs = [r for r in runs if r.problem == p.scene.name and r.sweep in ("main", "mesh")]
        for e, f in sorted({(r.element, r.mesh_factor) for r in rs}, key=lambda k: (k[0], -k[1])):
            loop = next((r for r in rs if r.method == "reparam" and (r.element, r.mesh_factor) == (e, f)), None)
            bil = next((r for r in rs if r.method == "bilevel" and (r.element, r.mesh_factor) == (e, f)), None)
            if loop is None or bil is None:
                continue
            t_loop, t_bil = loop.t_solve + loop.t_setup, bil.t_solve + bil.t_setup
            ratio_o = bil.objective / loop.objective if loop.objective > 0 else math.nan
            L.append(f"| {p.scene.name} | {bil.n_nodes} | {_fmt(loop.objective)} | {t_loop:.3f} | "
                     f"{_fmt(bil.objective)} | {t_bil:.3f} | {_fmt(ratio_o, '.4f')} | "
                     f"{t_bil / t_loop:.2f} | {bil.reason} |")
    return L + [""]


#: The reference's check difference must be this fraction of the smallest
#: error measured, or the report says the reference is not converged.
REFERENCE_MARGIN = 0.1
#: The model errors (length units) the "time to reach" table asks for.
ERROR_LEVELS = (1.0, 0.25, 0.05)


def _creases(runs) -> list[str]:
    """The report's paragraph on runs whose reference creases, if any."""
    creased = [r for r in runs if r.reference_crease]
    if not creased:
        return []
    at = sorted({r.reference_crease for r in creased})
    return [f"**No errors for {len(creased)} of {len(runs)} runs**: at their contractions the reference "
            f"folds through itself ({at[0]}" + (f"; and {len(at) - 1} more" if len(at) > 1 else "") +
            "). The model has no converged answer there (refinement folds the body further), so there is "
            "nothing to measure their errors against; `contact: {self: true}` forbids the fold "
            "(docs/accuracy.md).", ""]


def accuracy_section(problem, runs) -> list[str]:
    """The P2 reference, its own check, and the time each method and element
    needs to reach a given model error."""
    ref, chk = problem.reference, problem.check
    if ref is None:
        return []
    measured = [r.model_error for r in runs if math.isfinite(r.model_error)]
    checks = [r.reference_difference for r in runs if math.isfinite(r.reference_difference)]
    L = [f"Accuracy: errors are measured against a P2 reference of {ref.mesh.n_nodes} nodes (graded "
         f"towards reentrant corners, pinned ends and attachment discs) at each run's contractions. "
         f"Its distance to a coarser P2 level ({chk.mesh.n_nodes} nodes), RMS over the target points: "
         f"at most {_fmt(max(checks, default=math.nan), '.3g')}. That difference measures the "
         f"coarser level's error, not a bound of the reference's: two levels give no convergence rate, "
         f"and before the asymptotic regime the reference's own error can exceed it (`plush-opt solve "
         f"--accuracy` estimates errors with the rate, docs/accuracy.md). The smallest model "
         f"error measured is {_fmt(min(measured, default=math.nan), '.3g')}"
         + ("." if checks and measured and max(checks) <= REFERENCE_MARGIN * min(measured) else
            f": **the reference is not converged to {1 / REFERENCE_MARGIN:g} x below the errors "
            "measured** (the check level is the sweep's finest P2 mesh, so the smallest error "
            "measured is at most the check itself; docs/accuracy.md); errors below its check "
            "difference are not resolved."), ""] + _creases(runs) + [
         "Least solve time (s) of a stable run whose model error is at most the column's "
         "(default tolerances, any mesh; '-' = no run that accurate):", "",
         "| method | element | " + " | ".join(f"<= {e:g}" for e in ERROR_LEVELS) + " |",
         "|---|---|" + "---|" * len(ERROR_LEVELS)]
    for method in METHODS:
        for element in sorted({r.element for r in runs}):
            mine = [r for r in runs if r.method == method and r.element == element and r.stable
                    and r.tolerance == "default" and math.isfinite(r.model_error)]
            cells = []
            for e in ERROR_LEVELS:
                ok = [r for r in mine if r.model_error <= e]
                cells.append("-" if not ok else (lambda r: f"{r.t_solve:.3f} ({r.n_nodes} nodes)")(
                    min(ok, key=lambda r: r.t_solve)))
            L.append(f"| {method} | {element} | " + " | ".join(cells) + " |")
    return L + [""]
