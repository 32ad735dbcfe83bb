"""The work of a solve, counted rather than timed.

Which mesh level an accuracy sweep solves next and which one it picks
depend on what each level costs. Measured CPU seconds vary with the load
of the machine by tens of percent, and so would the picks: the same
command could return another mesh. Here a solve's cost is its
factorisations and evaluations, counted while it runs and weighted by
what each typically takes, so the same solve always gets the same cost.

Weights (CPU seconds on one core of an x86 machine of 2026, fitted to the
gripper and the hexapod, P1 and P2, 1,000-16,000 nodes): a sparse
Cholesky factorisation of a 2D mesh's matrix with ``nnz`` entries costs
about ``FACTOR_S * nnz^1.5`` (nested dissection: n^1.5 in the unknowns,
and a denser row fills its separators as much as more unknowns do); an
evaluation with the Hessian ``EVAL_HESSIAN_S * nnz``, one without it
(with the solve that goes with it in a kept-factor step)
``EVAL_GRADIENT_S * nnz``, and each of them ``OPERATION_S`` more (the
Python around it: what a small mesh's solve mostly costs). Enough to order
levels whose node counts differ by 4x; how close it comes to measured
times: ``tools/accuracy_work.py``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time

from ..base.low_rank import LowRankHessian

FACTOR_S = 0.15e-9
EVAL_HESSIAN_S = 14e-9
EVAL_GRADIENT_S = 10e-9
OPERATION_S = 0.3e-3


@dataclasses.dataclass
class Work:
    """What a solve did: factorisations (their matrices' entries) and
    evaluations with and without the Hessian; and the CPU seconds it took
    (reported beside the count, whatever else ran on the machine)."""

    factored: list = dataclasses.field(default_factory=list)    # nnz of each matrix factored
    hessians: int = 0
    gradients: int = 0
    cpu_s: float = dataclasses.field(default=0.0, compare=False)

    @property
    def seconds(self) -> float:
        """The counted work in typical CPU seconds (module docstring)."""
        nnz = self.factored[-1] if self.factored else 0
        return float(sum(FACTOR_S * k ** 1.5 for k in self.factored)
                     + (EVAL_HESSIAN_S * self.hessians + EVAL_GRADIENT_S * self.gradients) * nnz
                     + OPERATION_S * (len(self.factored) + self.hessians + self.gradients))


def _factored_nnz(H) -> int:
    # the low-rank form factors its sparse body (the rest is k solves: left out)
    return int((H.body if isinstance(H, LowRankHessian) else H).nnz)


@contextlib.contextmanager
def counted(model):
    """Count the factorisations and evaluations of ``model`` while the
    block runs: ``with counted(model) as work: ...``, then ``work.seconds``
    (and the block's CPU seconds, ``work.cpu_s``).
    What goes through :meth:`Model.evaluate` and the model's factoriser is
    counted: all of a Newton solve's work, not IPOPT's own evaluations."""
    work = Work()
    evaluate, factor = model.evaluate, model.factorizer.factor

    def counted_evaluate(x, c, order: int = 2):
        if order >= 2:
            work.hessians += 1
        else:
            work.gradients += 1
        return evaluate(x, c, order)

    def counted_factor(H, *args, **kwargs):
        work.factored.append(_factored_nnz(H))
        return factor(H, *args, **kwargs)

    # (restored as they were: the class's, or a wrapper of the caller's own)
    before = [(obj, name, obj.__dict__.get(name)) for obj, name in ((model, "evaluate"),
                                                                   (model.factorizer, "factor"))]
    model.evaluate, model.factorizer.factor = counted_evaluate, counted_factor
    t0 = time.process_time()
    try:
        yield work
    finally:
        work.cpu_s = time.process_time() - t0
        for obj, name, own in before:
            if own is None:
                delattr(obj, name)
            else:
                setattr(obj, name, own)
