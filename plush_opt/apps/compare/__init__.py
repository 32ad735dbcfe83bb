"""Side-by-side comparison of the control methods: speed against error.

For every problem file, three methods start from the same certified
equilibrium (the file's contractions):

* ``reparam`` - method 1, the sensitivity-driven gradient loop with
  reparametrised bounds (the paper's method);
* ``clip``    - the same loop with plain clipping of c to the bounds;
* ``bilevel`` - IPOPT with explicit bounds on the contractions, the pose
  eliminated through the certified equilibrium (reduced space).

Runs: each method at its default tolerances on the problem's mesh (the
main table and the anytime curves), a sweep over solver tolerances on that
mesh, and a sweep over mesh resolutions and element types (P1, P2) at the
default tolerances. Errors are measured against a P2 reference mesh graded
towards reentrant corners and attachment discs (plush_opt.fem.grading;
``CompareSettings.reference_factor``), whose own
convergence is checked against a coarser P2 level (``check_factor``) and
reported:

* ``rms_target_error`` - RMS distance of the targets on the run's own mesh;
* ``model_error``      - RMS distance between the run's target points and
  the reference's at the same contractions (the discretisation error);
* ``fine_target_error``- RMS target error of the reference's pose at the
  run's contractions: the best available prediction of what the robot
  would do. The speed-against-error Pareto front uses this one;
* ``reference_difference`` - RMS distance of the target points between the
  reference and its check level at the run's contractions;
* ``reference_crease`` - where the reference or its check level creases
  (folds through itself) at the run's contractions: the model has no
  converged answer there, and the three errors above are left out (nan).

Times are wall-clock seconds of the solve (from the starting equilibrium to
the returned pose); building IPOPT's problem is setup, reported separately
(milliseconds in the reduced space; the bilevel-against-loop table adds it
to the solve). The iterates of both the gradient loop and the reduced-space
bilevel method are certified equilibria within bounds (dispatchable to the
robot); the full-space formulation's are not, and the curves mark them
differently.

Writes ``report.md``, ``results.csv``, ``curves.csv``, ``anytime.png`` and
``speed_error.png`` to the output folder. :func:`add_compare_parser` adds
``plush-opt compare`` to the command line.
"""

from __future__ import annotations

from pathlib import Path

from ..batch_flags import add_batch_flags, batch_kwargs, progress_for
from .runner import pareto_front, run_compare
from .settings import METHODS, TOLERANCES, CompareSettings, Run

__all__ = ["CompareSettings", "METHODS", "Run", "TOLERANCES", "add_compare_parser", "cmd_compare",
           "pareto_front", "run_compare"]

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
    add_batch_flags(p)
    p.set_defaults(func=cmd_compare)
    return p


def cmd_compare(args) -> int:
    """``plush-opt compare``: progress on stderr, the files written on stdout.
    The problem files run side by side (``--jobs``, ``--dask``). Exit status
    0, or 3 if a problem's runs failed (the others are written) or a method
    returned a pose outside the bounds or not stable (which would be a bug)."""
    import sys

    def progress(line):
        if not getattr(args, "quiet", False):
            print(line, file=sys.stderr, flush=True)

    res = run_compare(args.problem, args.out, coarse=args.coarse, progress=progress,
                      batch_progress=progress_for(args, "compare"), **batch_kwargs(args))
    for f in res["files"]:
        print(f)
    if res["failed"]:
        print("plush-opt: compare: " + "; ".join(f"{p.name}: {e}" for p, e in res["failed"]),
              file=sys.stderr)
        return 3
    bad = [r for r in res["runs"] if r.contraction is not None
           and (r.bound_violation > 0 or not r.stable)]
    if bad:
        print("plush-opt: compare: " + ", ".join(f"{r.problem}/{r.method}" for r in bad)
              + " returned poses outside the bounds or not stable", file=sys.stderr)
        return 3
    return 0
