"""Newton from rest on problem files: how many iterations each forward
solve takes, and after how many a no-progress window would hand it over
to continuation (plush_opt.solve.equilibrium.HANDOVER_WINDOW).

    python tools/newton_from_rest.py                     # every problem file and the thin strip
    python tools/newton_from_rest.py problems/gripper.yaml --windows 20 30 40

Each file is solved at a quarter, half and all of each winch's range (an
unbounded winch: 20 mm), from rest, without continuation. A window w fires
once more than 2 w relative residuals are in and the best of the last w is
not below half the best before (``solve_newton``'s ``handover``, the
solver's own test); "-" where it never fires. A window that fires on a solve
that converges costs that solve time (continuation first, then Newton
resumes), never its equilibrium.
"""

from __future__ import annotations

import argparse
import logging
import re
import sys
import time
from pathlib import Path

import numpy as np

from plush_opt import load
from plush_opt.base.errors import PlushError
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
from plush_opt.solve.newton import _no_progress as no_progress

ROOT = Path(__file__).resolve().parent.parent
RESIDUAL = re.compile(r"^newton \d+: residual ([0-9.e+-]+)")


def fires(residuals: list[float], window: int) -> int | None:
    """The iteration count at which ``window`` would hand over (the
    solver's own rule on the residuals before each step), or None."""
    options = EquilibriumOptions()
    for k in range(1, len(residuals) + 1):
        if no_progress(residuals[:k], window, options):
            return k - 1
    return None


class _Residuals(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.values: list[float] = []

    def emit(self, record):
        m = RESIDUAL.match(record.getMessage())
        if m:
            self.values.append(float(m.group(1)))


def default_files() -> list[Path]:
    files = sorted((ROOT / "problems").glob("*.yaml")) + sorted((ROOT / "problems").glob("*/*.yaml"))
    return [f for f in files if f.parent.name not in ("invalid", "calib")] + [ROOT / "tests/data/thin_strip.yaml"]


def rows(path: Path, windows: list[int]):
    try:
        model = load(path).model
    except PlushError as e:
        yield f"| {path.relative_to(ROOT)} | - | - | - | - | - | {type(e).__name__} |"
        return
    lower, upper = np.array(model.lower), np.array(model.upper)
    upper = np.where(np.isfinite(upper), upper, lower + 20.0)
    log = logging.getLogger("plush_opt.solve.equilibrium")
    for share in (0.25, 0.5, 1.0):
        handler = _Residuals()
        log.addHandler(handler)
        old = log.level
        log.setLevel(logging.DEBUG)
        t = time.process_time()
        try:
            eq = solve_equilibrium(model, lower + share * (upper - lower), options=EquilibriumOptions(eigenvalue=False))
        finally:
            log.removeHandler(handler)
            log.setLevel(old)
        cpu = time.process_time() - t
        fired = " | ".join(str(fires(handler.values, w) or "-") for w in windows)
        yield (f"| {path.relative_to(ROOT)} | {share:g} | {model.n_dofs // 2:,} | {eq.iterations} | "
               f"{'yes' if eq.converged else 'no'} | {cpu:.2f} | {fired} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--windows", nargs="+", type=int, default=[20, 30, 40])
    args = ap.parse_args(argv)
    files = [f.resolve() for f in args.files] or default_files()
    print("| file | share of range | nodes | Newton its | converged | CPU s | "
          + " | ".join(f"window {w} fires at" for w in args.windows) + " |")
    print("|---|---|---|---|---|---|" + "---|" * len(args.windows))
    for f in files:
        for line in rows(f, args.windows):
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
