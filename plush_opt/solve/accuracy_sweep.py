"""Which mesh level an accuracy sweep solves next, and when it stops.

The default sweep (:func:`plush_opt.solve.accuracy.choose_levels`) has, per
element type, two nested families of levels (:func:`~plush_opt.solve.accuracy.default_levels`):
four *chains* (P2 A, P2 B, P1 A, P1 B), each solved coarse to fine. A level
of a chain gets an error estimate once the level after it is solved
(three levels of a chain for the first), and any level gets a bound once
some estimate exists (:func:`~plush_opt.solve.accuracy.bound_errors`).
Solving every chain to the end costs far more than the level that is
picked (a level 4x finer than the one it confirms, solved for every
element and family). Here the cost of each level is predicted before it
is solved, and:

* **the next level** is the one at the front of the chain whose *predicted
  cost to a level that meets the tolerance* is least (:meth:`Planner.cost_to_meet`):
  the chain's remaining levels up to the one that would confirm such a
  level, its error predicted from the chain's element's finest estimate
  and ratio (optimistically, its first estimate, where there is none yet;
  never, where the element's finest estimate says its levels do not converge);
* **the sweep stops** as soon as a level meets the tolerance, except that
  levels predicted to cost less than that level are still solved (a
  cheaper pick, bounded through the estimate that met it), for at most
  :data:`EXTRA_BUDGET` times its cost in all;
* a chain whose next level would exceed the default sweep (its finest
  level) is finished, and when no chain can still meet the tolerance the
  first chain (the first element's family A) is solved to its end, the
  budget of a tolerance that is not met, and the sweep stops there.

The cost of a level's solve is predicted from its node count ``n`` (a
refined level has 4x its parent's nodes, known before it is meshed) and
the levels of its element solved so far (:class:`CostModel`): between two
of them interpolated in log n and log t, beyond them ``t = a n^p`` from
the nearest, ``p`` fitted to them all. A solved level's cost is its counted work
(:attr:`~plush_opt.solve.accuracy_estimate.Level.cost`, in typical CPU
seconds: :mod:`plush_opt.solve.work`), not its measured time, so the same
command solves the same levels and picks the same one on every run, however
loaded the machine.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

#: The solve time's exponent in the node count before two levels of an
#: element are solved: a sparse Cholesky of a 2D mesh grows like n^1.2-1.5.
COST_EXPONENT = 1.3
#: The fitted exponent is kept within these (a noisy fit of two small levels).
COST_EXPONENT_RANGE = (1.0, 2.0)
#: After a level meets the tolerance, levels predicted to cost less than
#: it may still be solved (a cheaper pick), for at most this many times its
#: cost in all.
EXTRA_BUDGET = 2.0
#: Nodes of a uniformly refined level per node of the one before it.
REFINEMENT_GROWTH = 4.0


class CostModel:
    """Predicted one-solve costs (typical CPU seconds, :attr:`Level.cost`)
    of levels, fitted per element type to the levels solved so far:
    ``t = a n^p``."""

    def __init__(self):
        self.samples: dict[str, list[tuple[int, float]]] = {}

    def add(self, element: str, n_nodes: int, cost: float) -> None:
        self.samples.setdefault(element, []).append((int(n_nodes), max(float(cost), 1e-6)))

    def exponent(self, element: str) -> float:
        """The fitted p of ``element`` (COST_EXPONENT before two levels of
        clearly different sizes are solved)."""
        return self._fit(self.samples.get(element, []))

    @staticmethod
    def _fit(s) -> float:
        n = np.array([a for a, _ in s], dtype=np.float64)
        if len(s) < 2 or n.max() < 1.5 * n.min():
            return COST_EXPONENT
        t = np.array([b for _, b in s])
        p = np.polyfit(np.log(n), np.log(t), 1)[0]
        return float(np.clip(p, *COST_EXPONENT_RANGE))

    def predict(self, element: str, n_nodes: float) -> float:
        """Seconds for one solve of a level of ``element`` with ``n_nodes``:
        between two of that element's levels solved, interpolated in log n
        and log t (a small level's fixed costs show); beyond them, from the
        nearest by the fitted exponent; with none of that element, from any
        element's levels; with none at all ``n^COST_EXPONENT`` microseconds
        (only the order matters then)."""
        s = self.samples.get(element) or [x for v in self.samples.values() for x in v]
        if not s:
            return 1e-6 * float(n_nodes) ** COST_EXPONENT
        n, t = _log_samples(s)
        x = math.log(float(n_nodes))
        if n[0] <= x <= n[-1]:
            return math.exp(float(np.interp(x, n, t)))
        i = 0 if x < n[0] else -1
        return math.exp(t[i] + self._fit(s) * (x - n[i]))


def _log_samples(s) -> tuple[np.ndarray, np.ndarray]:
    """(log n, log t) of cost samples, by n; samples of the same n averaged."""
    n = np.array([a for a, _ in s], dtype=np.float64)
    t = np.log(np.array([b for _, b in s], dtype=np.float64))
    sizes, where = np.unique(n, return_inverse=True)
    mean = np.bincount(where, weights=t) / np.bincount(where)
    return np.log(sizes), mean


@dataclasses.dataclass
class Chain:
    """One element's nested family of levels, coarse to fine: its
    ``resolutions``, the node count of each (the first meshed, the others
    predicted: 4x per refinement, exact once solved) and the levels
    solved so far (:class:`~plush_opt.solve.accuracy.Level`)."""

    element: str
    resolutions: tuple
    nodes: list
    solved: list = dataclasses.field(default_factory=list)

    @property
    def done(self) -> bool:
        return len(self.solved) == len(self.resolutions)

    @property
    def next(self):
        return self.resolutions[len(self.solved)]

    def predicted_nodes(self, i: int) -> float:
        if i < len(self.solved):
            return self.solved[i].mesh.n_nodes
        n, r0 = self.nodes[0], self.resolutions[0].refinements
        if self.solved:
            n, r0 = self.solved[-1].mesh.n_nodes, self.resolutions[len(self.solved) - 1].refinements
        return n * REFINEMENT_GROWTH ** (self.resolutions[i].refinements - r0)


class Planner:
    """The order of a sweep over ``chains`` for tolerance ``tol`` (see the
    module docstring): :meth:`pick` the chain to solve next, or None."""

    def __init__(self, chains: list[Chain], tol: float):
        self.chains, self.tol = chains, float(tol)
        self.cost = CostModel()
        self.extra_spent = 0.0
        self.stopped = ""             # why the sweep stopped (set by its driver)
        self.best_effort = False      # no chain could meet the tolerance: the first one solved to its end
        self.left_out: list[dict] = []  # contractions left out of the estimates, and why (set by its driver)
        self.cut: list[dict] = []       # levels that cannot be used, and why (:meth:`inadmissible`)

    def solved(self, chain: Chain, level) -> None:
        chain.solved.append(level)
        self.cost.add(level.element, level.mesh.n_nodes, level.cost)

    def inadmissible(self, chain: Chain, nodes: int, why: str, progress=None) -> None:
        """The next level of ``chain`` (of ``nodes`` nodes) cannot be used,
        nor any finer one of its family (``why``: its self-contact pushes in
        the rest pose): the chain ends at the levels it has solved."""
        res = chain.next
        self.cut.append({"element": chain.element, "family": res.family, "refinements": res.refinements,
                         "nodes": int(nodes), "why": why})
        chain.resolutions = chain.resolutions[:len(chain.solved)]
        if progress is not None:
            progress(f"accuracy: {chain.element} level of {nodes:,} nodes not used, nor the finer ones of its "
                     f"family: {why}")

    def _trend(self, element: str):
        """(nodes, estimate, ratio) of the finest level of ``element`` with a
        finite estimate, or None."""
        best = None
        for ch in self.chains:
            if ch.element != element:
                continue
            for lv in ch.solved:
                if lv.estimate is not None and math.isfinite(lv.estimate) and lv.ratio is not None \
                        and (best is None or lv.mesh.n_nodes > best[0]):
                    best = (lv.mesh.n_nodes, lv.estimate, lv.ratio)
        return best

    def _diverging(self, element: str) -> bool:
        """Whether the finest level of ``element`` with an estimate has an
        infinite one (its differences do not shrink there: P1 locking in
        bending, a point load): its other chains are not predicted to meet
        the tolerance either, and another element is tried first."""
        finest = None
        for ch in self.chains:
            for lv in ch.solved if ch.element == element else ():
                if lv.estimate is not None and (finest is None or lv.mesh.n_nodes > finest.mesh.n_nodes):
                    finest = lv
        return finest is not None and not math.isfinite(finest.estimate)

    def predicted_error(self, chain: Chain, i: int) -> float | None:
        """The estimate level ``i`` of ``chain`` is predicted to get: its own
        where it has one, else from its element's trend (the estimate
        shrinking by the ratio per 4x nodes); None without a trend."""
        if i < len(chain.solved) and chain.solved[i].estimate is not None:
            return chain.solved[i].estimate
        if self._diverging(chain.element):
            return math.inf
        trend = self._trend(chain.element)
        if trend is None:
            return None
        n, est, ratio = trend
        return est * ratio ** (math.log(chain.predicted_nodes(i) / n) / math.log(REFINEMENT_GROWTH))

    def cost_to_meet(self, chain: Chain) -> float:
        """Predicted seconds of the chain's levels still to solve before one
        of its levels has an estimate within the tolerance: up to the level
        after it (which confirms it); inf if none is predicted to."""
        k = len(chain.solved)
        for i in range(1, len(chain.resolutions) - 1):
            if i + 1 < k:
                continue              # its estimate is known (and above the tolerance)
            est = self.predicted_error(chain, i)
            if est is None or est <= self.tol:
                return sum(self.cost.predict(chain.element, chain.predicted_nodes(j)) for j in range(k, i + 2))
        return math.inf

    def pick(self, best) -> Chain | None:
        """The chain whose next level to solve: before a level meets the
        tolerance (``best`` None), the least :meth:`cost_to_meet`; after,
        the cheapest next level predicted faster than ``best`` while the
        extra budget lasts. None: stop."""
        open_ = [ch for ch in self.chains if not ch.done]
        if best is None:
            costs = [(self.cost_to_meet(ch), i) for i, ch in enumerate(open_)]
            costs = [c for c in costs if math.isfinite(c[0])]
            if costs:
                return open_[min(costs)[1]]
            # no chain can meet the tolerance: the best effort, the first chain (the first
            # element's family A) to its finest level, the budget of a tolerance not met
            self.best_effort = True
            return None if self.chains[0].done else self.chains[0]
        budget = EXTRA_BUDGET * best.cost - self.extra_spent
        options = [(self.cost.predict(ch.element, ch.predicted_nodes(len(ch.solved))), i)
                   for i, ch in enumerate(open_)]
        options = [o for o in options if o[0] < best.cost and o[0] <= budget]
        return open_[min(options)[1]] if options else None

    def not_solved(self) -> list[dict]:
        """The default levels left unsolved, with their predicted nodes and
        one-solve seconds (for the report)."""
        return [{"element": ch.element, "family": ch.resolutions[0].max_area,
                 "refinements": ch.resolutions[i].refinements,
                 "predicted_nodes": int(round(ch.predicted_nodes(i))),
                 "predicted_t_solve_s": self.cost.predict(ch.element, ch.predicted_nodes(i))}
                for ch in self.chains for i in range(len(ch.solved), len(ch.resolutions))]
