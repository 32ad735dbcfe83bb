"""Time the elastic kernels over many elements: one call per element
against the compiled loop in chunks (plush_opt/fem/mapped.py).

    OPENBLAS_NUM_THREADS=1 python tools/bench_kernels.py [--elements N [N ...]] [--element P2] [--repeats R]

Prints, per element count N and kernel (energy; gradient; gradient and
Hessian), the chunk the compiled loop takes, the median CPU time of R
calls over N elements (P1 unless given) each way and their ratio."""

from __future__ import annotations

import argparse
import time

import numpy as np

from plush_opt.fem import elements
from plush_opt.fem.mapped import Mapped


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
    ap.add_argument("--elements", type=int, nargs="+", default=[19606])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--element", choices=("P1", "P2"), default="P1")
    args = ap.parse_args()
    kernels = elements.named(args.element).kernels
    # a rest triangle (P2: and its edge midpoints), each element moved a little
    rest = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0] + ([0.5, 0.0, 0.5, 0.5, 0.0, 0.5] if args.element == "P2" else [])
    print(f"{args.element} elements, median CPU of {args.repeats}")
    print("| elements | chunk | kernel | one call per element | compiled loop | ratio |")
    print("|---|---|---|---|---|---|")
    for n in args.elements:
        rng = np.random.default_rng(3)
        xe = np.array(rest) + rng.uniform(-0.05, 0.05, (n, len(rest)))
        consts = {1: np.tile([1.0, 0.0, 0.0, 1.0], (n, 1)), 2: np.full(n, 0.5),
                  3: np.full(n, 2.0), 4: np.full(n, 5.0)}
        for name, n_out, what in (("psi", 1, "energy"), ("psi_grad", 2, "gradient"),
                                  ("psi_derivs", 3, "gradient and Hessian")):
            per = Mapped(kernels[name], n, consts)
            loop = Mapped(kernels[name], n, consts, kernels.symbolic[name])
            a = median_cpu(lambda: per(xe, n_out), args.repeats)
            b = median_cpu(lambda: loop(xe, n_out), args.repeats)
            print(f"| {n} | {loop.chunk} | {what} | {1e3 * a:.3f} ms | {1e3 * b:.3f} ms | {a / b:.1f}x |")


if __name__ == "__main__":
    main()
