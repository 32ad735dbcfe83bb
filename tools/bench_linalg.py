"""Time one factorisation + solve per sparse backend on the shipped problems'
Hessians, with the symbolic analysis reused across refactorisations (as
Newton does).

    python tools/bench_linalg.py [--nodes 1000 2000 3000] [--repeats 30]
    python tools/bench_linalg.py --modes --element P1 P2 --nodes 5000 10000 15000 20000 --repeats 12

``--modes`` compares CHOLMOD's simplicial LDL^T and supernodal LL^T instead
(the crossover behind ``linalg.SUPERNODAL_MIN_ENTRIES``), of the assembled
Hessian; with ``--taken`` of the form Newton factors (a low-rank form: its
sparse body and the Woodbury set-up), with ``--peer`` of the body under
gravity without tendons (the ``plush-opt bench --peers`` problem):

    python tools/bench_linalg.py --modes --taken --peer --problems gripper --nodes 10000 20000 30000 40000

With ``--solves``, whole forward solves from rest in each mode instead
(every factorisation and solve Newton takes; CPU time, medians; nnz(H):
the entries of the matrix factored, the crossover's measure):

    python tools/bench_linalg.py --modes --solves [--peer] [--element P2] --problems gripper --nodes 20000 30000 40000 --repeats 5

``--forms`` compares
the Hessian's forms with finite attachments (assembled, rank_one, split:
docs/model.md, "The tendon terms as a low-rank update"; the crossover
behind ``model.SPLIT_MIN_DISC_NODES``), and the split form through its
augmented matrix (``linalg.augmented_factor``, where its body alone is
not positive definite):

    python tools/bench_linalg.py --forms --element P1 P2 --nodes 500 1000 3000 10000 --repeats 12

For each problem and node count: the Hessian at the equilibrium of a
mid-range contraction, then the time of ``factor(H)`` +
``solve(b)`` through :class:`plush_opt.base.linalg.Factorizer` for each
installed backend (the pivot test included), and of SciPy's SuperLU
(``splu``, no reuse of the analysis possible) as a baseline, and of
cholespy if installed (another wheel, no refactorisation API): the fastest
of ``--repeats`` calls, the backends interleaved. Prints a
Markdown table; the ratio column is QDLDL's time over CHOLMOD's.
Run it with one BLAS thread (OPENBLAS_NUM_THREADS=1), as the test suite does.
"""

from __future__ import annotations

import argparse
import platform
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
import scipy.sparse.linalg as spla

from plush_opt.base import linalg, low_rank
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
from plush_opt.fem.mesh import mesh_for_nodes
from plush_opt.fem.model import Model, build_model
from plush_opt.io import load_scene

ROOT = Path(__file__).resolve().parent.parent
PROBLEMS = ("gripper", "hexapod", "hexapod_leg")
#: where in each winch's range the Hessian is taken (a loaded, not a rest, pose)
CONTRACTION_FRACTION = 0.4


def _best_seconds(fns: dict, repeats: int) -> dict:
    """Fastest of ``repeats`` timed calls of each function, the functions
    taken in turn so a busy machine slows them alike (the fastest call is
    the one least disturbed by other processes)."""
    for fn in fns.values():
        fn()                               # the first call does the symbolic analysis
    best = dict.fromkeys(fns, np.inf)
    for _ in range(repeats):
        for key, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            best[key] = min(best[key], time.perf_counter() - t0)
    return best


def _loaded(name: str, nodes: int, element: str = "P1", peer: bool = False):
    """(mesh, model, contraction): the problem on about ``nodes`` nodes at
    a mid-range contraction; with ``peer`` its body under gravity without
    tendons (the ``bench --peers`` problem)."""
    if peer:
        from plush_opt.apps.bench_peers import peer_problem
        _, mesh, prob = peer_problem(ROOT / "problems" / f"{name}.yaml", nodes, element)
        model = prob.model
    else:
        scene = load_scene(ROOT / "problems" / f"{name}.yaml").replace(element=element)
        mesh = mesh_for_nodes(scene, nodes)
        model = build_model(scene, mesh)
    return mesh, model, model.lower + CONTRACTION_FRACTION * (model.upper - model.lower)


def _hessian(name: str, nodes: int, element: str = "P1", taken: bool = False, peer: bool = False):
    """(nodes, Hessian at a loaded equilibrium): assembled, or with
    ``taken`` the form Newton factors (a low-rank form stays one); with
    ``peer`` of the problem's body under gravity without tendons (the
    ``bench --peers`` problem)."""
    mesh, model, c = _loaded(name, nodes, element, peer)
    eq = solve_equilibrium(model, c, options=EquilibriumOptions(eigenvalue=False))
    ev = model.evaluate(eq.x, c)
    return mesh.n_nodes, (ev.hessian_form if taken else ev.hessian)


def _version(pkg: str) -> str:
    try:
        return version(pkg)
    except PackageNotFoundError:
        return "not installed"


def _cholespy():
    try:
        import cholespy
    except ImportError:
        return None
    return cholespy


def _cholespy_solve(H, b):
    """cholespy (CHOLMOD bundled in a wheel) has no refactorisation: every
    call redoes the analysis."""
    cs = _cholespy()
    solver = cs.CholeskySolverD(H.shape[0], H.indptr.astype(np.int32), H.indices.astype(np.int32),
                                H.data, cs.MatrixType.CSC)
    x = np.empty_like(b)
    solver.solve(b.copy(), x)
    return x


def bench(name: str, nodes: int, repeats: int, backends) -> dict:
    n_nodes, H = _hessian(name, nodes)
    b = np.random.default_rng(0).standard_normal(H.shape[0])
    fns = {backend: (lambda fz: lambda: fz.factor(H).solve(b))(linalg.Factorizer(backend))
           for backend in backends}
    fns["splu"] = lambda: spla.splu(H).solve(b)
    if _cholespy() is not None:
        fns["cholespy"] = lambda: _cholespy_solve(H, b)
    return {"problem": name, "nodes": n_nodes, "nnz": H.nnz, **_best_seconds(fns, repeats)}


def bench_modes(name: str, nodes: int, element: str, repeats: int, taken: bool = False,
                peer: bool = False) -> dict:
    n_nodes, H = _hessian(name, nodes, element, taken, peer)
    b = np.random.default_rng(0).standard_normal(H.shape[0])
    fns = {mode: (lambda fz: lambda: fz.factor(H).solve(b))(linalg.Factorizer("cholmod", mode))
           for mode in ("simplicial", "supernodal")}
    nnz = H.body.nnz if isinstance(H, low_rank.LowRankHessian) else H.nnz
    label = " (gravity, no tendons)" if peer else " (low-rank)" if isinstance(H, low_rank.LowRankHessian) else ""
    return {"problem": name + label,
            "element": element, "nodes": n_nodes, "dofs": H.shape[0], "nnz": nnz,
            **_best_seconds(fns, repeats)}


def bench_solves(name: str, nodes: int, element: str, repeats: int, peer: bool = False) -> dict:
    """Whole forward solves from rest, every factorisation in each CHOLMOD
    mode (its solves, the low-rank set-up and the pivot test included, as
    Newton takes them): CPU seconds, median of ``repeats``, the modes in
    turn, each mode's symbolic analysis done before the first timed solve."""
    mesh, model, c = _loaded(name, nodes, element, peer)
    options = EquilibriumOptions(eigenvalue=False)
    plain = model.factorizer
    by_mode = {mode: type(plain)("cholmod", mode, low_rank=plain.low_rank) for mode in ("simplicial", "supernodal")}
    times = {mode: [] for mode in by_mode}
    try:
        for i in range(repeats + 1):
            for mode, fz in by_mode.items():
                model.factorizer = fz
                t = time.process_time()
                eq = solve_equilibrium(model, c, options=options)
                if i:                              # (the first: the symbolic analysis)
                    times[mode].append(time.process_time() - t)
    finally:
        model.factorizer = plain
    H = model.evaluate(eq.x, c).hessian_form
    label = " (gravity, no tendons)" if peer else ""
    return {"problem": name + label, "element": element, "nodes": mesh.n_nodes, "dofs": model.n_dofs,
            "nnz": H.body.nnz if isinstance(H, low_rank.LowRankHessian) else H.nnz,
            **{mode: float(np.median(v)) for mode, v in times.items()}}


def bench_forms(name: str, nodes: int, element: str, repeats: int) -> dict:
    """factor + solve of one Hessian in each form, at the same pose."""
    scene = load_scene(ROOT / "problems" / f"{name}.yaml").replace(element=element)
    mesh = mesh_for_nodes(scene, nodes)
    models = {form: Model(scene, mesh, hessian=form) for form in ("assembled", "rank_one", "split")}
    ref = models["assembled"]
    c = ref.lower + CONTRACTION_FRACTION * (ref.upper - ref.lower)
    x = solve_equilibrium(ref, c, options=EquilibriumOptions(eigenvalue=False)).x
    b = np.random.default_rng(0).standard_normal(ref.n_dofs)
    forms = {form: m.evaluate(x, c).hessian_form for form, m in models.items()}
    fns = {form: (lambda fz, H: lambda: fz.factor(H).solve(b))(linalg.Factorizer(), H)
           for form, H in forms.items()}
    # the split form through its augmented matrix (where its body alone is not definite)
    fns["augmented"] = (lambda fz, H: lambda: linalg.augmented_factor(H, 0.0, fz)[0].solve(b))(
        linalg.Factorizer(mode="simplicial"), forms["split"])
    auto = build_model(scene, mesh)
    return {"problem": name, "element": element, "nodes": mesh.n_nodes,
            "disc_nodes": auto.tendon_points.mean_disc_nodes(), "k": forms["split"].M.shape[0],
            "auto": (f"split ({auto.factorizer.low_rank})" if auto.split_segments else
                     "rank_one" if auto.low_rank else "assembled"),
            **_best_seconds(fns, repeats)}


def _table(args, bench, header: str, row) -> None:
    """One Markdown row per problem, element and node count of ``args``:
    ``bench(name, nodes, element, repeats)`` measured, ``row(result)`` printed."""
    print(header + "\n|" + "---|" * header.count(" | ") + "---|")
    for name in args.problems:
        for element in args.element:
            for nodes in args.nodes:
                print(row(bench(name, nodes, element, args.repeats)), flush=True)


def main_forms(args):
    _table(args, bench_forms,
           "| problem | element | nodes | nodes per disc | k (split) | assembled (ms) | rank_one (ms) | "
           "split (ms) | split, augmented (ms) | assembled / split | auto |",
           lambda r: (f"| {r['problem']} | {r['element']} | {r['nodes']} | {r['disc_nodes']:.1f} | {r['k']} | "
                      f"{1e3 * r['assembled']:.1f} | {1e3 * r['rank_one']:.1f} | {1e3 * r['split']:.1f} | "
                      f"{1e3 * r['augmented']:.1f} | {r['assembled'] / r['split']:.2f} | {r['auto']} |"))


def main_modes(args):
    # whole solves in whole milliseconds, one factorisation to a tenth
    bench, digits = ((lambda *a: bench_solves(*a, peer=args.peer)), 0) if args.solves else \
        ((lambda *a: bench_modes(*a, taken=args.taken, peer=args.peer)), 1)
    _table(args, bench,
           "| problem | element | nodes | unknowns | nnz(H) | simplicial (ms) | supernodal (ms) | "
           "simplicial / supernodal |",
           lambda r: (f"| {r['problem']} | {r['element']} | {r['nodes']} | {r['dofs']} | {r['nnz']} | "
                      f"{1e3 * r['simplicial']:.{digits}f} | {1e3 * r['supernodal']:.{digits}f} | "
                      f"{r['simplicial'] / r['supernodal']:.2f} |"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--nodes", type=int, nargs="+", default=[1000, 2000, 3000])
    ap.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=PROBLEMS)
    ap.add_argument("--repeats", type=int, default=40)
    ap.add_argument("--modes", action="store_true", help="CHOLMOD simplicial against supernodal")
    ap.add_argument("--forms", action="store_true", help="the Hessian's forms with finite attachments")
    ap.add_argument("--element", nargs="+", default=["P1"], choices=("P1", "P2"))
    ap.add_argument("--taken", action="store_true",
                    help="with --modes: the Hessian in the form Newton factors (a low-rank form: its body + Woodbury)")
    ap.add_argument("--peer", action="store_true",
                    help="with --modes: the problem's body under gravity without tendons (bench --peers)")
    ap.add_argument("--solves", action="store_true",
                    help="with --modes: whole forward solves from rest in each mode (CPU time, medians)")
    args = ap.parse_args(argv)
    if args.modes:
        return main_modes(args)
    if args.forms:
        return main_forms(args)
    backends = [b for b in linalg.BACKENDS if b == "qdldl" or linalg._cholmod_installed()]
    print(f"Python {platform.python_version()}, scipy {_version('scipy')}, "
          f"scikit-sparse {_version('scikit-sparse')}, qdldl {_version('qdldl')}; "
          f"{platform.processor() or platform.machine()}\n")
    extra = ["splu"] + (["cholespy"] if _cholespy() is not None else [])
    cols = [f"{b} (ms)" for b in backends + extra]
    ratio = "cholmod" in backends
    print("| problem | nodes | nnz(H) | " + " | ".join(cols) + (" | qdldl / cholmod |" if ratio else " |"))
    print("|---" * (3 + len(cols) + ratio) + "|")
    for name in args.problems:
        for nodes in args.nodes:
            r = bench(name, nodes, args.repeats, backends)
            cells = [f"{1e3 * r[b]:.2f}" for b in backends + extra]
            if ratio:
                cells.append(f"{r['qdldl'] / r['cholmod']:.2f}")
            print(f"| {r['problem']} | {r['nodes']} | {r['nnz']} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
