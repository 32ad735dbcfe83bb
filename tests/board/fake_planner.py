"""A stand-in for the control side in board and run tests.

FakePlanner follows the ``plush_opt.apps.runs.Planner`` protocol: ``forward``
echoes its input, ``pose`` walks linearly from the current contraction to
a goal in ``steps`` iterates, each certified (optionally sleeping between them). The goal
is given, or derived from the targets' displacement, always within bounds.
"""

from __future__ import annotations

import time

import numpy as np


class FakePlanner:
    def __init__(self, winch_names=("left", "right", "grip"), lower=None, upper=None, *, steps=10, delay=0.0,
                 goal=None):
        self.winch_names = tuple(winch_names)
        n = len(self.winch_names)
        self.lower = np.asarray(lower if lower is not None else [0.0] * n, dtype=float)
        self.upper = np.asarray(upper if upper is not None else [20.0] * n, dtype=float)
        self.steps = int(steps)
        self.delay = float(delay)
        self.goal = dict(goal) if goal is not None else None
        self.current = dict(zip(self.winch_names, self.lower.tolist()))
        self.calls = []

    def _check(self, c):
        for name, lo, hi in zip(self.winch_names, self.lower, self.upper):
            if not lo - 1e-12 <= c[name] <= hi + 1e-12:
                raise ValueError(f"FakePlanner: {name}={c[name]} outside [{lo}, {hi}]")

    def forward(self, contraction):
        c = {n: float(contraction[n]) for n in self.winch_names}
        self._check(c)
        self.calls.append(("forward", dict(c)))
        self.current = c
        return {"contraction": dict(c), "objective": 0.0, "converged": True, "status": "fake forward"}

    def _goal(self, targets, freeze):
        if self.goal is not None:
            goal = {n: self.goal.get(n, self.current[n]) for n in self.winch_names}
        else:
            d = sum(float(np.hypot(t["to"][0] - t["at"][0], t["to"][1] - t["at"][1])) * t.get("weight", 1.0)
                    for t in targets)
            n = len(self.winch_names)
            goal = {}
            for i, (name, lo, hi) in enumerate(zip(self.winch_names, self.lower, self.upper)):
                frac = min(0.8, d / 50.0 * (i + 1) / n)
                goal[name] = float(lo + frac * (hi - lo))
        for name in freeze:
            goal[name] = self.current[name]
        return goal

    def pose(self, targets, freeze, max_time):
        self.calls.append(("pose", [dict(t) for t in targets], list(freeze), max_time))
        start, goal = dict(self.current), self._goal(targets, freeze)
        obj0 = sum((goal[n] - start[n]) ** 2 for n in self.winch_names)
        for k in range(1, self.steps + 1):
            if self.delay:
                time.sleep(self.delay)
            s = k / self.steps
            c = {n: start[n] + s * (goal[n] - start[n]) for n in self.winch_names}
            self._check(c)
            self.current = c
            yield {"contraction": dict(c), "objective": (1 - s) ** 2 * obj0, "converged": k == self.steps,
                   "status": "converged" if k == self.steps else f"iterate {k}", "certified": True}
