"""Time the elastic kernels over many elements: one call per element
against the compiled loop in chunks (plush_opt/fem/mapped.py).

    OPENBLAS_NUM_THREADS=1 python tools/bench_kernels.py [--elements N] [--repeats R]

Prints, per kernel (energy; gradient; gradient and Hessian), the median
CPU time of R calls over N P1 elements each way and their ratio."""

from __future__ import annotations

import argparse
import time

import numpy as np

from plush_opt.fem import elements
from plush_opt.fem.mapped import COMPILED_CHUNK, Mapped


def median_cpu(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, default=19606)
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args()
    n = args.elements
    kernels = elements.named("P1").kernels
    rng = np.random.default_rng(3)
    xe = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 1.0]) + rng.uniform(-0.05, 0.05, (n, 6))
    consts = {1: np.tile([1.0, 0.0, 0.0, 1.0], (n, 1)), 2: np.full(n, 0.5),
              3: np.full(n, 2.0), 4: np.full(n, 5.0)}
    print(f"{n} P1 elements, compiled chunks of {COMPILED_CHUNK}, median CPU of {args.repeats}")
    print("| kernel | one call per element | compiled loop | ratio |")
    print("|---|---|---|---|")
    for name, n_out, what in (("psi", 1, "energy"), ("psi_grad", 2, "gradient"),
                              ("psi_derivs", 3, "gradient and Hessian")):
        per = Mapped(kernels[name], n, consts)
        loop = Mapped(kernels[name], n, consts, kernels.symbolic[name])
        a = median_cpu(lambda: per(xe, n_out), args.repeats)
        b = median_cpu(lambda: loop(xe, n_out), args.repeats)
        print(f"| {what} | {1e3 * a:.2f} ms | {1e3 * b:.2f} ms | {a / b:.1f}x |")


if __name__ == "__main__":
    main()
