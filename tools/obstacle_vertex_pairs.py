"""What the format's contact energy does at an obstacle's vertices as the
body's boundary is refined (docs/model.md, "Contact").

    python tools/obstacle_vertex_pairs.py
    python tools/obstacle_vertex_pairs.py --scene problems/gripper_object.yaml \\
        --contraction left=2.7476,right=0,grip=18.9977 --levels 3

The format sums w b(d^2) over every pair: an obstacle vertex pairs with
every boundary segment within d_hat, each pair with the vertex's weight.
The first part is arithmetic: a vertex at distance ``--gap`` from a straight
boundary cut into segments of length h (d_hat 1, weight 1) against the
same boundary's nodes at that distance from a straight obstacle edge (their
length weights): the vertex's sum grows like 1/h, the nodes' converges to
the integral of b along the boundary. The sum with the duplicates removed
(the segments' terms minus those of the nodes between them: the improved
max approximator of Li et al. 2023, "Convergent Incremental Potential
Contact") is b of the distance to the boundary at every h.

With ``--scene``: forward solves at the given contractions on the P2 levels
of one nested family (the file's mesh refined uniformly), with the format's
pairs and with the vertex pairs' duplicates removed (an experiment, switched
here only): where the target points go, and the largest distance between
the two at each level.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from plush_opt.fem import contact as contact_module  # noqa: E402
from plush_opt.fem import contact_geometry as geo  # noqa: E402

D_HAT = 1.0
GAP = 0.5
SIZES = (0.5, 0.25, 0.125, 0.0625, 0.03125)


def _barrier(p, a, b):
    s, _, _ = geo.point_segment_sq(p, a, b, order=0)
    return geo.barrier(s, D_HAT ** 2, 0)[0]


def arithmetic(gap: float, sizes) -> list[str]:
    """The table of the first part, as markdown lines."""
    lines = ["| h | vertex: segments in reach | vertex: format's sum | vertex: duplicates removed | "
             "nodes against an edge: format's sum |", "|---|---|---|---|---|"]
    v = np.array([[0.0, gap]])
    for h in sizes:
        xs = np.arange(-2.0, 2.0 + h / 2, h) + h / 3          # a boundary not symmetric about the vertex
        A = np.c_[xs[:-1], np.zeros(len(xs) - 1)]
        B = np.c_[xs[1:], np.zeros(len(xs) - 1)]
        seg = _barrier(np.repeat(v, len(A), 0), A, B)
        nodes = np.c_[xs, np.zeros(len(xs))]
        inner = nodes[1:-1]
        vertex_sum = float(np.sum(seg))
        removed = vertex_sum - float(np.sum(_barrier(np.repeat(v, len(inner), 0), inner, inner)))
        # the same boundary's nodes below a straight obstacle edge at that gap, weighted by length
        edge_a, edge_b = np.array([[-10.0, gap]]), np.array([[10.0, gap]])
        w = np.full(len(nodes), h)
        w[[0, -1]] = h / 2
        node_sum = float(np.sum(w * _barrier(nodes, np.repeat(edge_a, len(nodes), 0),
                                             np.repeat(edge_b, len(nodes), 0))))
        lines.append(f"| {h:g} | {int(np.count_nonzero(seg))} | {vertex_sum:.4g} | {removed:.6g} | {node_sum:.6g} |")
    lines.append(f"\nb(d^2) at the gap {gap:g}: {float(geo.barrier(np.array([gap * gap]), D_HAT ** 2, 0)[0][0]):.6g}")
    return lines


def _without_duplicates(plain):
    """ContactTerm._find_pairs with each obstacle vertex's pairs with the
    body's nodes (and each body node's with the obstacle's vertices)
    subtracted: point-point pairs at minus the weight."""
    def find(self, P, radius):
        base = plain(self, P, radius)
        parts = [(base.dofs, base.P, base.A, base.B, base.weight, base.label)]
        bd = self.node_dofs
        for k, ((oa, _), ow) in enumerate(zip(self._obstacle_edges, self._obstacle_weight)):
            v, j = np.nonzero(np.linalg.norm(oa[:, None, :] - P[None, :, :], axis=2) < radius)
            none2, none4 = np.full((len(v), 2), -1), np.full((len(v), 4), -1)
            label = np.full(len(v), k + 1)
            parts.append((np.c_[none2, bd[j], bd[j]], oa[v], P[j], P[j], -ow[v], label))
            parts.append((np.c_[bd[j], none4], P[j], oa[v], oa[v], -self.boundary.weight[j], label))
        return contact_module.Pairs(*(np.concatenate([p[i] for p in parts]) for i in range(6)))
    return find


def scene_levels(path: str, contraction: dict, levels: int) -> list[str]:
    from plush_opt.fem.mesh import build_mesh
    from plush_opt.io.problem_file import load_scene
    from plush_opt.problem import from_scene
    scene = load_scene(path).replace(element="P2")
    plain = contact_module.ContactTerm._find_pairs
    lines = ["| P2 nodes | targets, format's pairs | targets, duplicates removed | largest difference |",
             "|---|---|---|---|"]
    for r in range(levels):
        mesh = build_mesh(scene, refinements=r)
        ys = []
        for find in (plain, _without_duplicates(plain)):
            contact_module.ContactTerm._find_pairs = find
            try:
                p = from_scene(scene, mesh)
                eq = p.equilibrium(contraction)
                if not eq.converged:
                    raise SystemExit(f"{path}: not converged on {mesh.n_nodes} nodes: {eq.status}")
                ys.append(p.targets.y(eq.x))
            finally:
                contact_module.ContactTerm._find_pairs = plain
        fmt = lambda y: "; ".join(f"({a:.4f}, {b:.4f})" for a, b in y)     # noqa: E731
        lines.append(f"| {mesh.n_nodes:,} | {fmt(ys[0])} | {fmt(ys[1])} | "
                     f"{float(np.max(np.linalg.norm(ys[0] - ys[1], axis=1))):.2g} |")
        print(lines[-1], file=sys.stderr, flush=True)
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--gap", type=float, default=GAP)
    ap.add_argument("--sizes", type=float, nargs="+", default=list(SIZES))
    ap.add_argument("--scene")
    ap.add_argument("--contraction", default="", help="name=value,... (with --scene)")
    ap.add_argument("--levels", type=int, default=3)
    args = ap.parse_args(argv)
    print("\n".join(arithmetic(args.gap, args.sizes)))
    if args.scene:
        c = {k: float(v) for k, v in (pair.split("=") for pair in args.contraction.split(",") if pair)}
        print("\n" + "\n".join(scene_levels(args.scene, c, args.levels)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
