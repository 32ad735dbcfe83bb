"""plush-opt sweep: follow one winch's contraction forward (and back) from
the scene's start state, each step from the previous one, and write what
the robot went through: contractions, the scene's ``points`` (or, where it
has none, its targets' points) and the end tensions of every tendon (CSV),
optionally the hysteresis loop (PNG).

Works with and without friction: a frictionless tendon is one spring, so
its two end tensions are equal and loading and unloading coincide."""

from __future__ import annotations

import csv
import sys
import time
from pathlib import Path

import numpy as np

from ..base.errors import SceneError
from ..problem import load
from ..solve.plant import make_plant
from ..base.files import atomic_path
from .console import is_quiet, say
from .run_log import ProgressLine
from .sweep_plot import followed_positions

# steps of one leg: each is an equilibrium solve, so a million would run for
# hours (and its states fill memory); a hysteresis loop needs hundreds
MAX_STEPS = 10_000


def add_sweep_parser(sub, contraction_arg):
    p = sub.add_parser("sweep", help="follow a winch's contraction in steps (friction: with history)",
                       description="From the scene's start state (zero contraction; other winches "
                       "at 0 or their -c value), move winch W to C1 in N steps, then back to C2 "
                       "(--back) in N more, each step from the previous state. Progress goes to stderr: a line "
                       "per step (an updating line on a terminal); -q prints nothing but errors.")
    p.add_argument("problem", type=Path)
    p.add_argument("--winch", required=True, metavar="W")
    p.add_argument("--to", type=float, required=True, metavar="C1")
    p.add_argument("--back", type=float, default=None, metavar="C2")
    p.add_argument("--steps", type=int, default=20, metavar="N")
    p.add_argument("--contraction", "-c", action="append", type=contraction_arg, default=[],
                   metavar="NAME=VALUE", help="a fixed contraction of another winch; repeatable")
    p.add_argument("--out", type=Path, required=True, metavar="S.csv")
    p.add_argument("--plot", type=Path, default=None, metavar="S.png")
    p.add_argument("--max-area", type=float, default=None)
    p.set_defaults(func=cmd_sweep)


def check_steps(steps: int) -> None:
    """Refuse a step count outside 1..:data:`MAX_STEPS` (SceneError)."""
    if not 1 <= steps <= MAX_STEPS:
        raise SceneError(f"--steps: expected 1..{MAX_STEPS}, got {steps}")


def sweep_path(problem, winch: str, to: float, back: float | None, steps: int,
               fixed: dict[str, float]) -> np.ndarray:
    """(n_steps, n_winches) contractions of the sweep."""
    check_steps(steps)
    if winch not in problem.winch_names:
        raise SceneError(f"--winch {winch}: no winch named {winch!r} "
                         f"(winches: {', '.join(problem.winch_names)})")
    zero = np.zeros(problem.model.n_winches)
    base = problem.contraction_vector(fixed, start=zero, what="--contraction")
    w = problem.winch_names.index(winch)
    problem.contraction_vector({winch: to}, start=zero, what="--to")
    legs = [np.linspace(base[w], to, steps + 1)[1:]]
    if back is not None:
        problem.contraction_vector({winch: back}, start=zero, what="--back")
        legs.append(np.linspace(to, back, steps + 1)[1:])
    values = np.concatenate(legs)
    path = np.tile(base, (len(values), 1))
    path[:, w] = values
    return path


def run_sweep(problem, path: np.ndarray, on_step=None):
    """The segmented plant of the problem (every tendon with via points in
    segments, :func:`~plush_opt.solve.plant.make_plant`) and its states
    from the start state along ``path`` (the start state first);
    ``on_step(k, state)`` after step k (from 1), if given."""
    plant = make_plant(problem.model, segmented=True)
    return plant, plant.follow(path, on_step=on_step)


class SweepProgress:
    """A sweep's progress on ``stream`` (default stderr): one updating line
    on a terminal, else one line per step as it ends
    (``sweep: [3/8] left 1.5 mm: converged (0.21 s)``).

    ``winch`` and ``values`` (mm, one per step) name the steps; call it as
    ``on_step(k, state)``, then :meth:`close`.
    """

    def __init__(self, winch: str, values, stream=None):
        self.winch, self.values = winch, [float(v) for v in values]
        self.stream = stream if stream is not None else sys.stderr
        self._line = ProgressLine(self.stream, bool(getattr(self.stream, "isatty", lambda: False)()))
        self._t = time.perf_counter()
        self._write(f"sweep: {len(self.values)} steps of winch {winch} from the start state")

    def _write(self, text: str) -> None:
        self._line.finish()
        print(text, file=self.stream, flush=True)

    def __call__(self, k: int, state) -> None:
        now = time.perf_counter()
        what = "converged" if state.converged else f"not converged: {state.status}"
        line = (f"sweep: [{k}/{len(self.values)}] {self.winch} {self.values[k - 1]:.4g} mm: {what} "
                f"({now - self._t:.2f} s)")
        if self._line.enabled and state.converged:
            self._line.update(line)
        else:
            self._write(line)
        self._t = now

    def close(self) -> None:
        self._line.finish()


def write_csv(problem, plant, states, out: Path) -> None:
    scene = problem.scene
    header = ["step"] + [f"c_{w}" for w in problem.winch_names]
    points = followed_positions(problem, states)
    for k in range(points.shape[1]):
        header += [f"x_{k}", f"y_{k}"]
    for t in scene.tendons:
        header += [f"T_{t.name}_winch", f"T_{t.name}_stopper"]
    with atomic_path(out) as tmp, open(tmp, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        for i, s in enumerate(states):
            row = [i] + [float(v) for v in s.contraction]
            for xy in points[i]:
                row += [float(v) for v in xy]
            for ends in plant.end_tensions(s):
                row += [float(v) for v in ends]
            writer.writerow([f"{v:.10g}" if isinstance(v, float) else v for v in row])


def cmd_sweep(args) -> int:
    t0 = time.perf_counter()
    check_steps(args.steps)
    problem = load(args.problem, max_area=args.max_area)
    path = sweep_path(problem, args.winch, args.to, args.back, args.steps, dict(args.contraction))
    w = problem.winch_names.index(args.winch)
    progress = None if is_quiet() else SweepProgress(args.winch, path[:, w])
    try:
        plant, states = run_sweep(problem, path, on_step=progress)
    finally:
        if progress is not None:
            progress.close()
    write_csv(problem, plant, states, args.out)
    if args.plot is not None:
        from .sweep_plot import plot_sweep
        plot_sweep(problem, states, args.winch, args.plot)
    last = states[-1]
    say(f"sweep: {len(states) - 1} of {len(path)} steps, {last.status}, "
        f"{time.perf_counter() - t0:.2f} s; wrote {args.out}")
    return 0 if last.converged and len(states) == len(path) + 1 else 3
