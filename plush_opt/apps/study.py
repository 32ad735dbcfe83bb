"""``plush-opt study``: solve one problem file at every combination of
varied parameters and write the trade-offs (docs/study.md).

    plush-opt study problems/gripper.yaml --vary material.youngs_modulus=0.01:0.08:8 \\
        --vary tendons.friction=0,0.15,0.3 --out out/study [--jobs N | --dask ADDRESS]

Writes ``study.csv`` (one row per variant), ``report.md`` and ``study.png``
(the trade-off curves) to ``--out``. Exit status 0 when every variant's
poses are certified, 3 when one failed or is not certified (the rows say
which), 130 when interrupted (what finished is written first).
"""

from __future__ import annotations

import csv
import io
import math
import sys
from pathlib import Path

from ..base.files import write_text_atomic
from .batch_flags import add_batch_flags, batch_kwargs, progress_for

EXIT_NOT_CERTIFIED = 3


def add_study_parser(sub):
    p = sub.add_parser("study", help="solve a problem at every combination of varied parameters",
                       description="For each combination of the --vary values, solve the file's "
                       "control problem and measure the target error, the largest tension and "
                       "contraction, the friction hysteresis of one winch and the pose left after "
                       "release; write study.csv, report.md and study.png to --out.")
    p.add_argument("problem", type=Path, help="problem file with targets")
    p.add_argument("--vary", action="append", required=True, metavar="KEY=A:B:N",
                   help="a key of the problem file and its values: N values from A to B, or a list "
                   "V1,V2,... (e.g. material.youngs_modulus=0.01:0.08:8); repeatable, every "
                   "combination is solved")
    p.add_argument("--out", "-o", type=Path, required=True, help="output folder")
    p.add_argument("--method", default="reparam", choices=("reparam", "clip", "bilevel"),
                   help="control method (default reparam)")
    p.add_argument("--max-area", type=float, default=None,
                   help="mesh every variant with triangles up to this area instead of the file's")
    p.add_argument("--sweep-winch", default=None, metavar="W",
                   help="the winch of the hysteresis sweep (default: the one the solution pulls most)")
    p.add_argument("--sweep-steps", type=int, default=None, metavar="N",
                   help="equilibria per leg of the hysteresis sweep")
    add_batch_flags(p)
    p.set_defaults(func=cmd_study)
    return p


def cmd_study(args) -> int:
    from ..batch.study import SWEEP_STEPS, StudyOptions, parse_vary, run_study
    varies = [parse_vary(text) for text in args.vary]
    options = StudyOptions(args.method, args.max_area,
                           SWEEP_STEPS if args.sweep_steps is None else args.sweep_steps,
                           args.sweep_winch)
    result = run_study(args.problem, varies, options, progress=progress_for(args, "study"),
                       **batch_kwargs(args))
    files = write_study(args.out, args.problem, result, options, sys.argv[1:])
    for f in files:
        print(f)
    result.batch.raise_if_interrupted()
    bad = [r for r in result.rows if not r["certified"]]
    if bad:
        print(f"plush-opt: study: {len(bad)} of {len(result.rows)} variants failed or are not "
              "certified (see status in study.csv)", file=sys.stderr)
        return EXIT_NOT_CERTIFIED
    return 0


def write_study(out: Path, problem: Path, result, options, argv) -> list[Path]:
    """study.csv, report.md and study.png in ``out``; the paths written."""
    from ..batch.study import COLUMNS
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    columns = list(result.keys) + list(COLUMNS)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for row in result.rows:
        writer.writerow([_cell(row.get(c)) for c in columns])
    files = [write_text_atomic(out / "study.csv", buf.getvalue())]
    files.append(write_text_atomic(out / "report.md", report_text(problem, result, options, argv)))
    if any(r["certified"] for r in result.rows):
        from .study_plot import plot_study
        files.append(plot_study(out / "study.png", problem, result))
    return files


def _cell(v):
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.10g}"
    return v


def report_text(problem: Path, result, options, argv) -> str:
    """The study as markdown: what ran, the table, what failed."""
    rows, keys, batch = result.rows, result.keys, result.batch
    n_ok = sum(r["certified"] for r in rows)
    lines = [f"# Study of {Path(problem).name}", "",
             f"`plush-opt {' '.join(argv)}`" if argv else "", "",
             f"{len(rows)} variants ({' x '.join(str(len({r[k] for r in rows})) for k in keys)} of "
             f"{', '.join(keys)}), control method {options.method}, "
             f"{batch.backend} backend with {batch.jobs} worker(s), {batch.t_wall:.1f} s. "
             f"{n_ok} of {len(rows)} variants have every pose certified.", ""]
    if batch.interrupted:
        lines += [f"**Interrupted**: {len(batch.finished)} of {len(rows)} variants finished; "
                  "the others are marked interrupted.", ""]
    head = [k.rsplit(".", 1)[-1] for k in keys] + [
        "target error", "max tension", "max contraction", "hysteresis work", "release error",
        "control", "certified"]
    lines += ["Units: the problem file's (lengths, forces; the hysteresis work is force x length).",
              "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [f"{r[k]:g}" for k in keys] + [_fmt(r[c]) for c in (
            "target_error", "max_tension", "max_contraction", "hysteresis_work", "release_error")]
        cells += [r["control_reason"] or "-", "yes" if r["certified"] else r["status"]]
        lines.append("| " + " | ".join(cells) + " |")
    failed = [r for r in rows if not r["certified"]]
    if failed:
        lines += ["", "Not certified or failed:", ""]
        lines += [f"- {', '.join(f'{k}={r[k]:g}' for k in keys)}: {r['status']}" for r in failed]
    return "\n".join(lines) + "\n"


def _fmt(v) -> str:
    return "n/a" if not isinstance(v, float) or math.isnan(v) else f"{v:.4g}"

