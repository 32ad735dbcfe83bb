"""Time the contact kernels: barrier + point-segment distance + their
derivatives, ours (numpy, plush_opt/fem/contact_geometry.py) against the
Incremental Potential Contact toolkit's 2D equivalent when ``ipctk`` imports.

    OPENBLAS_NUM_THREADS=1 python tools/contact_kernels_bench.py [--pairs 10000 100000]
        [--repeats 5] [--out FILE.md]

Two measurements per number of pairs k:

- ``kernel``: k point-segment pairs (a third each nearest to end a, to
  end b, to the interior), each pair's barrier value, 6-vector gradient and
  6x6 Hessian of b(d^2) with respect to (p, a, b). Ours is one vectorised
  call; ipctk exposes these per pair only (barrier, point_edge_distance and
  their gradient/Hessian functions), so its figure includes one Python
  call per function and pair.
- ``potential``: the whole barrier potential of a mesh holding the k pairs
  (k separate edge + point configurations, far apart, every vertex tested
  against every edge): broad phase, narrow phase, energy, gradient and the
  sparse Hessian. ipctk: NormalCollisions.build + BarrierPotential value,
  gradient, hessian (C++ throughout, no PSD projection); ours:
  candidate_pairs + point_segment_sq + barrier + the chain rule, assembled
  into a scipy CSR matrix.
- ``stepsize``: the largest collision-free fraction of a step in which a
  third of the points move through their segments, a third slide along
  them and a third move away: ours is motion_candidates +
  ccd_point_segment (additive CCD, min_fraction 0.2); ipctk's is
  compute_collision_free_stepsize with its additive and its tight-inclusion
  narrow phase.

Reports the median of the repeats, wall-clock and process CPU time (the CPU
time is the figure to quote on a shared machine; ipctk runs on one thread
unless ``--ipctk-threads`` says otherwise), and ours / ipctk ratios;
writes them as a markdown table to ``--out`` and prints it.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from plush_opt.base.files import write_text_atomic
from plush_opt.fem.contact_geometry import (barrier, candidate_pairs, ccd_point_segment,
                                           motion_candidates, point_segment_sq)

DHAT = 0.1          # barrier distance; every configuration's point lies within it
SPACING = 10.0      # configurations this far apart never see each other


def configurations(k: int, seed: int = 0):
    """k unit segments on a grid, each with a point at distance in
    (0.05, 0.9) d_hat nearest to its end a, end b or interior in turn."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(k)))
    corner = SPACING * np.column_stack([np.arange(k) % side, np.arange(k) // side]).astype(float)
    angle = rng.uniform(0, 2 * np.pi, k)
    e = np.column_stack([np.cos(angle), np.sin(angle)])
    n = np.column_stack([-e[:, 1], e[:, 0]])
    along = np.choose(np.arange(k) % 3, [rng.uniform(-0.05, 0.0, k), rng.uniform(1.0, 1.05, k),
                                         rng.uniform(0.1, 0.9, k)])
    off = rng.uniform(0.05, 0.9, k) * DHAT * rng.choice([-1.0, 1.0], k)
    a, b = corner, corner + e
    p = a + along[:, None] * e + off[:, None] * n
    # the offset along the line can add distance at the ends: keep all pairs inside d_hat
    keep = point_segment_sq(p, a, b, order=0)[0] < (0.95 * DHAT) ** 2
    return p[keep], a[keep], b[keep]


def ours_kernel(p, a, b):
    s, g, h = point_segment_sq(p, a, b)
    v, dv, d2v = barrier(s, DHAT ** 2)
    grad = dv[:, None] * g
    hess = d2v[:, None, None] * np.einsum("ki,kj->kij", g, g) + dv[:, None, None] * h
    return v.sum(), grad, hess


def ipctk_kernel(ipctk, p, a, b):
    total = 0.0
    for pi, ai, bi in zip(p, a, b):
        s = ipctk.point_edge_distance(pi, ai, bi)
        g = ipctk.point_edge_distance_gradient(pi, ai, bi)
        h = ipctk.point_edge_distance_hessian(pi, ai, bi)
        dv = ipctk.barrier_first_derivative(s, DHAT ** 2)
        d2v = ipctk.barrier_second_derivative(s, DHAT ** 2)
        total += ipctk.barrier(s, DHAT ** 2)
        _ = d2v * np.outer(g, g) + dv * h
    return total


def mesh_of(p, a, b):
    """Vertices (3k, 2): points, then each segment's ends; edges (k, 2)."""
    k = len(p)
    V = np.vstack([p, a, b])
    E = np.column_stack([k + np.arange(k), 2 * k + np.arange(k)])
    return V, E


def ours_potential(V, E):
    exclude = E                                  # a segment's own ends
    point, seg = candidate_pairs(V, V[E[:, 0]], V[E[:, 1]], DHAT, exclude=exclude)
    s, g, h = point_segment_sq(V[point], V[E[seg, 0]], V[E[seg, 1]])
    v, dv, d2v = barrier(s, DHAT ** 2)
    grad_local = dv[:, None] * g
    hess_local = d2v[:, None, None] * np.einsum("ki,kj->kij", g, g) + dv[:, None, None] * h
    dofs = (2 * np.column_stack([point, E[seg, 0], E[seg, 1]])[:, :, None] + [0, 1]).reshape(-1, 6)
    grad = np.bincount(dofs.ravel(), grad_local.ravel(), minlength=V.size)
    rows = np.repeat(dofs, 6, axis=1).ravel()
    cols = np.tile(dofs, (1, 6)).ravel()
    hess = sp.csr_matrix((hess_local.ravel(), (rows, cols)), shape=(V.size, V.size))
    return v.sum(), grad, hess


def ipctk_potential(ipctk, V, E):
    mesh = ipctk.CollisionMesh(V, E.astype(np.int32))
    collisions = ipctk.NormalCollisions()
    collisions.build(mesh, V, DHAT)
    potential = ipctk.BarrierPotential(DHAT, 1.0)
    return (potential(collisions, mesh, V), potential.gradient(collisions, mesh, V),
            potential.hessian(collisions, mesh, V))


def motion_of(p, a, b, seed=1):
    """A step for every configuration: its point moves through its segment
    (to twice its distance beyond), slides along it, or moves away, in turn;
    the segments stay."""
    rng = np.random.default_rng(seed)
    k = len(p)
    s, g, _ = point_segment_sq(p, a, b, order=1)
    toward = -g[:, :2] / 2                              # from p to its nearest point
    e = (b - a) / np.linalg.norm(b - a, axis=1)[:, None]
    dp = np.choose((np.arange(k) % 3)[:, None], [2 * toward, 0.5 * e, -toward]) \
        + rng.normal(scale=1e-3, size=(k, 2))
    return np.vstack([dp, np.zeros((2 * k, 2))])


def ours_stepsize(V, dV, E):
    a, b, da, db = V[E[:, 0]], V[E[:, 1]], dV[E[:, 0]], dV[E[:, 1]]
    point, seg = motion_candidates(V, dV, a, b, da, db, 0.0, exclude=E)
    t = ccd_point_segment(V[point], a[seg], b[seg], dV[point], da[seg], db[seg])
    return float(t.min(initial=1.0))


def ipctk_stepsize(ipctk, V, dV, E, narrow):
    mesh = ipctk.CollisionMesh(V, E.astype(np.int32))
    return ipctk.compute_collision_free_stepsize(mesh, V, V + dV, narrow_phase_ccd=narrow)


def median_times(run, repeats):
    wall, cpu = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        out = run()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return 1e3 * statistics.median(wall), 1e3 * statistics.median(cpu), out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, nargs="+", default=[10_000, 100_000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--ipctk-threads", type=int, default=1,
                    help="ipctk's worker threads (1: the same single core numpy uses)")
    args = ap.parse_args(argv)
    try:
        import ipctk
        ipctk.set_num_threads(args.ipctk_threads)
    except ImportError:
        ipctk = None
    rows = []
    for k in args.pairs:
        p, a, b = configurations(k)
        V, E = mesh_of(p, a, b)
        dV = motion_of(p, a, b)
        cases = [("kernel", "numpy", lambda: ours_kernel(p, a, b)),
                 ("potential", "numpy", lambda: ours_potential(V, E)),
                 ("stepsize", "numpy", lambda: ours_stepsize(V, dV, E))]
        if ipctk is not None:
            cases += [("kernel", "ipctk", lambda: ipctk_kernel(ipctk, p, a, b)),
                      ("potential", "ipctk", lambda: ipctk_potential(ipctk, V, E)),
                      ("stepsize", "ipctk", lambda: ipctk_stepsize(ipctk, V, dV, E, ipctk.AdditiveCCD())),
                      ("stepsize", "ipctk-tight", lambda: ipctk_stepsize(ipctk, V, dV, E,
                                                                          ipctk.TightInclusionCCD()))]
        for what, impl, run in cases:
            wall, cpu, out = median_times(run, args.repeats)
            value = out if np.isscalar(out) else out[0]       # energy, or the step found
            rows.append({"what": what, "pairs": len(p), "impl": impl, "wall_ms": wall, "cpu_ms": cpu,
                         "value": float(value)})
    text = table(rows, ipctk, args.repeats)
    print(text)
    if args.out:
        write_text_atomic(args.out, text)


def table(rows, ipctk, repeats):
    lines = [f"contact kernels: median of {repeats} repeats; python {platform.python_version()}, "
             f"numpy {np.__version__}, ipctk {getattr(ipctk, '__version__', 'not installed')}", "",
             "| what | pairs | impl | wall ms | cpu ms | ours/ipctk (cpu) | value |",
             "|---|---|---|---|---|---|---|"]
    cpu = {(r["what"], r["pairs"], r["impl"]): r["cpu_ms"] for r in rows}
    for r in rows:
        ours = cpu.get((r["what"], r["pairs"], "numpy"))
        ratio = f"{ours / r['cpu_ms']:.3g}" if r["impl"] != "numpy" and r["cpu_ms"] > 0 else ""
        lines.append(f"| {r['what']} | {r['pairs']} | {r['impl']} | {r['wall_ms']:.1f} | {r['cpu_ms']:.1f} "
                     f"| {ratio} | {r['value']:.10g} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
