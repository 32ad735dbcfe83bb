"""The gradient loop on friction scenes, with and without its handling of
the kink (docs/control.md, "Where O has a kink"): for each scene and bounds
method, the loop with ``trial_in_blend='mapped'`` and ``kink_steps=()``
(the loop before that handling) and with the defaults.

    OPENBLAS_NUM_THREADS=1 python tools/friction_control_table.py [--write-doc]

Prints a markdown table (exit code as the command line gives it: 0
converged, 3 not; O; accepted iterates; process CPU seconds of the run,
the model built beforehand); ``--write-doc`` puts its rows between
``<!-- kink-table -->`` and ``<!-- /kink-table -->`` in docs/control.md.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from plush_opt import load
from plush_opt.base.files import rewrite_block
from plush_opt.control.gradient_options import ControlOptions

ROOT = Path(__file__).resolve().parent.parent
SCENES = (ROOT / "problems" / "gripper_friction.yaml", ROOT / "tests" / "data" / "notched_finger.yaml",
          ROOT / "tests" / "data" / "notched_finger_mu01.yaml")
METHODS = ("reparam", "clip")
BEFORE = dict(trial_in_blend="mapped", kink_steps=())
DOC = ROOT / "docs" / "control.md"
HEADER = "| scene | method | before: exit, O, iterates, CPU s | now: exit, O, iterates, CPU s |"


def run(problem, method: str, **options) -> str:
    """'exit, O, iterates, CPU s' of one control run."""
    t = time.process_time()
    result = problem.control(method=method, options=ControlOptions(bounds=method, **options))
    cpu = time.process_time() - t
    return f"{0 if result.converged else 3}, {result.objective:.6g}, {result.stats.iterations}, {cpu:.2f}"


def rows(before: bool = True) -> list[str]:
    """The table's rows (``before`` False: the 'before' cells left empty)."""
    out = []
    for path in SCENES:
        problem = load(path)
        problem.equilibrium()                      # the model built before the runs are timed
        for method in METHODS:
            name = path.relative_to(ROOT).as_posix()
            then = run(problem, method, **BEFORE) if before else ""
            out.append(f"| {name} | {method} | {then} | {run(problem, method)} |")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write-doc", action="store_true", help="rewrite the table's rows in docs/control.md")
    args = ap.parse_args()
    when = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    lines = [HEADER, "|---|---|---|---|"] + rows() + ["", f"(Run on {when} UTC.)"]
    print("\n".join(lines))
    if args.write_doc:
        try:
            rewrite_block(DOC, "<!-- kink-table -->", "<!-- /kink-table -->", "\n".join(lines))
        except ValueError as exc:
            raise SystemExit(str(exc)) from None


if __name__ == "__main__":
    main()
