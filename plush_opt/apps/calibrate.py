"""``plush-opt calibrate``: fit the model to a sewn robot from measured poses.

    plush-opt calibrate MEAS.yaml --out FITTED.yaml [--fit youngs_modulus,assembly_offset]
        [--report REP.json] [--plot DIR] [--holdout 6,7] [--huber 3] [--max-area A]
        [--starts N [--jobs J | --dask ADDRESS]]

Prints a summary (fitted values with standard errors, RMS marker error per
pose before and after, chi^2) and writes the input problem file with only
the fitted keys changed. A set of parameters the measurements cannot tell
apart is refused, naming the combination (exit status 3).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..base.errors import SceneError
from .batch_flags import add_batch_flags, batch_kwargs, progress_for

EXIT_NOT_FITTED = 3               # the command line's "solver did not converge" status


def _indices(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected pose indices like 6,7, got {text!r}") from None


def add_calibrate_parser(sub):
    from ..fit import KINDS
    p = sub.add_parser("calibrate", help="fit the model to measured marker positions of a robot",
                       description="Fit scene parameters so that the equilibria at the measured "
                       "contractions put the markers where they were seen (docs/calibration.md).")
    p.add_argument("measurements", type=Path, help="measurement file (YAML, plush-opt-measurements/1)")
    p.add_argument("--out", "-o", type=Path, required=True,
                   help="write the fitted problem file here (the input with the fitted keys changed)")
    p.add_argument("--fit", default=None, metavar="P1,P2,...",
                   help=f"parameters to fit, from {', '.join(KINDS)} (offsets also as KIND:NAME); "
                   "default youngs_modulus,assembly_offset")
    p.add_argument("--report", type=Path, help="write the report (JSON) here")
    p.add_argument("--plot", type=Path, metavar="DIR",
                   help="write one PNG per pose (measured, predicted before and after) here")
    p.add_argument("--holdout", type=_indices, default=(), metavar="I,J",
                   help="poses (0-based) predicted but not fitted")
    p.add_argument("--huber", type=float, default=None, metavar="K",
                   help="robust Huber loss per marker, threshold K sigma (outlier markers count less)")
    p.add_argument("--max-area", type=float, default=None,
                   help="mesh with triangles up to this area instead of the problem file's")
    p.add_argument("--starts", type=int, default=1, metavar="N",
                   help="fit from N starting points (the scene's values first, moduli and stiffnesses "
                   "spread 1/3x-3x around them) in worker processes and keep the best")
    add_batch_flags(p)
    p.set_defaults(func=cmd_calibrate)


def cmd_calibrate(args) -> int:
    from ..fit import FitOptions
    from ..fit.job import calibrate, fitted_text
    from ..fit.report import report_dict, summary_text
    from ..io.measurement import load_measurements
    from ..base.files import write_json_atomic, write_text_atomic

    if args.max_area is not None and not args.max_area > 0:
        raise SceneError(f"--max-area: expected an area > 0, got {args.max_area:g}")
    from ..fit.starts import MAX_STARTS
    if not 1 <= args.starts <= MAX_STARTS:
        raise SceneError(f"--starts: expected 1..{MAX_STARTS}, got {args.starts}")
    meas = load_measurements(args.measurements)
    options = FitOptions(huber=args.huber, holdout=args.holdout)
    starts = None
    if args.starts == 1:
        result = calibrate(meas, args.fit, options, max_area=args.max_area)
    else:
        from ..batch.multistart import calibrate_from_starts, starts_table
        result, outcomes, best = calibrate_from_starts(
            meas, args.fit, options, args.starts, max_area=args.max_area,
            progress=progress_for(args, "calibrate: starts"), **batch_kwargs(args))
        starts = {"best": best, "starts": [{**vars(o), "cost": o.cost if o.cost == o.cost else None}
                                           for o in outcomes]}
        print("\n".join(starts_table(outcomes, best)))
    if result.identifiable:
        write_text_atomic(args.out, fitted_text(meas, result))
    doc = report_dict(meas, result, fitted_file=str(args.out) if result.identifiable else None,
                      huber=args.huber)
    if starts is not None:
        doc["starts"] = starts
    if args.report:
        write_json_atomic(args.report, doc)
    if args.plot:
        from .calibrate_plot import plot_poses
        plot_poses(args.plot, meas, result)
    print(summary_text(doc))
    if not result.identifiable:
        print(f"plush-opt: not fitted: {result.status}", file=sys.stderr)
        return EXIT_NOT_FITTED
    if not result.converged:
        print(f"plush-opt: not converged: {result.status}", file=sys.stderr)
        return EXIT_NOT_FITTED
    return 0
