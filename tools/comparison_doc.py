"""docs/comparison.md's figures from a compare run: its main table, its
least-time table, the reference checks and the facts the "Which to use"
section rests on, written from the run's ``results.csv``.

    python tools/comparison_doc.py DIR [--write-doc]

DIR is the ``--out`` folder of the compare run (docs/comparison.md,
"Running the comparison"). Prints the blocks; ``--write-doc`` puts each
between its ``<!-- compare-NAME -->`` and ``<!-- /compare-NAME -->``
markers in docs/comparison.md and copies the run's two plots to
docs/img/. The run's date is that of its ``results.csv``, its wall time
the one its ``report.md`` gives.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import math
import re
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "comparison.md"
METHODS = ("reparam", "clip", "bilevel")
LEVELS = (1.0, 0.25, 0.05)
#: final objectives within this relative difference are "the same objective"
SAME_O = 0.01


def read_rows(folder: Path) -> list[dict]:
    """The rows of ``folder/results.csv``, numbers as floats (nan where empty)."""
    rows = []
    with open(folder / "results.csv", newline="") as f:
        for row in csv.DictReader(f):
            for key in ("objective", "model_error", "fine_target_error", "reference_difference",
                        "t_solve_s", "n_nodes", "iterations", "equilibrium_solves", "stable"):
                row[key] = float(row[key]) if row[key] not in ("", "nan") else math.nan
            row["reference_crease"] = row.get("reference_crease") or ""   # (not in older runs' files)
            rows.append(row)
    return rows


def problems(rows: list[dict]) -> list[str]:
    return list(dict.fromkeys(r["problem"] for r in rows))


def _main(rows, problem, method):
    return next(r for r in rows if r["problem"] == problem and r["method"] == method and r["sweep"] == "main")


def _refused(row) -> bool:
    return row["status"].startswith("error:")


def main_table(rows: list[dict]) -> str:
    """Each method on each file's own mesh."""
    out = ["| problem | nodes | method | final O | ref. target error mm | model error mm | time s | iterations "
           "| eq. solves |", "|---|---|---|---|---|---|---|---|---|"]
    for p in problems(rows):
        for k, m in enumerate(METHODS):
            r = _main(rows, p, m)
            head = f"| {p} | {int(r['n_nodes'])} |" if k == 0 else "|  |  |"
            if _refused(r):
                out.append(f"{head} {m} | refused | - | - | - | - | - |")
                continue
            errors = ("- | creases" if r["reference_crease"] else
                      f"{r['fine_target_error']:.4g} | {r['model_error']:.3g}")
            out.append(f"{head} {m} | {r['objective']:.6g} | {errors} "
                       f"| {r['t_solve_s']:.3f} | {int(r['iterations'])} | {int(r['equilibrium_solves'])} |")
    return "\n".join(out)


def _default_runs(rows, problem, method, element=None):
    """The stable runs at default tolerances (the main run and the mesh sweep)."""
    return [r for r in rows if r["problem"] == problem and r["method"] == method and r["tolerance"] == "default"
            and r["stable"] == 1 and not _refused(r) and (element is None or r["element"] == element)]


def _least(runs, level: float) -> str:
    times = [r["t_solve_s"] for r in runs if r["model_error"] <= level]
    return f"{min(times):.2g} s" if times else "-"


def least_time_table(rows: list[dict]) -> str:
    """Least time of a stable run whose model error is at most 1, 0.25, 0.05 mm, P1 / P2."""
    out = ["| problem | method | <= 1 mm: P1 / P2 | <= 0.25 mm: P1 / P2 | <= 0.05 mm: P1 / P2 |",
           "|---|---|---|---|---|"]
    for p in problems(rows):
        for m in ("reparam", "bilevel"):
            cells = [" / ".join(_least(_default_runs(rows, p, m, e), lv) for e in ("P1", "P2")) for lv in LEVELS]
            out.append(f"| {p} | {m} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def checks(rows: list[dict]) -> str:
    """Each file's reference check: the largest distance of its reference
    to the coarser P2 level over the runs (what the report's accuracy
    paragraph says "at most")."""
    parts = []
    for p in problems(rows):
        mine = [r for r in rows if r["problem"] == p]
        d = [r["reference_difference"] for r in mine if not math.isnan(r["reference_difference"])]
        creased = sum(1 for r in mine if r["reference_crease"])
        check = f"{max(d):.2g}" if d else "-"
        parts.append(f"{p} {check}" + (f" (the reference creases at {creased} of {len(mine)} runs' contractions: "
                                        "no errors there)" if creased else ""))
    return "Reference checks of this run (mm): " + ", ".join(parts) + "."


def _o_differs(a: float, b: float) -> bool:
    return abs(a - b) > SAME_O * max(abs(a), abs(b)) and max(abs(a), abs(b)) > 1e-9


def facts(rows: list[dict]) -> str:
    """Where the methods' final objectives differ by more than 1 % (any
    default-tolerance run, same mesh), and which was faster on the files'
    meshes."""
    lines = []
    for other in ("clip", "bilevel"):
        differs = []
        for r in (r for r in rows if r["method"] == "reparam" and r["tolerance"] == "default"):
            o = next((s for s in rows if s["method"] == other and s["problem"] == r["problem"]
                      and s["tolerance"] == "default" and s["element"] == r["element"]
                      and s["n_nodes"] == r["n_nodes"]), None)
            if o is None or _refused(o) or _refused(r) or not _o_differs(r["objective"], o["objective"]):
                continue
            creased = ", a reference that creases" if r["reference_crease"] or o["reference_crease"] else ""
            differs.append(f"{r['problem']} ({r['element']} {int(r['n_nodes']):,} nodes: "
                           f"{o['objective']:.6g} against {r['objective']:.6g}{creased})")
        where = "; ".join(dict.fromkeys(differs)) if differs else "none"
        lines.append(f"- `{other}`'s final O differs from `reparam`'s by more than 1 % on: {where}.")
    faster = [p for p in problems(rows) if not _refused(_main(rows, p, "bilevel"))
              and _main(rows, p, "bilevel")["t_solve_s"] < _main(rows, p, "reparam")["t_solve_s"]]
    lines.append("- On the files' meshes `bilevel` took less time than `reparam` on: "
                 + (", ".join(f"`{p}`" for p in faster) or "none") + " (single samples).")
    return "\n".join(lines)


def made_by(folder: Path, rows: list[dict]) -> str:
    """Which run the figures are from: its files, date and wall time."""
    stamp = (folder / "results.csv").stat().st_mtime
    date = datetime.datetime.fromtimestamp(stamp, datetime.timezone.utc).strftime("%Y-%m-%d")
    found = re.search(r"Total wall time ([0-9.]+) s", (folder / "report.md").read_text())
    if found is None:
        raise SystemExit(f"{folder / 'report.md'}: no 'Total wall time' line (not a compare report?)")
    wall_minutes = float(found.group(1)) / 60.0
    return (f"Made by the Python call above ({len(problems(rows))} files, one repeat, default settings) on {date}, "
            f"{wall_minutes:.0f} minutes wall on a shared two-core machine with one BLAS thread; "
            "`python tools/comparison_doc.py DIR --write-doc` wrote the figures of this page from its "
            "`results.csv`. Times are single samples.")


BLOCKS = {"made": None, "main": main_table, "least": least_time_table, "checks": checks, "facts": facts}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--write-doc", action="store_true")
    args = ap.parse_args(argv)
    rows = read_rows(args.folder)
    blocks = {name: (made_by(args.folder, rows) if fn is None else fn(rows)) for name, fn in BLOCKS.items()}
    for name, text in blocks.items():
        print(f"<!-- compare-{name} -->\n{text}\n")
    if args.write_doc:
        from plush_opt.base.files import rewrite_block
        for name, text in blocks.items():
            rewrite_block(DOC, f"<!-- compare-{name} -->", f"<!-- /compare-{name} -->", text)
        for png in ("anytime", "speed_error"):
            shutil.copyfile(args.folder / f"{png}.png", ROOT / "docs" / "img" / f"compare_{png}.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
