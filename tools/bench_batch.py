"""Wall time of batch-parallel jobs with --jobs 1 against --jobs N, runs
interleaved (1, N, 1, N, ...) so that a change in the machine's load hits
both alike, and whether their results are identical.

    python tools/bench_batch.py --repeat 2 --out batch_bench.md

Measures ``plush-opt compare --coarse`` on the shipped control problems and
``tools/accuracy_check.py`` on one shipped file, and writes the command
lines, every wall time, the medians and their ratio, the machine's load
average before each run, and whether the outputs (times aside) agree.
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

from plush_opt.base.files import write_text_atomic

ROOT = Path(__file__).resolve().parents[1]
COMPARE_FILES = ["problems/gripper.yaml", "problems/gripper_friction.yaml", "problems/hexapod_leg.yaml",
                 *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "problems" / "compare").glob("*.yaml"))]
ACCURACY_FILE = "problems/accuracy/beam_tendon.yaml"
#: columns of compare's results.csv that are times (or chosen by time): left out of the equality check
TIMED = ("t_solve_s", "t_setup_s", "pareto")


def compare_cmd(jobs: int, out: Path) -> list[str]:
    return [sys.executable, "-m", "plush_opt", "-q", "compare", *COMPARE_FILES, "--coarse",
            "--jobs", str(jobs), "--out", str(out)]


def accuracy_cmd(jobs: int, out: Path) -> list[str]:
    return [sys.executable, "tools/accuracy_check.py", ACCURACY_FILE, "--jobs", str(jobs),
            "--out", str(out)]


def compare_result(out: Path) -> list[dict]:
    with open(out / "results.csv", newline="") as fh:
        return [{k: v for k, v in row.items() if k not in TIMED} for row in csv.DictReader(fh)]


def accuracy_result(out: Path) -> list[str]:
    """The tables without the time columns and the total."""
    keep = []
    for line in out.read_text().splitlines():
        if line.startswith("(") and line.endswith("for this problem)"):
            continue
        cells = line.split("|")
        if len(cells) == 10 and cells[1].strip() not in ("TOL", "---"):   # the picks' table
            del cells[7]                                                 # one solve s
        keep.append("|".join(cells))
    return keep


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--only", choices=("compare", "accuracy"), default=None)
    ap.add_argument("--work", type=Path, default=Path("out/bench_batch"))
    ap.add_argument("--out", type=Path, default=Path("batch_bench.md"))
    args = ap.parse_args(argv)
    cases = [("compare", compare_cmd, compare_result, lambda d: d),
             ("accuracy", accuracy_cmd, accuracy_result, lambda d: d.with_suffix(".md"))]
    lines = [f"# Batch speed-up, --jobs 1 against --jobs {args.jobs}", "",
             f"Python {platform.python_version()}, {os.cpu_count()} cores, "
             f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; runs interleaved.", ""]
    for name, cmd, result, where in cases:
        if args.only not in (None, name):
            continue
        times = {1: [], args.jobs: []}
        results = {}
        for r in range(args.repeat):
            for jobs in (1, args.jobs):
                out = where(args.work / f"{name}_j{jobs}_r{r}")
                load = os.getloadavg()[0]
                t0 = time.perf_counter()
                subprocess.run(cmd(jobs, out), cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
                t = time.perf_counter() - t0
                times[jobs].append(t)
                results.setdefault(jobs, result(out))
                lines.append(f"- {name} --jobs {jobs} (repeat {r}): {t:.1f} s, load average before {load:.2f}")
                print(lines[-1], file=sys.stderr, flush=True)
        m1, mn = statistics.median(times[1]), statistics.median(times[args.jobs])
        lines += ["", f"**{name}**: `{' '.join(cmd('J', Path('OUT'))[1:])}`: median {m1:.1f} s with "
                  f"--jobs 1, {mn:.1f} s with --jobs {args.jobs}: **{m1 / mn:.2f}x**; results "
                  f"{'identical' if results[1] == results[args.jobs] else 'DIFFERENT'} (times aside).", ""]
        write_text_atomic(args.out, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
